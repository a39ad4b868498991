"""What the tiny pipeline writes is what it wrote before (`tools/tiny_reports.py`): the outputs that repeat on
every machine (the data stages and `tune_kalman`), timing fields aside, against the digests pinned in
tests/tiny_reports.json. A refactor passes unchanged; a change that alters an output on purpose re-pins them
(`python tools/tiny_reports.py --repository <tiny run> --write`), and the diff of the pinned file names what it
altered."""

from __future__ import annotations

import json
from pathlib import Path

from tools import tiny_reports


def test_the_tiny_runs_outputs_are_the_pinned_ones(tiny_pipeline: Path) -> None:
    pinned = json.loads(tiny_reports.PINNED.read_text())
    changed = tiny_reports.differences(pinned, tiny_reports.output_digests(tiny_pipeline))
    assert not changed, f"outputs of the tiny run differ from tests/tiny_reports.json: {changed}"


def test_a_changed_output_is_named_and_timings_and_trained_outputs_are_not() -> None:
    pinned = {"stages": {"routes": {"data/routes": "md5:a"}, "tune_kalman": {"models/kalman_tuned.json": "json:t"},
                         "evaluate": {"reports/tracker_metrics.json": "json:b"}}}
    found = {"routes": {"data/routes": "md5:a"}, "tune_kalman": {"models/kalman_tuned.json": "json:u"},
             "evaluate": {"reports/tracker_metrics.json": "json:c"}, "simulate": {"data/simulated": "md5:s"}}
    assert tiny_reports.differences(pinned, found) == ["simulate: (not pinned)", "tune_kalman: models/kalman_tuned.json"]
    assert tiny_reports._without_timing({"runs": [{"OSPA": 1.0, "plots_per_second": 9e3}], "seconds": 3}) == {
        "runs": [{"OSPA": 1.0}]}

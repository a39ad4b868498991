"""Metrics files as DVC compares them (`io.write_metrics`): results to six significant digits, timings apart,
so that `dvc metrics diff` of two runs lists what a change moved and not the machine's last bits or its load."""

from __future__ import annotations

import json
import math
import os
import stat

from pipeline import io


def test_floats_keep_six_significant_digits_and_other_values_are_kept():
    data = {"MAE": 1 / 3, "GOSPA": 2162.123456789, "tiny": 1.23456789e-7, "count": 12345678, "flag": True,
            "missing": math.nan, "nested": [{"x": 0.1 + 0.2}]}
    assert io.rounded(data) == {"MAE": 0.333333, "GOSPA": 2162.12, "tiny": 1.23457e-7, "count": 12345678,
                                "flag": True, "missing": data["missing"], "nested": [{"x": 0.3}]}


def test_last_bit_differences_of_two_machines_give_the_same_bytes(tmp_path):
    """The same mean summed in another order on another processor differs in its twelfth digit."""
    here, there = 160.23456789012345, 160.23456789012991
    assert here != there
    io.write_metrics({"runs": {"imm_gnn_4000": {"MAE": here}}}, tmp_path / "a.json")
    io.write_metrics({"runs": {"imm_gnn_4000": {"MAE": there}}}, tmp_path / "b.json")
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()


def test_timings_go_beside_the_metrics_and_come_back_when_read(tmp_path):
    report = {"runs": {"imm_gnn_4000": {"MAE": 160.25, "plots_per_second": 19265.31},
                       "via_4000": {"MAE": 170.5, "plots_per_second": 3317.2}},
              "filters": {"cv": {"cost": 1.5, "seconds": 43.46221}}, "split": "test"}
    path = tmp_path / "reports" / "tracker_metrics.json"
    path.parent.mkdir()
    io.write_metrics(report, path)
    assert json.loads(path.read_text()) == {"runs": {"imm_gnn_4000": {"MAE": 160.25}, "via_4000": {"MAE": 170.5}},
                                            "filters": {"cv": {"cost": 1.5}}, "split": "test"}
    timings = tmp_path / "reports" / "timings" / "tracker_metrics.json"
    assert json.loads(timings.read_text()) == {"runs": {"imm_gnn_4000": {"plots_per_second": 19300.0},
                                                        "via_4000": {"plots_per_second": 3320.0}},
                                               "filters": {"cv": {"seconds": 43.5}}}
    back = io.read_metrics(path)
    assert back["runs"]["via_4000"] == {"MAE": 170.5, "plots_per_second": 3320.0}
    assert back["filters"]["cv"] == {"cost": 1.5, "seconds": 43.5} and back["split"] == "test"


def test_a_report_without_timings_writes_no_timings_file_and_reads_back_whole(tmp_path):
    io.write_metrics({"rows": 380, "share": 0.25}, tmp_path / "data.json")
    assert not (tmp_path / "timings").exists()
    assert io.read_metrics(tmp_path / "data.json") == {"rows": 380, "share": 0.25}


def test_metrics_keep_the_mode_of_the_file_they_replace(tmp_path):
    path = tmp_path / "data.json"
    path.write_text("{}")
    os.chmod(path, 0o640)
    io.write_metrics({"rows": 1}, path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o640 and json.loads(path.read_text()) == {"rows": 1}

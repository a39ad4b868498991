"""Stage `evaluate_sites`: the evaluated routes flown past radars at `evaluate.sites`, every
tracker scored at each (`pipeline.bench.sites`); the training site's row is the `evaluate` stage's.

Writes `reports/site_metrics.json`: per site its place, plot counts and every run's metrics
as `reports/tracker_metrics.json` has them, without the speeds.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.bench import sites
from pipeline.bench.runs import declared_runs
from pipeline.params import Params

log = logging.getLogger("pipeline")


def training_runs(params: Params, path: Path) -> tuple[dict[str, dict], dict[str, float]]:
    """The `evaluate` stage's metrics at the training site of the runs scored at sites
    (`evaluate.site_runs`) and the references, checked to be of params' runs, and its bounds by model."""
    if not path.is_file():
        raise io.InputError(f"{path}: file not found (run `dvc repro evaluate`)")
    report = io.read_metrics(path)
    runs = report["runs"]
    expected = sorted(declared_runs(params))  # every run and reference, by name
    if sorted(runs) != expected:
        raise io.InputError(f"{path}: runs {sorted(runs)}, but params evaluate {expected}; "
                            "run `dvc repro evaluate`")
    at_sites = {run.name for run in (*params.evaluate.runs_at_sites(), *params.evaluate.reference_runs())}
    if "pcrb_horizontal_rms_m" not in report:
        raise io.InputError(f"{path}: no pcrb_horizontal_rms_m (written before the bound was); run `dvc repro evaluate`")
    return {name: values for name, values in runs.items() if name in at_sites}, report["pcrb_horizontal_rms_m"]


def run_evaluate_sites(params: Params, models_dir: Path, reports_dir: Path) -> None:
    report = sites.site_metrics(params, *training_runs(params, reports_dir / "tracker_metrics.json"), models_dir)
    io.write_metrics(report, reports_dir / "site_metrics.json")
    log.info("evaluate_sites: %d sites -> %s", len(report["sites"]), reports_dir / "site_metrics.json")

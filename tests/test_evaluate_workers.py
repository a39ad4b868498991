"""The evaluate stage gives the same reports whatever the number of worker processes.

A tiny test split (two routes of each of the thesis's two strategies, each scenario cut to its
first 15 minutes), tiny trained networks (tests/tracker_fixtures.py) and the classical filters at their start values,
evaluated with one run of each kind (network gates, the young-track radius, classical
nearest and global nearest neighbour, one under the m_of_n management rule) and both references, on two
draws of every scenario (`evaluate.seeds`): once in the stage's process, once over two local Dask workers;
and on one draw, in the stage's process and on a scheduler and two workers started apart. Everything written must be equal byte for byte, except the speed
of each run (`plots_per_second`), a timing.
"""

from __future__ import annotations

import json
from pathlib import Path

import dask
import numpy as np
import pyarrow as pa
import pytest

from pipeline import io
from pipeline.simulation import routes, simulate
from pipeline.stages.evaluate_stage import run_evaluate
from tests import tracker_fixtures as tf
from tests.servers import dask_cluster

# Third-party deprecation notices (Lightning's pytree use), not ours.
pytestmark = pytest.mark.filterwarnings("ignore:.*LeafSpec.* is deprecated")

TEST_SPLIT = {"routes.splits.test.constant_jerk": 2, "routes.splits.test.random_turns": 2,
              "routes.splits.test.sustained_turns": 0, "routes.splits.test.climb_dive": 0}
KEPT_S = 900.0  # of each scenario: enough for tracks to confirm, and seconds to evaluate
RUNS = [{"method": "via", "window_m": 4000.0}, {"method": "mia", "window_m": 4000.0},
        {"method": "ae", "window_m": 5000.0}, {"method": "radius", "window_m": 4000.0},
        {"method": "kalman_cv", "window_m": 4000.0}, {"method": "imm_gnn", "window_m": 4000.0},
        {"method": "imm_gnn", "window_m": 4000.0, "management": "m_of_n"}]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> tuple[Path, Path, Path]:
    """Folders of simulated data, routes and models for a tiny test split."""
    params = tf.make_params(TEST_SPLIT)
    folder = tmp_path_factory.mktemp("evaluate")
    split = params.routes.split(params.evaluate.split)
    route_table = routes.generate_split(params, split)
    plots, truth = simulate.simulate_split(params, split, route_table)
    time, scenario = plots.column("time_unix_s").to_numpy(), plots.column("scenario_id").to_numpy()
    first = {s: time[scenario == s].min() for s in np.unique(scenario)}
    keep = time <= np.array([first[s] for s in scenario]) + KEPT_S
    io.write_parquet(plots.filter(pa.array(keep)), folder / "simulated" / split.name / "plots.parquet")
    io.write_parquet(truth, folder / "simulated" / split.name / "truth.parquet")
    io.write_parquet(simulate.radar_description(params), folder / "simulated" / split.name / "radar.parquet")
    io.write_parquet(route_table, folder / "routes" / f"{split.name}.parquet")
    models = folder / "models"
    models.mkdir()
    for network in tf.trained_models(tmp_path_factory).glob("*.pt"):
        (models / network.name).write_bytes(network.read_bytes())
    io.write_json({"cost": "rmse", "filters": {kind: settings.to_dict()
                                               for kind, settings in tf.untuned_filters(params).items()}},
                  models / "kalman_tuned.json")
    return folder / "simulated", folder / "routes", models


def evaluate(inputs: tuple[Path, Path, Path], workers: int, reports: Path, seeds: int = 2) -> Path:
    params = tf.make_params({**TEST_SPLIT, "evaluate.runs": RUNS, "evaluate.site_runs": [], "evaluate.scene_runs": [], "evaluate.example_scenarios": 2,
                             "evaluate.example_run": "via_4000", "evaluate.seeds": seeds, "compute.workers": workers})
    run_evaluate(params, *inputs, reports)
    return reports


def files(reports: Path) -> dict[str, bytes]:
    return {str(path.relative_to(reports)): path.read_bytes() for path in sorted(reports.rglob("*")) if path.is_file()}


def speeds(reports: dict[str, bytes]) -> list[float]:
    """The runs' plots per second, taken out of `reports` (the timings file beside the metrics file, which
    holds the timings, apart so that the metrics are the same bytes on every run): each a positive number."""
    timings = json.loads(reports.pop("timings/tracker_metrics.json"))
    values = [run["plots_per_second"] for run in timings["runs"].values()]
    assert values and all(value > 0.0 for value in values)
    return values


def test_one_and_two_workers_write_the_same_reports(inputs, tmp_path, monkeypatch):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    alone = files(evaluate(inputs, 1, tmp_path / "one"))
    shared = files(evaluate(inputs, 2, tmp_path / "two"))
    assert sorted(alone) == sorted(shared) == ["ospa_per_scan.png", "timings/tracker_metrics.json",
                                               "tracker_intervals.json", "tracker_metrics.json", "tracker_tables.md",
                                               "tracks/scenario_0.png", "tracks/scenario_1.png"]
    assert len(speeds(alone)) == len(speeds(shared))
    assert alone == shared
    metrics = json.loads(alone["tracker_metrics.json"])
    # The runs did track: each confirmed tracks on target plots.
    assert set(metrics["runs"]) == {"via_4000", "mia_4000", "ae_5000", "radius_4000", "kalman_cv_4000",
                                    "imm_gnn_4000", "imm_gnn_4000_m_of_n", "plots_reference", "oracle_reference"}
    assert all(run["NOPA"] > 0 for run in metrics["runs"].values())
    bounds = metrics["pcrb_horizontal_rms_m"]  # the limit beside the scorecard's position RMS, by tuned model
    assert set(bounds) == {"cv", "ca"} and all(0.0 < value < 1e4 for value in bounds.values())


def test_a_cluster_of_workers_apart_writes_the_same_reports(inputs, tmp_path, monkeypatch):
    """The units sent to a scheduler and two workers started as their own processes (as on machines
    apart, DASK_SCHEDULER_ADDRESS naming the scheduler): the reports of one process, byte for byte."""
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    alone = files(evaluate(inputs, 1, tmp_path / "one", seeds=1))
    with dask_cluster(tmp_path) as address, dask.config.set({"scheduler-address": address}):
        apart = files(evaluate(inputs, 1, tmp_path / "cluster", seeds=1))
    assert len(speeds(alone)) == len(speeds(apart))
    assert alone == apart

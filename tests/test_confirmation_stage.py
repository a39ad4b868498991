"""`python -m pipeline train-confirmation` as a user runs it in a copy of the tiny pipeline (its simulated plots
and tuned filters), then `track --management learned` with the network it wrote."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import pyarrow.parquet as pq

from pipeline.learning import confirmation
from pipeline.settings import load_params
from pipeline.tracker.learned_confirmation import LearnedConfirmation
from tests.project import run_pipeline

TRACK = ["track", "--params", "params.yaml", "--plots", "data/simulated/test/plots.parquet", "--radar",
         "data/simulated/test/radar.parquet", "--method", "kalman_cv", "--management", "learned"]


def test_the_stage_learns_from_candidate_tracks_and_the_tracker_confirms_by_it(tiny_pipeline: Path, tmp_path: Path
                                                                               ) -> None:
    repository = shutil.copytree(tiny_pipeline, tmp_path / "copy", symlinks=True)
    (repository / "mlflow.db").unlink()  # the copied store keeps its artifacts in the tiny pipeline's folder
    result = run_pipeline("train-confirmation", "--params", "params.yaml", "--simulated", "data/simulated",
                          "--models", "models", "--reports", "reports", cwd=repository)
    assert result.returncode == 0, result.stderr
    params = load_params(repository / "params.yaml")
    trained = confirmation.load(repository / "models" / "confirmation.pt")
    assert trained.window == params.tracker.management.confirm_n and len(trained.clutter_maxima) > 0
    assert (trained.clutter_maxima[:-1] <= trained.clutter_maxima[1:]).all()  # sorted, for the threshold
    report = json.loads((repository / "reports" / "confirmation.json").read_text())
    assert report["associations"]["train"] > 0 and report["associations"]["held_out"] > 0
    at = report["at_default_probability"]
    assert at["clutter_confirmed"] <= at["false_track_probability"]
    assert 0.0 < report["held_out"]["log_loss"] < 1.0 and len(report["epoch_losses"]) == 3
    with sqlite3.connect(repository / "mlflow.db") as store:
        names = [row[0] for row in store.execute("SELECT name FROM runs WHERE status = 'FINISHED'")]
    assert names == ["train_confirmation"]

    result = run_pipeline(*TRACK, "--out", "tracks.parquet", cwd=repository)
    assert result.returncode == 0, result.stderr
    weights = pq.read_table(repository / "tracks.parquet").column("weight").to_numpy()
    rule = LearnedConfirmation(params.tracker.management.confirm_n, 1.0, 20.0, 3.25, lambda evidence: 1.0)
    assert rule.confirmed(weights).any() and not rule.confirmed(weights).all()


def test_tracking_under_the_learned_rule_without_its_network_names_the_stage(tiny_pipeline: Path, tmp_path: Path
                                                                            ) -> None:
    repository = shutil.copytree(tiny_pipeline, tmp_path / "copy", symlinks=True)
    (repository / "models" / "confirmation.pt").unlink(missing_ok=True)
    result = run_pipeline(*TRACK, "--out", "tracks.parquet", cwd=repository)
    assert result.returncode == 2
    assert "models/confirmation.pt: file not found" in result.stderr and "dvc repro train_confirmation" in result.stderr
    assert not (repository / "tracks.parquet").exists()

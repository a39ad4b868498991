"""`python -m pipeline train-association` as a user runs it: outputs, one MLflow run; bad params stop it first."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

from pipeline.association import association_net
from pipeline.association.registry import ASSOCIATORS
from tests.project import run_pipeline, tiny_params_tree, write_params


def test_stage_writes_model_report_picture_and_one_mlflow_run(tmp_path: Path) -> None:
    params = write_params(tiny_params_tree(), tmp_path / "params.yaml")
    result = run_pipeline("train-association", "--params", str(params), "--models", "models", "--reports", "reports",
                          cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert association_net.load(tmp_path / "models" / "association_net.pt").config.size == 32
    report = json.loads((tmp_path / "reports" / "association.json").read_text())
    assert sorted(report["by_bias_m"]) == ["0", "200"]
    assert sorted(report["seed_setting"]["methods"]) == sorted(ASSOCIATORS)
    assert report["by_bias_m"]["0"]["methods"]["statistical"]["accuracy"] == 1.0
    assert (tmp_path / "reports" / "association_bias.png").read_bytes().startswith(b"\x89PNG")
    with sqlite3.connect(tmp_path / "mlflow.db") as store:
        names = [row[0] for row in store.execute("SELECT name FROM runs WHERE status = 'FINISHED'")]
    assert names == ["train_association"]


def test_more_targets_than_the_scene_tensor_holds_is_refused_before_any_output(tmp_path: Path) -> None:
    tree = tiny_params_tree()
    tree["association"]["targets"] = [16, 40]
    result = run_pipeline("train-association", "--params", str(write_params(tree, tmp_path / "params.yaml")),
                          "--models", "models", "--reports", "reports", cwd=tmp_path)
    assert result.returncode == 2
    assert "association.targets = [16, 40]: more targets than scene_size = 32 tracks" in result.stderr
    assert not (tmp_path / "models").exists() and not (tmp_path / "mlflow.db").exists()

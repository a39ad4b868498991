"""The worked examples of docs/architecture.md, run as written from its code blocks: adding an estimator (its module and
its registry entry give a method that tracks a straight target), and adding a trained estimator (its model
module, its entry, its registry entry and its params section: trained by the one training task on tiny
params, loaded by the tracker as `models[name]`, tracking a straight target)."""

from __future__ import annotations

import json
import re
import sys
import types
from dataclasses import dataclass, fields, make_dataclass
from pathlib import Path
from typing import Any

import mlflow
import numpy as np
import pytest
import yaml

from pipeline.learning import kinds
from pipeline.learning.recipe import Folders
from pipeline.learning.runner import run_training
from pipeline.params import Params
from pipeline.settings import parse_params
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.run import track
from tests import tracker_fixtures as tf
from tests.project import REPOSITORY, run_pipeline, tiny_params_tree, write_params

PAGE = REPOSITORY / "docs" / "architecture.md"


def example(marker: str, language: str = "python") -> str:
    """The code block after `<!-- example: marker -->` in docs/architecture.md."""
    after = PAGE.read_text().split(f"<!-- example: {marker} -->", 1)[1]
    return re.search(rf"```{language}\n(.*?)```", after, re.S).group(1)


def add_module(monkeypatch, name: str, marker: str) -> types.ModuleType:
    """The page's module block `marker`, importable as `name`."""
    module = types.ModuleType(name)
    monkeypatch.setitem(sys.modules, name, module)  # before its code runs: dataclasses look their module up
    exec(compile(example(marker), f"docs/architecture.md: {name}", "exec"), module.__dict__)
    return module


def add_method(monkeypatch, marker: str) -> registry.Method:
    """The page's registry entry `marker` (a compose function, then the method), registered."""
    definition, entry = example(marker).strip().rsplit("\n\n", 1)
    namespace = dict(vars(registry))
    exec(compile(definition, f"docs/architecture.md: {marker}", "exec"), namespace)
    method = eval(entry, namespace)
    monkeypatch.setitem(registry.METHODS, method.name, method)
    return method


def tracks_a_straight_flight(models, method: str, params) -> tuple[dict, np.ndarray]:
    """The updates of `method` on 20 plots of a straight 216 m/s flight, and the flight's true positions."""
    features = tf.straight_features(params.radar, (50e3, 80e3, 9000.0), (-180.0, 120.0, 0.0), 20)
    updates = track(tf.plots_of(features, np.arange(20), params.radar),
                    registry.compose(method, models, params.tracker, 4000.0, params.tracker.seed))
    return updates, features[:, 1:4]


def test_the_readme_alpha_beta_example_is_one_module_and_one_entry_and_tracks(monkeypatch, tmp_path: Path):
    """The example's module, importable as pipeline.tracker.alpha_beta, and its registry entry, added
    to the registry: loading its needs reads no file, and on 20 plots of a straight 216 m/s flight it
    gives one track holding them all, confirmed from the fourth plot, within 100 m of the flight from
    the tenth plot on."""
    add_module(monkeypatch, "pipeline.tracker.alpha_beta", "estimator module")
    add_method(monkeypatch, "registry entry")

    params = tf.make_params()
    models = load_models(tmp_path, params, ["alpha_beta"])
    updates, truth = tracks_a_straight_flight(models, "alpha_beta", params)
    assert updates["track_id"].tolist() == [0] * 20
    assert updates["association"].tolist() == ["start", "radius"] + ["alpha_beta"] * 18
    np.testing.assert_allclose(updates["weight"][3:], 1.0)
    estimates = np.column_stack([updates[f"{axis}_ecef_m"] for axis in "xyz"])
    assert np.linalg.norm(estimates[9:] - truth[9:], axis=1).max() < 100.0


def with_section(params: Params, name: str, values: dict[str, Any]) -> Params:
    """`params` with the README's params section `name` added: what declaring it in pipeline/params/ gives
    (its keys, with the YAML's values)."""
    section = make_dataclass(name, [(key, type(value)) for key, value in values.items()], frozen=True)
    declared = dataclass(frozen=True)(type("Declared", (Params,), {"__annotations__": {name: Any}}))
    return declared(**{field.name: getattr(params, field.name) for field in fields(params)},
                    **{name: section(**values)})


@pytest.mark.slow
def test_the_readme_trained_estimator_example_is_trained_by_the_one_task_and_tracks(monkeypatch, tmp_path: Path):
    """The trained example's model module, entry, registry entry and params section (3 epochs) on a tiny
    simulation: `train --kind alpha_beta_gains`'s task trains it in one FINISHED MLflow run with its section's
    params, lowers its loss, writes its bundle and report (gains moved, in (0, 1)), and the tracker loads it for `learned_alpha_beta`,
    which holds a straight flight in one confirmed track within 150 m from the tenth plot."""
    add_module(monkeypatch, "pipeline.tracker.alpha_beta", "estimator module")
    add_module(monkeypatch, "pipeline.learning.alpha_beta_gains", "trained model module")
    namespace = dict(vars(kinds))
    definitions, entry = example("kind entry").strip().rsplit("\n\n\n", 1)
    exec(compile(definitions, "README: kind entry", "exec"), namespace)
    kind = eval(entry, namespace)
    monkeypatch.setitem(kinds.KINDS, kind.name, kind)
    monkeypatch.setitem(kinds.PIECES, kind.name, kind)
    method = add_method(monkeypatch, "trained registry entry")
    [(name, values)] = yaml.safe_load(example("params section", "yaml")).items()
    stage = yaml.safe_load(example("dvc stage", "yaml"))[kind.stage]
    assert f"--kind {kind.name}" in stage["cmd"] and f"models/{kind.file}" in stage["outs"]

    tree = tiny_params_tree()
    write_params(tree, tmp_path / "params.yaml")
    for command in (("routes", "--out", "routes"), ("simulate", "--routes", "routes", "--out", "simulated")):
        result = run_pipeline(command[0], "--params", "params.yaml", *command[1:], cwd=tmp_path)
        assert result.returncode == 0, result.stderr
    store = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", store)
    monkeypatch.chdir(tmp_path)
    params = with_section(parse_params(tree), name, {**values, "epochs": 3})
    run_training(kind, params, Folders(simulated=tmp_path / "simulated", models=tmp_path / "models",
                                       reports=tmp_path / "reports"))

    report = json.loads((tmp_path / "reports" / "alpha_beta_gains.json").read_text())
    assert len(report["epoch_losses_m"]) == 3 and report["epoch_losses_m"][-1] < report["epoch_losses_m"][0]
    assert 0.0 < report["alpha"] < 1.0 and 0.0 < report["beta"] < 1.0 and report["alpha"] != 0.5
    client = mlflow.MlflowClient(tracking_uri=store)
    [run] = client.search_runs([client.get_experiment_by_name(params.training.experiment).experiment_id])
    assert (run.info.run_name, run.info.status) == (kind.stage, "FINISHED")
    assert run.data.params["alpha_beta_gains.initial_alpha"] == "0.5"
    assert run.data.metrics["alpha_beta_gains.alpha"] == pytest.approx(report["alpha"], rel=1e-5)  # the file: 6 digits

    models = load_models(tmp_path / "models", params, [method.name])
    assert models[kind.name].gains() == pytest.approx((report["alpha"], report["beta"]), rel=1e-5)
    updates, truth = tracks_a_straight_flight(models, method.name, params)
    assert updates["track_id"].tolist() == [0] * 20
    np.testing.assert_allclose(updates["weight"][3:], 1.0)
    estimates = np.column_stack([updates[f"{axis}_ecef_m"] for axis in "xyz"])
    assert np.linalg.norm(estimates[9:] - truth[9:], axis=1).max() < 150.0

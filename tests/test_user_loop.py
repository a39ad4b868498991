"""The user's loop with DVC, as a user meets it, on tiny params in a fresh copy of the repository.

Change a param and rerun; try it as an experiment and compare; look at the plots. And what the
user relies on without seeing it: the same params give the same results, and a run stopped
half-way leaves nothing half-written behind.

The tiny pipeline runs once for the whole module (`tiny_run`) and its result is committed, as
a user commits a run. The tests change that copy, so each one first goes back to the commit
(`restore_committed_state`), the way a user undoes an experiment. With `--dist loadfile`
(pyproject.toml) the module stays on one xdist worker, so the fixture runs once, not once per
worker.
"""

from __future__ import annotations

import copy
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import mlflow
import pytest
import yaml

from pipeline.learning.model_store import load_model
from tests.project import copy_repository, environment, tiny_params_tree, write_params

pytestmark = pytest.mark.slow

GIT = ["git", "-c", "user.name=test", "-c", "user.email=test@example.invalid"]
UP_TO_DATE = "Data and pipelines are up to date."
# Keys of metrics files that record wall-clock measurements, not results (see reproducible_outputs).
TIMING_KEY = re.compile(r"per_second|seconds|runtime")


def dvc(repository: Path, *arguments: str) -> str:
    """`dvc <arguments>` as a user types it; its standard output. Fails the test on a non-zero exit."""
    result = subprocess.run([sys.executable, "-m", "dvc", *arguments], cwd=repository, env=environment(),
                            capture_output=True, text=True)
    assert result.returncode == 0, f"dvc {' '.join(arguments)} failed:\n{result.stdout}\n{result.stderr}"
    return result.stdout


def git(repository: Path, *arguments: str) -> None:
    subprocess.run([*GIT, *arguments], cwd=repository, check=True, capture_output=True)


def commit_workspace(repository: Path, message: str) -> None:
    git(repository, "add", "--all")
    git(repository, "commit", "--quiet", "--message", message)


def restore_committed_state(repository: Path) -> None:
    """Undo what a test did, as a user drops an experiment: git restores params, dvc.lock and
    reports, `dvc checkout` the data and models from DVC's cache."""
    git(repository, "reset", "--quiet", "--hard")
    dvc(repository, "checkout")
    assert UP_TO_DATE in dvc(repository, "status")


def without_timing(metrics: Any) -> Any:
    if isinstance(metrics, dict):
        return {key: without_timing(value) for key, value in metrics.items() if not TIMING_KEY.search(key)}
    return metrics


def reproducible_outputs(repository: Path) -> dict[str, Any]:
    """What the same params must reproduce exactly, by path: every file under data/ and every model
    file (bytes, so a fresh run reproduces dvc.lock's hashes), every metrics JSON and loss curve
    under reports/.

    Left out: pictures (test_determinism covers the data report's), and in metrics JSON the keys
    that name a wall-clock measurement (`per_second`, `seconds`, `runtime`: a tracker run's
    `plots_per_second`, the Kalman tuning's `seconds` per filter), which depend on the machine
    and its load, not on the params."""
    outputs: dict[str, Any] = {}
    for path in sorted((repository / "data").rglob("*")):
        if path.is_file():
            outputs[str(path.relative_to(repository))] = path.read_bytes()
    for path in sorted((repository / "models").glob("*.pt")):
        outputs[str(path.relative_to(repository))] = path.read_bytes()
    for path in sorted((repository / "reports").rglob("*.json")):
        outputs[str(path.relative_to(repository))] = without_timing(json.loads(path.read_text()))
    for path in sorted((repository / "reports" / "loss").glob("*.csv")):
        outputs[str(path.relative_to(repository))] = path.read_text()
    return outputs


@dataclass
class TinyRun:
    """A fresh copy of the repository after one tiny `dvc repro`, committed."""

    repository: Path
    params: dict[str, Any]  # the tiny params tree it ran with
    outputs: dict[str, Any]  # reproducible_outputs() right after the run

    def params_with(self, changes: Mapping[str, Any]) -> dict[str, Any]:
        """The run's params with dotted keys changed, e.g. ``{"training.predictor.epochs": 3}``."""
        tree = copy.deepcopy(self.params)
        for dotted, value in changes.items():
            *parents, key = dotted.split(".")
            node = tree
            for parent in parents:
                node = node[parent]
            node[key] = value
        return tree


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> TinyRun:
    """The whole tiny pipeline, run once for the module and committed as a user commits a run."""
    repository = copy_repository(tmp_path_factory.mktemp("user"))
    params = tiny_params_tree()
    write_params(params, repository / "params.yaml")
    dvc(repository, "repro")
    commit_workspace(repository, "Tiny pipeline run")
    return TinyRun(repository, params, reproducible_outputs(repository))


def declared_plots(repository: Path) -> set[str]:
    """Every path dvc.yaml declares as a plot: the stages' plots, and the files the top-level
    plot definitions draw from."""
    pipeline = yaml.safe_load((repository / "dvc.yaml").read_text())
    entries = [entry for stage in pipeline["stages"].values() for entry in stage.get("plots", [])]
    paths = set()
    for entry in entries + pipeline.get("plots", []):
        if isinstance(entry, str):
            paths.add(entry)
            continue
        for name, definition in entry.items():
            sources = (definition or {}).get("y")
            paths.update(sources if isinstance(sources, dict) else [name])
    return paths


def test_plots_show_renders_every_declared_plot(tiny_run: TinyRun, tmp_path: Path) -> None:
    """`dvc plots show -o <dir>` writes one HTML page with the loss curves, the linearity
    histogram and every other plot dvc.yaml declares, and every image it shows is there."""
    dvc(tiny_run.repository, "plots", "show", "-o", str(tmp_path))
    page = (tmp_path / "index.html").read_text()
    declared = declared_plots(tiny_run.repository)
    assert {"reports/loss/filter.csv", "reports/loss/predictor.csv", "reports/loss/autoencoder.csv",
            "reports/windows_linearity.png"} <= declared
    for path in declared:
        assert path in page, f"{path} is declared as a plot but not on the page"
    images = re.findall(r'<img src="([^"]+)"', page.split("<body>", 1)[1])  # not in the inline chart library
    assert images
    for image in images:
        assert (tmp_path / image).stat().st_size > 1000, f"{image} is missing or empty"


def test_predictor_param_change_reruns_the_predictor_and_what_uses_it_only(tiny_run: TinyRun) -> None:
    """A predictor param is a dependency of train_predictor alone: the data stages, the windows
    and the other two networks are left as they are; what uses the predictor runs again."""
    restore_committed_state(tiny_run.repository)
    write_params(tiny_run.params_with({"training.predictor.epochs": 3}), tiny_run.repository / "params.yaml")
    output = dvc(tiny_run.repository, "repro")
    for stage in ("train_predictor", "models_report", "evaluate"):
        assert f"Running stage '{stage}'" in output
    for stage in ("routes", "simulate", "data_report", "windows", "train_filter", "train_autoencoder"):
        assert f"Stage '{stage}' didn't change, skipping" in output


def experiment_data(shown: list[dict[str, Any]], name: str) -> dict[str, Any]:
    """The params and metrics of experiment `name` in `dvc exp show --json` output."""
    for baseline in shown:
        for group in baseline.get("experiments") or []:
            for revision in group["revs"]:
                if revision["name"] == name:
                    return revision["data"]
    raise AssertionError(f"no experiment {name} in dvc exp show")


def test_exp_run_shows_in_exp_show_params_diff_and_metrics_diff(tiny_run: TinyRun) -> None:
    """`dvc exp run -S` changes one param and runs; `dvc exp show` puts the experiment beside
    its commit, `dvc params diff` names the param, `dvc metrics diff` the metrics it moved."""
    repository = tiny_run.repository
    restore_committed_state(repository)
    dvc(repository, "exp", "run", "-n", "faster-predictor", "-S", "training.predictor.learning_rate=0.002")

    shown = json.loads(dvc(repository, "exp", "show", "--json"))
    commit = next(entry for entry in shown if entry["rev"] != "workspace")["data"]
    experiment = experiment_data(shown, "faster-predictor")
    predictor_params = [data["params"]["params.yaml"]["data"]["training"]["predictor"] for data in (commit, experiment)]
    committed = tiny_run.params["training"]["predictor"]["learning_rate"]
    assert committed != 0.002
    assert [params["learning_rate"] for params in predictor_params] == [committed, 0.002]
    losses = [data["metrics"]["reports/models/predictor.json"]["data"]["final_train_loss"]
              for data in (commit, experiment)]
    assert losses[0] != losses[1]

    params_diff = json.loads(dvc(repository, "params", "diff", "--json"))
    assert params_diff["params.yaml"].keys() == {"training.predictor.learning_rate"}
    assert params_diff["params.yaml"]["training.predictor.learning_rate"]["new"] == 0.002

    metrics_diff = json.loads(dvc(repository, "metrics", "diff", "--json"))
    assert "final_train_loss" in metrics_diff["reports/models/predictor.json"]
    untouched = {"reports/data.json", "reports/windows.json", "reports/models/filter.json",
                 "reports/models/autoencoder.json"}
    assert not untouched & metrics_diff.keys()


def test_same_params_give_identical_data_models_and_metrics(tiny_run: TinyRun, tmp_path: Path) -> None:
    """A colleague clones the commit and reruns every stage (`dvc repro --force`): the same data
    bytes, model weights and metrics as the first run (what is compared: reproducible_outputs).
    A clone, not a new copy of the working tree, so both runs use the same code."""
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "--quiet", str(tiny_run.repository), str(clone)], check=True)
    dvc(clone, "repro", "--force")
    second = reproducible_outputs(clone)
    assert sorted(second) == sorted(tiny_run.outputs)
    assert any(name.endswith(".parquet") for name in second) and any(name.endswith(".pt") for name in second)
    for name, content in tiny_run.outputs.items():
        assert second[name] == content, f"{name} differs between two runs with the same params"


def stop_filter_training(tiny_run: TinyRun, epochs: int, signal_number: int, log: Path) -> None:
    """From the committed state, train the filter for `epochs` with `dvc repro`, and once it is
    training send `signal_number` to the whole process group (dvc and the stage), as Ctrl-C in a
    terminal does.

    `epochs` of batches of 16 is some seconds of training, so the signal lands in it, and differs between tests:
    DVC's run cache restores a finished run with the same params instead of training again."""
    repository = tiny_run.repository
    restore_committed_state(repository)
    write_params(tiny_run.params_with({"training.filter.epochs": epochs, "training.filter.batch_size": 16}),
                 repository / "params.yaml")
    with log.open("w") as output:
        process = subprocess.Popen([sys.executable, "-m", "dvc", "repro"], cwd=repository, env=environment(),
                                   stdout=output, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 600
        while "the filter network: epoch 1/" not in log.read_text():
            assert process.poll() is None, f"dvc repro ended before training the filter:\n{log.read_text()}"
            assert time.monotonic() < deadline, "the filter's training did not start in 10 minutes"
            time.sleep(0.1)
        os.killpg(process.pid, signal_number)
        assert process.wait(timeout=120) != 0, "dvc repro finished although it was stopped"
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def assert_nothing_half_written(repository: Path) -> None:
    """No temporary file is left, and the filter model is absent (DVC removes a stage's outputs
    before it runs) or whole."""
    leftovers = [path for folder in ("data", "models", "reports") for path in (repository / folder).rglob("*.tmp")]
    assert not leftovers
    model = repository / "models" / "filter.pt"
    assert not model.exists() or load_model(model, expected_kind="filter")
    assert "train_filter" in json.loads(dvc(repository, "status", "--json"))


def test_training_killed_half_way_leaves_no_partial_output_and_repro_finishes_it(tiny_run: TinyRun,
                                                                                 tmp_path: Path) -> None:
    """SIGKILL (out of memory, a closed session): no code of the pipeline runs after it, so only
    writing every output atomically keeps half-written files out. Running the same command
    again trains the filter to the end."""
    repository = tiny_run.repository
    stop_filter_training(tiny_run, 100, signal.SIGKILL, tmp_path / "repro.log")
    assert_nothing_half_written(repository)
    assert "Running stage 'train_filter'" in dvc(repository, "repro")
    assert UP_TO_DATE in dvc(repository, "status")
    load_model(repository / "models" / "filter.pt", expected_kind="filter")
    assert json.loads((repository / "reports" / "models" / "filter.json").read_text())["epochs_trained"] == 100


def test_ctrl_c_during_training_is_a_failed_run_and_putting_the_param_back_restores_the_model(
        tiny_run: TinyRun, tmp_path: Path) -> None:
    """Ctrl-C (SIGINT to dvc and the stage, as a terminal sends it): the stage stops, dvc exits
    non-zero, no output is half written and the model file is absent, and the interrupted run is
    marked FAILED in MLflow, so the UI shows it neither as still running nor as a finished model.
    This holds even when the test runner started dvc with SIGINT ignored (the stage restores
    Python's handler). A user who then puts the param back gets the committed model again from
    DVC's cache, without training."""
    repository = tiny_run.repository
    stop_filter_training(tiny_run, 101, signal.SIGINT, tmp_path / "repro.log")
    assert_nothing_half_written(repository)
    assert not (repository / "models" / "filter.pt").exists()
    client = mlflow.MlflowClient(f"sqlite:///{repository / 'mlflow.db'}")
    experiment = client.get_experiment_by_name(tiny_run.params["training"]["experiment"])
    latest = client.search_runs([experiment.experiment_id], "attributes.run_name = 'train_filter'",
                                order_by=["attributes.start_time DESC"], max_results=1)[0]
    assert latest.data.params["network.epochs"] == "101"
    assert latest.info.status == "FAILED"

    write_params(tiny_run.params, repository / "params.yaml")
    assert "Running stage" not in dvc(repository, "repro")
    assert UP_TO_DATE in dvc(repository, "status")
    assert (repository / "models" / "filter.pt").read_bytes() == tiny_run.outputs["models/filter.pt"]

"""The README's "Walkthrough: your first day", run as written in a fresh copy with tiny params."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import mlflow
import pytest
import yaml

from pipeline.params import ParamsLoader
from pipeline.settings import parse_params
from tests.project import REPOSITORY, copy_repository, environment, tiny_params_tree, write_params

MARKER = "<!-- walkthrough -->"
GIT = ["git", "-c", "user.name=test", "-c", "user.email=test@example.invalid"]


def walkthrough_script(readme: str) -> str:
    """The ```bash block right after the marker."""
    match = re.search(re.escape(MARKER) + r"\s*```bash\n(.*?)\n```", readme, re.DOTALL)
    assert match, f"README.md has no ```bash block right after {MARKER}"
    return match.group(1)


def test_readme_has_the_walkthrough() -> None:
    """The block the slow test runs is there, with the steps a newcomer needs."""
    script = walkthrough_script((REPOSITORY / "README.md").read_text())
    for step in ("dvc repro", "mlflow ui", "dvc exp run", "dvc exp show", "dvc params diff", "dvc metrics diff",
                 "dvc plots show", "python -m pipeline track"):
        assert step in script


@pytest.mark.slow
def test_walkthrough_runs_as_written(tmp_path: Path) -> None:
    """Every command exits 0, in order, in one shell (`bash -e`: the first failure stops it).

    The copy is set up as a newcomer's clone would be after `make env`, with tiny params as its
    committed params (so `dvc params diff` shows the walkthrough's change alone), and `.venv/bin`
    linked to this interpreter's environment. `mlflow ui` serves until stopped, so its command
    line is checked with `--help` instead, and the runs it would show are looked up afterwards."""
    repository = copy_repository(tmp_path)
    params = tiny_params_tree()
    write_params(params, repository / "params.yaml")
    subprocess.run([*GIT, "commit", "--quiet", "--all", "--message", "Tiny params"], cwd=repository, check=True)
    (repository / ".venv").mkdir()
    (repository / ".venv" / "bin").symlink_to(Path(sys.executable).parent)
    script, servers = re.subn(r"^mlflow ui .*$", "mlflow ui --help > /dev/null",
                              walkthrough_script((repository / "README.md").read_text()), flags=re.MULTILINE)
    assert servers == 1

    identity = {"GIT_AUTHOR_NAME": "test", "GIT_AUTHOR_EMAIL": "test@example.invalid",
                "GIT_COMMITTER_NAME": "test", "GIT_COMMITTER_EMAIL": "test@example.invalid"}  # the baseline commit
    result = subprocess.run(["bash", "-e", "-x", "-c", script], cwd=repository, env={**environment(), **identity},
                            capture_output=True, text=True)
    assert result.returncode == 0, f"the walkthrough failed at the last '+' command:\n{result.stderr[-6000:]}"
    page = (repository / "dvc_plots" / "index.html").read_text()  # readable offline: no script fetched
    assert "vegaEmbed('#network_loss_per_epoch'" in page and "<script src" not in page and "cdn." not in page
    untracked = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=repository,
                               capture_output=True, text=True, check=True).stdout
    assert not [line for line in untracked.splitlines() if line.startswith("??")], untracked  # outputs ignored

    moved = metrics_moved(repository)
    assert moved, "the experiment moved no metric"
    assert not {"reports/data.json", "reports/windows.json", "reports/kalman_tuning.json",
                "reports/models/filter.json", "reports/models/autoencoder.json"} & set(moved)  # upstream of it
    classical = ("kalman_cv", "kalman_ca", "imm", "plots_reference", "oracle_reference")
    assert not [(file, key) for file, keys in moved.items() for key in keys
                if any(f".{name}" in key for name in classical) or "per_second" in key or "seconds" in key]

    client = mlflow.MlflowClient(f"sqlite:///{repository / 'mlflow.db'}")
    experiment = client.get_experiment_by_name(params["training"]["experiment"])
    names = {run.info.run_name for run in client.search_runs([experiment.experiment_id])}
    assert {"train_filter", "train_predictor", "train_autoencoder", "evaluate"} <= names


def metrics_moved(repository: Path) -> dict[str, list[str]]:
    """`dvc metrics diff` of the workspace (the experiment) against the baseline commit: file -> the keys it
    lists as changed. The issue's goal: only what the experiment moved, so neither a classical tracker's figure
    (the predictor is not in it; the same bits on the same machine) nor a timing, nor a stage upstream of it."""
    result = subprocess.run([str(Path(sys.executable).parent / "dvc"), "metrics", "diff", "--json"], cwd=repository,
                            env=environment(), capture_output=True, text=True, check=True)
    diff = json.loads(result.stdout or "{}")
    return {file: sorted(keys) for file, keys in diff.items() if keys}


def test_thesis_schedule_command_sets_the_thesis_schedule(params_tree) -> None:
    """The one command for the thesis's schedule (docs/networks.md, "Training schedule"), applied as
    `dvc exp run -S` applies it, gives valid params with the thesis's epochs, batches and learning
    rate, and neither early stopping nor learning-rate decay."""
    page = (REPOSITORY / "docs" / "networks.md").read_text()
    match = re.search(r"<!-- thesis-schedule -->\s*```bash\n(.*?)\n```", page, re.DOTALL)
    assert match, "docs/networks.md has no ```bash block after <!-- thesis-schedule -->"
    command = match.group(1).replace("\\\n", " ")
    assert command.split()[:3] == ["dvc", "exp", "run"]
    for dotted, value in re.findall(r"-S (\S+)=(\S+)", command):
        *parents, key = dotted.split(".")
        node = params_tree
        for parent in parents:
            node = node[parent]
        assert key in node, f"{dotted}: not a key of params.yaml"
        node[key] = yaml.load(value, Loader=ParamsLoader)  # DVC reads a -S value as YAML 1.2
    networks = parse_params(params_tree).training.networks
    thesis = {"filter": (500, 128), "predictor": (500, 128), "autoencoder": (400, 64)}
    for kind, (epochs, batch) in thesis.items():
        network = networks[kind]
        assert (network.epochs, network.batch_size, network.learning_rate) == (epochs, batch, 0.001)
        assert network.early_stopping_patience == network.lr_decay_patience == 0

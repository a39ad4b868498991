"""MLflow runs as a user finds them in the store: a run whose stage was killed does not stay RUNNING;
the runs of a queued experiment are in the repository's store, and a workspace's runs keep their
artifacts in that workspace."""

from __future__ import annotations

import logging
import shutil
import subprocess
import sys
from pathlib import Path
from urllib.parse import urlparse

import mlflow
import pytest

from pipeline.learning.experiment_tracking import (
    EXPERIMENT_KIND_TAG,
    MODEL_TRAINING,
    TrackingError,
    check_tracking_store,
    run_tags,
    session,
    tracking_uri,
)
from pipeline.settings import parse_params
from tests.project import environment
from tests.servers import run_queue

EXPERIMENT = "radar-nn-tracker"


def _running_run(client: mlflow.MlflowClient, experiment_id: str, stage: str, **changes: str) -> str:
    """A RUNNING run tagged as `stage` tags it, with some tags changed (pid, host): what a stage
    killed with SIGKILL leaves behind, or what a stage still going shows."""
    return client.create_run(experiment_id, tags={**run_tags(stage), **changes}, run_name=stage).info.run_id


def test_a_stage_start_marks_killed_the_runs_its_killed_predecessors_left_running(tmp_path: Path, caplog) -> None:
    """When train_filter starts, a RUNNING train_filter run of this host whose process is gone is
    marked KILLED, with one log line naming it; a run whose process still runs, a run of another
    host (whose pids mean nothing here) and a run of another stage are left as they are."""
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    client = mlflow.MlflowClient(tracking_uri=uri)
    experiment_id = client.create_experiment(EXPERIMENT, artifact_location=str(tmp_path / "mlruns"))
    finished = subprocess.Popen([sys.executable, "-c", "pass"])
    finished.wait()
    still_going = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        killed = _running_run(client, experiment_id, "train_filter", pid=str(finished.pid))
        live = _running_run(client, experiment_id, "train_filter", pid=str(still_going.pid))
        elsewhere = _running_run(client, experiment_id, "train_filter", pid=str(finished.pid), host="another-host")
        other_stage = _running_run(client, experiment_id, "evaluate", pid=str(finished.pid))
        with caplog.at_level(logging.INFO, logger="pipeline"):
            check_tracking_store(uri, EXPERIMENT, "train_filter")
    finally:
        still_going.kill()
        still_going.wait()
    status = {run_id: client.get_run(run_id).info.status for run_id in (killed, live, elsewhere, other_stage)}
    assert status == {killed: "KILLED", live: "RUNNING", elsewhere: "RUNNING", other_stage: "RUNNING"}
    assert client.get_run(killed).info.end_time is not None
    closing = [record.getMessage() for record in caplog.records if "KILLED" in record.getMessage()]
    assert len(closing) == 1 and killed in closing[0] and str(finished.pid) in closing[0]


def test_a_relative_store_is_the_repositorys_also_in_dvcs_temporary_copy(tmp_path: Path, monkeypatch) -> None:
    """DVC runs a queued or `--temp` experiment in a copy of the repository under
    .dvc/tmp/exps/, deletes the copy afterwards, and sets DVC_ROOT to the repository the
    experiment came from: a relative store (params' `sqlite:///mlflow.db`) is that repository's,
    where the runs outlive the copy."""
    repository = tmp_path / "repository"
    copy = repository / ".dvc" / "tmp" / "exps" / "tmpa1b2c3"
    (copy / ".dvc").mkdir(parents=True)
    monkeypatch.chdir(copy)
    monkeypatch.setenv("DVC_ROOT", str(repository))
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    assert tracking_uri("sqlite:///mlflow.db") == f"sqlite:///{repository / 'mlflow.db'}"
    assert tracking_uri("sqlite:///runs/mlflow.db?timeout=30") == f"sqlite:///{repository}/runs/mlflow.db?timeout=30"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "file:mlruns")  # a file store, named by the user
    assert tracking_uri("sqlite:///mlflow.db") == (repository / "mlruns").as_uri()


def test_a_relative_store_of_a_stage_in_the_repository_itself_is_where_the_stage_runs(tmp_path: Path,
                                                                                       monkeypatch) -> None:
    """`dvc repro` sets DVC_ROOT to the repository it runs in; without DVC (a stage's command typed
    by hand) there is none. Either way the relative store is in the current folder, and an
    absolute one or a server is left as it is."""
    repository = tmp_path / "repository"
    (repository / ".dvc").mkdir(parents=True)
    monkeypatch.chdir(repository)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    for dvc_root in (str(repository), None):
        if dvc_root is None:
            monkeypatch.delenv("DVC_ROOT", raising=False)
        else:
            monkeypatch.setenv("DVC_ROOT", dvc_root)
        assert tracking_uri("sqlite:///mlflow.db") == f"sqlite:///{repository / 'mlflow.db'}"
        assert tracking_uri("sqlite:////srv/mlflow/team.db") == "sqlite:////srv/mlflow/team.db"
        assert tracking_uri("http://mlflow.example.org:5000") == "http://mlflow.example.org:5000"


LOG_RUN = '''\
"""A stage that logs one MLflow run as the pipeline's stages do, its params and one artifact."""
import mlflow
import yaml

from pipeline.learning.experiment_tracking import check_tracking_store, run_tags, tracking_uri

uri = tracking_uri("sqlite:///mlflow.db")
check_tracking_store(uri, "radar-nn-tracker", "log_run")
mlflow.set_tracking_uri(uri)
mlflow.set_experiment("radar-nn-tracker")
with mlflow.start_run(run_name="log_run", tags=run_tags("log_run")):
    mlflow.log_params(yaml.safe_load(open("params.yaml")))
    mlflow.log_artifact("params.yaml")
'''


def _repository_with_a_logging_stage(folder: Path) -> tuple[Path, dict[str, str]]:
    """A committed DVC repository whose one stage logs a run as the pipeline's stages do, and the
    environment to run DVC in (no MLFLOW_TRACKING_URI: the stage's relative store decides)."""
    repository = folder / "repository"
    repository.mkdir()
    (repository / "log_run.py").write_text(LOG_RUN)
    (repository / "params.yaml").write_text("learning_rate: 0.001\n")
    (repository / "dvc.yaml").write_text("stages:\n  log_run:\n    cmd: python log_run.py\n"
                                         "    deps: [log_run.py]\n    params: [learning_rate]\n")
    (repository / ".gitignore").write_text("/mlflow.db\n/mlruns/\n")
    env = {**environment(), "GIT_AUTHOR_NAME": "test", "GIT_AUTHOR_EMAIL": "test@example.invalid",
           "GIT_COMMITTER_NAME": "test", "GIT_COMMITTER_EMAIL": "test@example.invalid"}
    env.pop("MLFLOW_TRACKING_URI", None)
    for command in (["git", "init", "-q"], [sys.executable, "-m", "dvc", "init", "-q"],
                    ["git", "add", "-A"], ["git", "commit", "-q", "-m", "a stage that logs a run"]):
        _run(command, repository, env)
    return repository, env


def _run(command: list[str], repository: Path, env: dict[str, str]) -> str:
    result = subprocess.run(command, cwd=repository, env=env, capture_output=True, text=True)
    assert result.returncode == 0, f"{' '.join(command)}:\n{result.stdout}\n{result.stderr[-3000:]}"
    return result.stdout


def _repository_runs(repository: Path) -> list[mlflow.entities.Run]:
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{repository / 'mlflow.db'}")
    experiment = client.get_experiment_by_name(EXPERIMENT)
    assert experiment is not None, "no run reached the repository's mlflow.db"
    return client.search_runs([experiment.experiment_id])


def test_an_experiment_dvc_runs_in_a_temporary_copy_logs_to_the_repositorys_store(tmp_path: Path) -> None:
    """`dvc exp run --temp` (what `dvc queue start` does for each queued experiment) runs the
    stage in .dvc/tmp/exps/ and deletes that copy: its run, params and artifact are in the
    repository's mlflow.db and mlruns/ afterwards."""
    repository, env = _repository_with_a_logging_stage(tmp_path)
    _run([sys.executable, "-m", "dvc", "exp", "run", "--temp", "-S", "learning_rate=0.002"], repository, env)
    runs = _repository_runs(repository)
    assert [run.data.params["learning_rate"] for run in runs] == ["0.002"]
    artifacts = _local_path(runs[0].info.artifact_uri)
    assert artifacts.is_relative_to(repository / "mlruns") and (artifacts / "params.yaml").is_file()


def test_two_queued_experiments_run_two_at_a_time_both_log_to_the_repositorys_store(tmp_path: Path) -> None:
    """The sweep of docs/networks.md: `dvc exp run --queue -S 'learning_rate=0.002,0.003'` queues two
    experiments, `dvc queue start -j 2` runs them in two workers at once, each in its own
    temporary copy, on a store neither has created yet: both runs are in the repository's store,
    each with its params."""
    repository, env = _repository_with_a_logging_stage(tmp_path)
    _run([sys.executable, "-m", "dvc", "exp", "run", "--queue", "-S", "learning_rate=0.002,0.003"], repository, env)
    run_queue(repository, workers=2)
    assert sorted(run.data.params["learning_rate"] for run in _repository_runs(repository)) == ["0.002", "0.003"]


def _local_path(artifact_uri: str) -> Path:
    """The folder of a local artifact URI, which MLflow writes as a path or a file: URI."""
    return Path(urlparse(artifact_uri).path)


def _log_run_with_artifact(uri: str, artifact: Path) -> str:
    """One run of a stage in the store at `uri`, checked first as every stage does; its id."""
    check_tracking_store(uri, EXPERIMENT, "train_filter")
    client = mlflow.MlflowClient(tracking_uri=uri)
    run_id = _running_run(client, client.get_experiment_by_name(EXPERIMENT).experiment_id, "train_filter")
    client.log_artifact(run_id, str(artifact))
    client.set_terminated(run_id)
    return run_id


def test_a_new_store_keeps_its_runs_artifacts_beside_it_wherever_the_stage_runs(tmp_path: Path, monkeypatch) -> None:
    """The first stage to use a SQLite store creates the experiment with its artifacts in the
    store's folder, not in ./mlruns of the folder the stage happens to run in."""
    store, elsewhere = tmp_path / "workspace", tmp_path / "elsewhere"
    store.mkdir()
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    model = tmp_path / "filter.pt"
    model.write_bytes(b"weights")
    uri = f"sqlite:///{store / 'mlflow.db'}"
    run_id = _log_run_with_artifact(uri, model)
    artifacts = _local_path(mlflow.MlflowClient(tracking_uri=uri).get_run(run_id).info.artifact_uri)
    assert artifacts.is_relative_to(store / "mlruns") and (artifacts / "filter.pt").read_bytes() == b"weights"
    assert list(elsewhere.iterdir()) == []


def test_a_copied_store_is_refused_naming_both_folders_before_writing_into_the_original(tmp_path: Path) -> None:
    """A workspace copied with its mlflow.db and mlruns/ (cp -a, rsync, a backup restored
    elsewhere): MLflow recorded the experiment's artifact location as the original folder's
    mlruns/, so a new run of the copy would write its model file there. The stage stops instead,
    naming the copy's store, the original folder and the way out; the original goes on as before."""
    original, copy = tmp_path / "original", tmp_path / "copy"
    original.mkdir()
    model = tmp_path / "filter.pt"
    model.write_bytes(b"weights")
    _log_run_with_artifact(f"sqlite:///{original / 'mlflow.db'}", model)
    shutil.copytree(original, copy)
    before = sorted(path for path in (original / "mlruns").rglob("*"))

    with pytest.raises(TrackingError) as refused:
        check_tracking_store(f"sqlite:///{copy / 'mlflow.db'}", EXPERIMENT, "train_filter")
    message = str(refused.value)
    assert f"keeps its runs' artifacts in {original / 'mlruns'}" in message
    assert f"outside {copy}, the store's folder" in message
    assert f"move {copy / 'mlflow.db'} aside" in message
    assert sorted(path for path in (original / "mlruns").rglob("*")) == before
    _log_run_with_artifact(f"sqlite:///{original / 'mlflow.db'}", model)


def test_the_experiment_is_marked_as_model_training_so_the_ui_opens_on_its_runs(tmp_path: Path) -> None:
    """MLflow 3's UI opens an experiment without a kind on its GenAI overview. A new experiment is
    created marked `custom_model_development`; one made before (no kind, or a kind the UI only
    inferred) is marked when a stage next starts; a kind a user chose is kept."""
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    client = mlflow.MlflowClient(tracking_uri=uri)
    check_tracking_store(uri, EXPERIMENT, "train_filter")
    assert client.get_experiment_by_name(EXPERIMENT).tags[EXPERIMENT_KIND_TAG] == MODEL_TRAINING
    for kind, kept in ((None, MODEL_TRAINING), ("genai_development_inferred", MODEL_TRAINING),
                       ("finetuning", "finetuning")):
        name = f"older-{kind}"
        older = client.create_experiment(name, artifact_location=str(tmp_path / "mlruns" / name))
        if kind is not None:
            client.set_experiment_tag(older, EXPERIMENT_KIND_TAG, kind)
        check_tracking_store(uri, name, "train_filter")
        assert client.get_experiment(older).tags[EXPERIMENT_KIND_TAG] == kept, kind


def test_stages_of_one_experiment_share_its_name_as_session_and_a_repro_its_code_and_params(
        params_tree, monkeypatch) -> None:
    """`pipeline.session`: DVC's experiment name inside `dvc exp run`; otherwise the same for the
    same code and params, and another for other params."""
    params = parse_params(params_tree)
    monkeypatch.setenv("DVC_EXP_NAME", "wider-predictor")
    assert session(params) == "wider-predictor"
    monkeypatch.delenv("DVC_EXP_NAME")
    repro = session(params)
    assert repro.startswith("repro-") and repro == session(parse_params(params_tree))
    params_tree["training"]["predictor"]["hidden"] = [64, 64]
    assert session(parse_params(params_tree)) != repro


def test_two_stages_started_at_once_on_a_fresh_store_both_log_their_run(tmp_path: Path) -> None:
    """Two stages of parallel experiments start together on a store that does not exist yet: both
    create it and the experiment without failing (MLflow's first-use migration is not safe for two
    processes at once), and both runs are there with their params."""
    repository = tmp_path / "repository"
    repository.mkdir()
    (repository / "log_run.py").write_text(LOG_RUN)
    (repository / "params.yaml").write_text("learning_rate: 0.001\n")
    env = {**environment(), "DVC_ROOT": str(repository)}
    env.pop("MLFLOW_TRACKING_URI", None)
    stages = [subprocess.Popen([sys.executable, "log_run.py"], cwd=repository, env=env, stderr=subprocess.PIPE,
                               text=True) for _ in range(2)]
    errors = [stage.communicate()[1] for stage in stages]
    assert [stage.returncode for stage in stages] == [0, 0], "\n".join(error[-2000:] for error in errors)
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{repository / 'mlflow.db'}")
    runs = client.search_runs([client.get_experiment_by_name(EXPERIMENT).experiment_id])
    assert len(runs) == 2 and all(run.data.params["learning_rate"] == "0.001" for run in runs)


def test_a_training_run_is_failed_when_its_stage_raises_and_finished_otherwise(tmp_path: Path, make_params) -> None:
    """`training_run`, as every training stage opens its run: the run and a Lightning logger bound to it; a
    stage body that raises (even KeyboardInterrupt) leaves the run FAILED and the error goes on, one that
    returns leaves it FINISHED with what the logger logged."""
    from pipeline.learning.tracking_logger import training_run
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    params = make_params(1, {"training.tracking_uri": uri})
    with training_run(params, "train_lstm_update", "train-lstm-update", {}, "nothing") as (run, logger):
        assert logger.run_id == run.info.run_id
        logger.log_hyperparams({"lstm_update.hidden": params.lstm_update.hidden})
        finished = run.info.run_id
    for error in (RuntimeError("training diverged"), KeyboardInterrupt()):
        with pytest.raises(type(error)):
            with training_run(params, "train_lstm_update", "train-lstm-update", {}, "nothing") as (run, _):
                failed = run.info.run_id
                raise error
        assert mlflow.MlflowClient(tracking_uri=uri).get_run(failed).info.status == "FAILED"
    client = mlflow.MlflowClient(tracking_uri=uri)
    assert client.get_run(finished).info.status == "FINISHED"
    assert client.get_run(finished).data.params["lstm_update.hidden"] == str(params.lstm_update.hidden)
    assert client.get_run(finished).data.tags["mlflow.source.name"] == "python -m pipeline train-lstm-update"

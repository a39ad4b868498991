"""MLflow: where runs go, and the tags that tie a run to its code and data.

By default runs go to a SQLite file in the repository (`sqlite:///mlflow.db`, see
`tracking.uri` in params.yaml); the environment variable MLFLOW_TRACKING_URI points them
at a team server instead, with no other change. The store is checked before any training
starts, so an unreachable server fails in seconds with its address in the message rather
than after an hour of training.

A stage killed outright (SIGKILL, the OOM killer, power loss) cannot end its run, which would
stay RUNNING for good. Every run is tagged with the host and pid of the process behind it, and
when a stage starts it marks KILLED the RUNNING runs of the same stage on this host whose
process is gone.
"""

from __future__ import annotations

import hashlib
import logging
import os
import socket
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.io import InputError, process_alive

if TYPE_CHECKING:
    from mlflow import MlflowClient

log = logging.getLogger("pipeline")


class TrackingError(RuntimeError):
    """The MLflow tracking store cannot be used; the message names the URI."""


def tracking_uri(default: str) -> str:
    return os.environ.get("MLFLOW_TRACKING_URI") or default


def check_tracking_store(uri: str, experiment: str, stage: str) -> None:
    """Fail fast, naming the URI, if the store cannot be reached or written; then close the runs
    of `stage` that killed processes on this host left RUNNING."""
    os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0")
    os.environ.setdefault("MLFLOW_HTTP_REQUEST_TIMEOUT", "10")
    import mlflow

    try:
        client = mlflow.MlflowClient(tracking_uri=uri)
        found = client.get_experiment_by_name(experiment)
        experiment_id = found.experiment_id if found else client.create_experiment(experiment)
        _close_killed_runs(client, experiment_id, stage)
    except Exception as error:  # mlflow raises many types for an unreachable or broken store
        raise TrackingError(f"MLflow tracking store {uri!r} cannot be used: {type(error).__name__}: "
                            f"{str(error).splitlines()[0] if str(error) else ''}") from None


def run_tags(stage: str) -> dict[str, str]:
    """The tags of a stage's run: the stage, the commit of the code, and the host and pid of the
    process, by which a later start of the stage tells a killed run from one still going."""
    return {"stage": stage, "git_commit": git_commit(), "host": socket.gethostname(), "pid": str(os.getpid())}


def _close_killed_runs(client: MlflowClient, experiment_id: str, stage: str) -> None:
    """Mark KILLED the RUNNING runs of `stage` on this host whose process no longer runs.

    Only this host's runs: a pid means nothing on another machine, whose runs may be going on."""
    host = socket.gethostname()
    running = client.search_runs([experiment_id], filter_string=f"tags.stage = '{stage}' and tags.host = '{host}' "
                                                                "and attributes.status = 'RUNNING'")
    for run in running:
        pid = run.data.tags.get("pid", "")
        if pid.isdigit() and not process_alive(int(pid)):
            client.set_terminated(run.info.run_id, "KILLED")
            log.warning("MLflow run %s (%s, pid %s on %s) was left RUNNING by a process that is gone: marked KILLED",
                        run.info.run_id, stage, pid, host)


CODE_DIRECTORY = Path(__file__).resolve().parent


def git_commit(repository: Path = CODE_DIRECTORY) -> str:
    """The commit of the code that runs (not of the working directory), '-dirty' if changed."""
    result = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repository, capture_output=True, text=True)
    if result.returncode != 0:
        return "unknown"
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=repository,
                           capture_output=True, text=True).stdout.strip()
    return result.stdout.strip() + ("-dirty" if dirty else "")


def data_hash(*paths: Path) -> str:
    """SHA-256 over the input files' names and bytes, in order."""
    digest = hashlib.sha256()
    for path in paths:
        if not path.is_file():
            raise InputError(f"{path}: file not found")
        digest.update(path.name.encode())
        with path.open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()

"""MLflow: where runs go, and the tags that tie a run to its code and data.

By default runs go to a SQLite file in the repository (`sqlite:///mlflow.db`, see
`tracking.uri` in params.yaml); the environment variable MLFLOW_TRACKING_URI points them
at a team server instead, with no other change. The store is checked before any training
starts, so an unreachable server fails in seconds with its address in the message rather
than after an hour of training.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
from pathlib import Path

from pipeline.io import InputError

class TrackingError(RuntimeError):
    """The MLflow tracking store cannot be used; the message names the URI."""


def tracking_uri(default: str) -> str:
    return os.environ.get("MLFLOW_TRACKING_URI") or default


def check_tracking_store(uri: str, experiment: str) -> None:
    """Fail fast, naming the URI, if the store cannot be reached or written."""
    os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0")
    os.environ.setdefault("MLFLOW_HTTP_REQUEST_TIMEOUT", "10")
    import mlflow

    try:
        client = mlflow.MlflowClient(tracking_uri=uri)
        if client.get_experiment_by_name(experiment) is None:
            client.create_experiment(experiment)
    except Exception as error:  # mlflow raises many types for an unreachable or broken store
        raise TrackingError(f"MLflow tracking store {uri!r} cannot be used: {type(error).__name__}: "
                            f"{str(error).splitlines()[0] if str(error) else ''}") from None


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

"""MLflow: where runs go, and the tags that tie a run to its code and data.

By default runs go to a SQLite file in the repository (`sqlite:///mlflow.db`, see
`tracking.uri` in params.yaml); the environment variable MLFLOW_TRACKING_URI points them
at a team server instead, with no other change. The store is checked before any training
starts, so an unreachable server fails in seconds with its address in the message rather
than after an hour of training.

A store kept on this machine (a SQLite file, or MLflow's file store) holds its runs' artifacts
beside itself, so that a workspace's runs, with their model files, stay in that workspace:
- a relative path in its URI is the repository's, also for the stages of a queued or `--temp`
  experiment, which DVC runs in a temporary copy of the repository that it deletes afterwards
  (mlflow.db is git-ignored, so the copy has none: runs logged there would be lost);
- the experiment is created with its artifact location in the store's folder, wherever the
  stage runs from (MLflow's default is `./mlruns` of the current folder);
- an experiment whose artifact location is elsewhere (the store was copied from another folder,
  and MLflow records absolute paths) is refused, naming both folders: its new runs would write
  their model files into the other folder, and MLflow cannot move an experiment's location.

A stage killed outright (SIGKILL, the OOM killer, power loss) cannot end its run, which would
stay RUNNING for good. Every run is tagged with the host and pid of the process behind it, and
when a stage starts it marks KILLED the RUNNING runs of the same stage on this host whose
process is gone.

Several stages may start at once on a store that does not exist yet (`dvc queue start -j 2`,
`dvc exp run --run-all -j 2`): MLflow creates a SQLite store's tables and the experiment on
first use, and two processes doing that together fail (an alembic migration that finds its row
gone; an experiment that already exists). Stages on one local store take turns for that first
step, under a lock on the store's folder, and an experiment another stage created meanwhile is
used as it is.

A store that goes away during a stage (a SQLite file removed or locked, a server that stops
answering) does not cost the stage its outputs. Every write of a run is retried a bounded number of
times (`write_to_store`: a local store `LOCAL_STORE_ATTEMPTS` times; a server by MLflow's own HTTP
retries, MLFLOW_HTTP_REQUEST_MAX_RETRIES and MLFLOW_HTTP_REQUEST_TIMEOUT, `RUN_HTTP_SETTINGS` unless
set); when one still fails, a warning names the store and the run's later writes are skipped
(`tracking_logger.TrainingLogger`), the training goes on and writes its model and reports (atomically, as always),
and the stage then ends with a TrackingError naming the URI and the outputs written (exit 2).

What the UI groups by: every run is tagged `pipeline.session`, the same for every stage of one
`dvc exp run` (DVC's experiment name, which DVC passes to the stages in DVC_EXP_NAME) and, for a
plain `dvc repro` or a stage run by hand, for every stage of the same code and params
(`repro-<commit>-<params digest>`): DVC gives a plain repro no name, and a rerun of the same code
on the same params is the same configuration. The experiment is marked as model training
(`mlflow.experimentKind`), its kind for MLflow's API and for the UIs of MLflow 3 that open an
experiment by its kind; the UI of MLflow 3.17 goes by the view in its address
(`?workflowType=machine_learning`, which the README's address has) or the one the browser last
chose, and opens a new browser on the GenAI overview, which has no runs table.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import logging
import os
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import unquote, urlparse
from urllib.request import pathname2url

from pipeline.io import InputError, process_alive

if TYPE_CHECKING:
    from mlflow import ActiveRun, MlflowClient

    from pipeline.params import Params

log = logging.getLogger("pipeline")

EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
MODEL_TRAINING = "custom_model_development"  # MLflow 3's kind of a model-training experiment
SESSION_TAG = "pipeline.session"
DVC_EXPERIMENT_TAG = "dvc.experiment"


LOCAL_STORE_ATTEMPTS = 3       # tries of a write to a SQLite or file store (a lock held by another process) ...
LOCAL_STORE_BACKOFF_S = 1.0    # ... waiting this, then twice this, between them
CHECK_HTTP_SETTINGS = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0", "MLFLOW_HTTP_REQUEST_TIMEOUT": "10"}  # fail fast
RUN_HTTP_SETTINGS = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "3", "MLFLOW_HTTP_REQUEST_TIMEOUT": "30"}  # 2, 4, 8 s apart


class TrackingError(RuntimeError):
    """The MLflow tracking store cannot be used; the message names the URI."""


def _first_line(error: BaseException) -> str:
    return f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"


MLFLOW_SQL_LOGGER = "mlflow.store.db.utils"  # logs every failed SQL statement with its traceback


@contextmanager
def _quiet(name: str) -> Iterator[None]:
    """The logger `name` silent for the block: the failure is reported once, by the caller."""
    logger = logging.getLogger(name)
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


def write_to_store(uri: str, what: str, call: Callable[..., Any], *arguments: Any, **keywords: Any) -> Any:
    """`call(*arguments, **keywords)`, a write to the store at `uri`, retried: a local store's up to
    LOCAL_STORE_ATTEMPTS times, 1 s then 2 s apart; a server's once (MLflow retries its HTTP requests
    itself, `RUN_HTTP_SETTINGS`). TrackingError naming the URI and `what` when the last try fails."""
    attempts = LOCAL_STORE_ATTEMPTS if _local_store_path(uri) is not None else 1
    for attempt in range(attempts):
        try:
            with _quiet(MLFLOW_SQL_LOGGER):
                return call(*arguments, **keywords)
        except Exception as error:  # mlflow, SQLAlchemy and requests raise many types for a store gone
            if attempt + 1 == attempts:
                tries = f" (tried {attempts} times)" if attempts > 1 else ""
                raise TrackingError(f"MLflow tracking store {uri!r} failed while {what}{tries}: "
                                    f"{_first_line(error)}") from None
            time.sleep(LOCAL_STORE_BACKOFF_S * 2 ** attempt)
    raise AssertionError("unreachable")


def tracking_uri(default: str) -> str:
    """MLFLOW_TRACKING_URI, else `default`; a local store's relative path made absolute in the
    repository the stage belongs to, not in DVC's temporary copy of it."""
    uri = os.environ.get("MLFLOW_TRACKING_URI") or default
    path = _local_store_path(uri)
    if path is None or path.is_absolute():
        return uri
    absolute = _in_original_repository(Path.cwd().resolve() / path)
    if uri.startswith("sqlite:"):
        return "sqlite:///" + pathname2url(str(absolute)) + "".join(uri.partition("?")[1:])
    return absolute.as_uri()


def _local_store_path(uri: str) -> Path | None:
    """The SQLite file or file-store folder of a store on this machine, as the URI writes it
    (relative or not); None for a server or an in-memory database."""
    if uri.startswith("sqlite:///"):
        path = unquote(uri[len("sqlite:///"):].partition("?")[0])
        return Path(path) if path not in ("", ":memory:") else None
    parsed = urlparse(uri)
    if parsed.scheme == "file" and parsed.netloc in ("", "localhost"):
        return Path(unquote(parsed.path))
    return Path(uri) if parsed.scheme == "" else None


def _in_original_repository(path: Path) -> Path:
    """`path`, if it lies in a temporary copy DVC made of the repository to run an experiment
    (queued, or `--temp`), moved to the same place in the repository the copy was made from.

    In a stage's command DVC sets DVC_ROOT to the root of the repository that ran or queued it,
    also in a temporary copy; the stage's own repository is the nearest folder up with a `.dvc`
    folder. When they differ, the stage runs in a copy."""
    original = os.environ.get("DVC_ROOT")
    here = Path.cwd().resolve()
    workspace = next((folder for folder in (here, *here.parents) if (folder / ".dvc").is_dir()), None)
    if not original or workspace is None or workspace == Path(original).resolve():
        return path
    return Path(os.path.normpath(Path(original).resolve() / os.path.relpath(path, workspace)))


def _store_folder(uri: str) -> Path | None:
    """The folder a store on this machine keeps its runs' artifacts in: the SQLite file's
    folder, or the file store itself; None for a server."""
    path = _local_store_path(uri)
    if path is None:
        return None
    return path.absolute().parent if uri.startswith("sqlite:") else path.absolute()


def check_tracking_store(uri: str, experiment: str, stage: str) -> None:
    """Fail fast, naming the URI, if the store cannot be reached or written, or if it would put
    the runs' artifacts outside a local store's folder; then close the runs of `stage` that
    killed processes on this host left RUNNING."""
    import mlflow

    folder = _store_folder(uri)
    try:
        with _http_settings(CHECK_HTTP_SETTINGS):
            with _first_use_lock(folder):
                client = mlflow.MlflowClient(tracking_uri=uri)
                found = client.get_experiment_by_name(experiment)
                if found is None:
                    experiment_id = _create_experiment(client, experiment, folder, uri)
                else:
                    experiment_id = found.experiment_id
                    if folder is not None:
                        _check_artifacts_in_store_folder(uri, folder, experiment, found.artifact_location)
                    if _needs_kind(found.tags.get(EXPERIMENT_KIND_TAG)):
                        client.set_experiment_tag(experiment_id, EXPERIMENT_KIND_TAG, MODEL_TRAINING)
            _close_killed_runs(client, experiment_id, stage)
    except TrackingError:
        raise
    except Exception as error:  # mlflow raises many types for an unreachable or broken store
        raise TrackingError(f"MLflow tracking store {uri!r} cannot be used: {_first_line(error)}") from None
    for name, value in RUN_HTTP_SETTINGS.items():
        os.environ.setdefault(name, value)


@contextmanager
def _http_settings(settings: dict[str, str]) -> Iterator[None]:
    """MLflow's HTTP settings `settings` for the block, where the environment does not set them (MLflow reads
    them at every request), then as they were: the check fails fast, the run's writes are retried."""
    unset = [name for name in settings if name not in os.environ]
    os.environ.update({name: settings[name] for name in unset})
    try:
        yield
    finally:
        for name in unset:
            os.environ.pop(name, None)


@contextmanager
def _first_use_lock(folder: Path | None) -> Iterator[None]:
    """Hold an exclusive lock on a local store's folder (none for a server, which serialises its
    own first use): the stages of parallel experiments create the store and the experiment one
    at a time. A lock on the folder, not on a file in it, leaves nothing behind in the
    repository; the kernel releases it if the process dies."""
    if folder is None:
        yield
        return
    folder.mkdir(parents=True, exist_ok=True)
    handle = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX)
        yield
    finally:
        os.close(handle)  # releases the lock


def _create_experiment(client: MlflowClient, experiment: str, folder: Path | None, uri: str) -> str:
    """Create the experiment, marked as model training; if another process (on a server, which
    the folder lock does not cover) created it meanwhile, use that one."""
    # A SQLite store's default would be ./mlruns of wherever this stage runs from.
    location = str(folder / "mlruns" / experiment) if uri.startswith("sqlite:") else None
    try:
        return client.create_experiment(experiment, artifact_location=location,
                                        tags={EXPERIMENT_KIND_TAG: MODEL_TRAINING})
    except Exception:
        found = client.get_experiment_by_name(experiment)
        if found is None:
            raise
        return found.experiment_id


def _needs_kind(kind: str | None) -> bool:
    """An experiment made before the pipeline marked its kind, or whose kind only the UI guessed
    (MLflow writes `..._inferred` or `no_inferred_type`), is marked; a kind a user chose is kept."""
    return kind is None or kind.endswith("_inferred") or kind == "no_inferred_type"


def _check_artifacts_in_store_folder(uri: str, folder: Path, experiment: str, location: str) -> None:
    """Refuse a local store whose experiment keeps its artifacts outside the store's folder.

    MLflow records the experiment's artifact location as an absolute path when it creates the
    experiment, and derives every new run's from it: in a copy of a workspace (cp -a, rsync, a
    backup restored elsewhere) the copied store would send new runs' model files into the
    original folder, or fail if that is gone. The location cannot be changed afterwards, so the
    stage stops, before any training, with the three ways out."""
    parsed = urlparse(location)
    if parsed.scheme not in ("", "file"):
        return  # an artifact server or a bucket: reached the same way from every copy
    artifacts = Path(unquote(parsed.path) if parsed.scheme == "file" else location)
    if artifacts.resolve().is_relative_to(folder.resolve()):
        return
    store = _local_store_path(uri).absolute()
    raise TrackingError(
        f"MLflow tracking store {uri!r}: experiment {experiment!r} keeps its runs' artifacts in {artifacts}, "
        f"outside {folder}, the store's folder (the store was copied from another folder?): new runs would write "
        f"their model files there. Log to the store it was copied from (set MLFLOW_TRACKING_URI to it), to a new "
        f"experiment of this store (a new training.experiment in params.yaml), or to a new store here "
        f"(move {store} aside)")


def run_tags(stage: str) -> dict[str, str]:
    """The tags of a stage's run: the stage, the commit of the code, and the host and pid of the
    process, by which a later start of the stage tells a killed run from one still going."""
    return {"stage": stage, "git_commit": git_commit(), "host": socket.gethostname(), "pid": str(os.getpid())}


def dvc_experiment() -> str | None:
    """The name of the DVC experiment this stage runs in (`dvc exp run`, queued or not), or None."""
    return os.environ.get("DVC_EXP_NAME") or None


def session(params: Params) -> str:
    """The value of the `pipeline.session` tag: the DVC experiment's name, else one name for the
    same code on the same params (see the module's docstring)."""
    named = dvc_experiment()
    if named:
        return named
    digest = hashlib.sha256(json.dumps(asdict(params), sort_keys=True, default=str).encode()).hexdigest()
    return f"repro-{git_commit()[:12]}-{digest[:8]}"


def session_tags(params: Params) -> dict[str, str]:
    """The tags every stage's run carries to say which session made it: `pipeline.session`, and
    DVC's experiment name inside `dvc exp run`."""
    named = dvc_experiment()
    return {SESSION_TAG: session(params), **({DVC_EXPERIMENT_TAG: named} if named else {})}


@contextmanager
def stage_run(uri: str, params: Params, stage: str, command: str,
              tags: dict[str, str] | None = None) -> Iterator[ActiveRun]:
    """The stage's MLflow run, open for as long as the block: opened before the stage's work, so
    its duration in the UI is the work's, and ended FAILED if the block raises (Ctrl-C too).

    Call `check_tracking_store` first, before any work, so a bad store stops the stage at once. Opening
    and ending the run are retried (`write_to_store`); a store that fails while the run ends FAILED is
    warned about, and the block's error goes on."""
    import mlflow

    mlflow.set_tracking_uri(uri)
    every_tag = {**run_tags(stage), **session_tags(params), "mlflow.source.name": f"python -m pipeline {command}",
                 **(tags or {})}
    run = write_to_store(uri, "starting the run", _start_run, params.training.experiment, stage, every_tag)
    try:
        yield run
    except BaseException:
        try:
            _end_run(uri, run.info.run_id, "FAILED")
        except TrackingError as error:
            log.warning("%s", error)
        raise
    _end_run(uri, run.info.run_id, "FINISHED")


def _start_run(experiment: str, stage: str, tags: dict[str, str]) -> ActiveRun:
    import mlflow

    mlflow.set_experiment(experiment)
    return mlflow.start_run(run_name=stage, tags=tags)


def _end_run(uri: str, run_id: str, status: str) -> None:
    """End the active run; MLflow takes it off its stack of active runs before it writes the status, so
    a failed write is retried with the client."""
    import mlflow

    try:
        with _quiet(MLFLOW_SQL_LOGGER):
            mlflow.end_run(status)
    except Exception:  # the store's: retried below
        write_to_store(uri, f"ending run {run_id} ({status})", mlflow.MlflowClient(uri).set_terminated, run_id,
                       status)


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

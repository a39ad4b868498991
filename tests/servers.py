"""Servers that the end-to-end tests start on 127.0.0.1 (PostgreSQL, the MLflow tracking server),
and the tiny pipeline run whose MLflow runs they serve.

Each server is a context manager that waits until it answers and stops it on exit, so a
failing test leaves no server behind. The programs come from Debian (`make system-deps`);
a missing one fails the test with the command that installs it, never a skip, so CI cannot
go green without the test having run.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from pipeline.io import process_alive
from tests.project import copy_repository, environment, tiny_params_tree, write_params

INSTALL_HINT = "run `make system-deps` (as root, or with sudo)"


def free_port() -> int:
    """A TCP port nobody listens on now (the OS picks it), for a server started right after."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def dvc(repository: Path, *arguments: str, tracking_uri: str | None = None) -> str:
    """`dvc <arguments>` in a copy of the repository; its output.

    With `tracking_uri`, only the environment variable MLFLOW_TRACKING_URI points the stages
    at it, as a team member would do; without, the variable is unset and the copy's params
    (`sqlite:///mlflow.db`) decide.
    """
    result = subprocess.run([sys.executable, "-m", "dvc", *arguments], cwd=repository,
                            env=_dvc_environment(tracking_uri), capture_output=True, text=True)
    assert result.returncode == 0, (f"dvc {' '.join(arguments)} failed:\n{result.stdout}\n"
                                    f"{result.stderr[-5000:]}")
    return result.stdout


SWEEP = "training.predictor.hidden=[16,16],[64,64]"  # docs/networks.md's sweep (of train_predictor alone)
QUEUE_TIMEOUT_S = 600


def _dvc_environment(tracking_uri: str | None) -> dict[str, str]:
    """The environment DVC runs in: MLFLOW_TRACKING_URI is `tracking_uri`, or unset."""
    env = environment()
    env.pop("MLFLOW_TRACKING_URI", None)
    if tracking_uri is not None:
        env["MLFLOW_TRACKING_URI"] = tracking_uri
    return env


def repro_tiny_pipeline(destination: Path) -> Path:
    """A fresh copy of the repository with tiny params, `dvc repro evaluate` run in it, then the
    sweep of docs/networks.md over the predictor's layers queued and run two at a time.

    That runs every training stage, `tune_kalman` and `evaluate`, each logging one MLflow run to
    the copy's `mlflow.db`, and two more `train_predictor` runs, one per DVC experiment of the
    sweep: the Models page has a filter and an autoencoder version and three predictor versions.
    """
    copy_repository(destination)
    write_params(tiny_params_tree(), destination / "params.yaml")
    dvc(destination, "repro", "evaluate")
    dvc(destination, "exp", "run", "--queue", "-S", SWEEP, "train_predictor")
    run_queue(destination, workers=2)
    return destination


def run_queue(repository: Path, workers: int) -> None:
    """`dvc queue start -j <workers>`, and wait until every queued experiment has finished;
    fails the test unless each succeeded.

    The workers are DVC's daemons: their output goes to a file, not a pipe this process would
    wait on for as long as they live. A worker can stay after it said it shut down on the empty
    queue, so once `dvc queue stop` has asked them to, the ones still there are ended by the pid
    DVC recorded for them."""
    with (repository / ".dvc" / "tmp" / "queue-start.log").open("w") as output:
        started = subprocess.run([sys.executable, "-m", "dvc", "queue", "start", "-j", str(workers)], cwd=repository,
                                 env=_dvc_environment(None), stdout=output, stderr=subprocess.STDOUT)
    assert started.returncode == 0, (repository / ".dvc" / "tmp" / "queue-start.log").read_text()
    try:
        deadline = time.monotonic() + QUEUE_TIMEOUT_S
        while True:
            status = dvc(repository, "queue", "status")
            if "Queued" not in status and "Running" not in status:
                break
            if time.monotonic() > deadline:
                pytest.fail(f"the DVC queue did not finish within {QUEUE_TIMEOUT_S} s:\n{status}")
            time.sleep(2)
    finally:
        dvc(repository, "queue", "stop")
        _end_queue_workers(repository)
    if "Failed" in status:
        pytest.fail(f"a queued experiment failed (`dvc queue logs <task>` in {repository} tells why):\n{status}")


def _end_queue_workers(repository: Path, grace_s: float = 20.0) -> None:
    """SIGTERM the queue workers of `repository` still alive `grace_s` after they were asked to stop."""
    pids = [int(text) for path in (repository / ".dvc" / "tmp" / "exps" / "celery").glob("dvc-exp-worker-*.pid")
            if (text := path.read_text().strip()).isdigit()]
    deadline = time.monotonic() + grace_s
    while time.monotonic() < deadline and any(process_alive(pid) for pid in pids):
        time.sleep(0.5)
    for pid in pids:
        if process_alive(pid):
            os.kill(pid, signal.SIGTERM)


def _wait_until_answers(url: str, process: subprocess.Popen, log: Path, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            pytest.fail(f"the server exited with code {process.returncode} before answering {url}:\n"
                        f"{log.read_text()[-5000:]}")
        try:
            with urllib.request.urlopen(url, timeout=2) as response:
                if response.status == 200:
                    return
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            pass
        time.sleep(0.5)
    pytest.fail(f"no answer from {url} within {timeout_s:.0f} s:\n{log.read_text()[-5000:]}")


def _stop(process: subprocess.Popen) -> None:
    """Stop the server and every process it started (its own session), politely first."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


@contextmanager
def mlflow_server(backend_store_uri: str, directory: Path) -> Iterator[str]:
    """`mlflow server` over a store, on a free port of 127.0.0.1; yields its URL.

    Artifacts that clients upload go through the server (MLflow's default `--serve-artifacts`)
    to `directory/artifacts`; the server's log is `directory/mlflow-server.log`. One worker,
    and no job runner (it serves GenAI scorers, and would start seven more processes on a
    2-core machine).
    """
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    log = directory / "mlflow-server.log"
    env = environment()
    env.pop("MLFLOW_TRACKING_URI", None)
    env["MLFLOW_SERVER_ENABLE_JOB_EXECUTION"] = "false"
    command = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", backend_store_uri,
               "--artifacts-destination", str(directory / "artifacts"),
               "--host", "127.0.0.1", "--port", str(port), "--workers", "1"]
    with log.open("w") as output:
        process = subprocess.Popen(command, cwd=directory, env=env, stdout=output, stderr=subprocess.STDOUT,
                                   start_new_session=True)
    try:
        _wait_until_answers(f"{url}/health", process, log, timeout_s=120)
        yield url
    finally:
        _stop(process)


def postgres_programs() -> Path:
    """The folder of PostgreSQL's server programs (initdb, pg_ctl, createdb).

    Debian keeps them in /usr/lib/postgresql/<version>/bin, off PATH; PATH is tried first for
    other systems.
    """
    on_path = shutil.which("initdb")
    if on_path:
        return Path(on_path).resolve().parent
    versions = sorted(Path("/usr/lib/postgresql").glob("*/bin/initdb"), key=lambda p: int(p.parent.parent.name))
    if not versions:
        pytest.fail(f"PostgreSQL's initdb was not found (on PATH or in /usr/lib/postgresql/*/bin): {INSTALL_HINT}, "
                    "or `apt-get install -y --no-install-recommends postgresql`")
    return versions[-1].parent


@contextmanager
def postgres_database(name: str = "mlflow") -> Iterator[str]:
    """A throw-away PostgreSQL server on a free port of 127.0.0.1 with one empty database;
    yields its SQLAlchemy URI (`postgresql+psycopg://mlflow@127.0.0.1:<port>/<name>`).

    PostgreSQL refuses to run as root, so under root (CI) the server runs as the `postgres`
    user that Debian's package creates, in a data folder that user owns. The folder is in
    /tmp, not pytest's tmp_path: pytest makes that private to root, where `postgres` could
    not reach it. Only connections from 127.0.0.1 are accepted, without a password (trust),
    and the Unix socket lives in the same folder.
    """
    programs = postgres_programs()
    as_server_user: list[str] = []
    directory = Path(tempfile.mkdtemp(prefix="mlflow-postgres-"))
    if os.geteuid() == 0:
        if shutil.which("runuser") is None:
            pytest.fail("runuser (util-linux) is needed to run PostgreSQL as the postgres user")
        as_server_user = ["runuser", "-u", "postgres", "--"]
        try:
            shutil.chown(directory, "postgres", "postgres")
        except LookupError:
            pytest.fail(f"running as root and there is no `postgres` user to run PostgreSQL as: {INSTALL_HINT}")
    data, log, port = directory / "data", directory / "postgres.log", free_port()

    def run(*command: str) -> None:
        result = subprocess.run([*as_server_user, *command], capture_output=True, text=True)
        if result.returncode != 0:
            log_text = log.read_text() if log.is_file() else ""
            pytest.fail(f"{' '.join(command)} failed:\n{result.stdout}\n{result.stderr}\n{log_text[-5000:]}")

    try:
        run(str(programs / "initdb"), "-D", str(data), "--username=mlflow", "--auth=trust", "--encoding=UTF8",
            "--no-locale", "--no-sync")
        run(str(programs / "pg_ctl"), "-D", str(data), "-l", str(log), "-w", "-t", "60",
            "-o", f"-h 127.0.0.1 -p {port} -k {directory}", "start")
        try:
            run(str(programs / "createdb"), "-h", "127.0.0.1", "-p", str(port), "-U", "mlflow", name)
            yield f"postgresql+psycopg://mlflow@127.0.0.1:{port}/{name}"
        finally:  # immediate: a throw-away database needs no shutdown checkpoint
            run(str(programs / "pg_ctl"), "-D", str(data), "-m", "immediate", "-w", "stop")
    finally:
        shutil.rmtree(directory, ignore_errors=True)


def _dask(program: str, *arguments: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", f"distributed.cli.dask_{program}", *arguments],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


@contextmanager
def dask_cluster(folder: Path, workers: int = 2) -> Iterator[str]:
    """A Dask scheduler and `workers` one-thread workers on 127.0.0.1, each its own process started
    from the command line as on machines apart; yields the scheduler's address."""
    import distributed

    scheduler_file = folder / "dask-scheduler.json"
    processes = [_dask("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                       "--scheduler-file", str(scheduler_file))]
    try:
        processes += [_dask("worker", "--scheduler-file", str(scheduler_file), "--nthreads", "1", "--nworkers", "1",
                            "--no-dashboard", "--host", "127.0.0.1") for _ in range(workers)]
        with distributed.Client(scheduler_file=str(scheduler_file), timeout=60) as client:
            client.wait_for_workers(workers, timeout=60)
            address = client.scheduler.address
        yield address
    finally:
        for process in processes[::-1]:
            process.terminate()
        for process in processes:
            process.wait(timeout=30)

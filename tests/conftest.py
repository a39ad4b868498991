"""Shared fixtures: the default params tree, small params built from it, and a tiny pipeline run."""

from __future__ import annotations

import copy
import fcntl
import os
import sys
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import pytest

from pipeline.params import STRATEGIES, Params, load_params_tree
from pipeline.settings import parse_params
from tests.servers import repro_tiny_pipeline

PARAMS_YAML = Path(__file__).resolve().parents[1] / "params.yaml"
_DEFAULT_TREE = load_params_tree(PARAMS_YAML)


@pytest.fixture(autouse=True)
def tracking_uri_left_as_found() -> Iterator[None]:
    """MLflow's tracking URI put back after every test. A stage run in the test's process opens its
    run with `mlflow.set_tracking_uri`, and MLflow then also sets MLFLOW_TRACKING_URI in
    `os.environ` (for child processes); left there, the `dvc repro` that a later test of the same
    worker starts would send its runs to that test's store, not to the store its params name."""
    before = os.environ.get("MLFLOW_TRACKING_URI")
    yield
    if "mlflow" in sys.modules:
        sys.modules["mlflow"].set_tracking_uri(None)
    if before is None:
        os.environ.pop("MLFLOW_TRACKING_URI", None)
    else:
        os.environ["MLFLOW_TRACKING_URI"] = before


@pytest.fixture
def params_tree() -> dict[str, Any]:
    """The default params.yaml as the stages read it (load_params_tree); a fresh copy for each test to edit."""
    return copy.deepcopy(_DEFAULT_TREE)


@pytest.fixture(scope="session")
def make_params() -> Callable[..., Params]:
    """Build validated params from the defaults with few routes, e.g.
    ``make_params(2, {"routes.start_spread_s": 0.0})``: 2 routes per strategy and split, one key changed."""

    def make(routes_per_strategy: int = 3, changes: Mapping[str, Any] | None = None) -> Params:
        tree = copy.deepcopy(_DEFAULT_TREE)
        for split in tree["routes"]["splits"].values():
            split.update(dict.fromkeys(STRATEGIES, routes_per_strategy))
        for dotted, value in (changes or {}).items():
            *parents, key = dotted.split(".")
            node = tree
            for parent in parents:
                node = node[parent]
            node[key] = value
        return parse_params(tree)

    return make


@pytest.fixture(scope="session")
def tiny_pipeline(tmp_path_factory: pytest.TempPathFactory, worker_id: str) -> Path:
    """A copy of the repository in which a tiny `dvc repro evaluate` ran, its MLflow runs in the
    copy's `mlflow.db`; shared by the MLflow UI and team-server tests.

    Minutes of work, so done once per test session. Under pytest-xdist each worker is a
    session of its own: the first worker to ask makes it in the session's common folder,
    under a file lock, and the others wait for it and reuse it.
    """
    if worker_id == "master":  # not distributed
        return repro_tiny_pipeline(tmp_path_factory.mktemp("tiny-pipeline"))
    common = tmp_path_factory.getbasetemp().parent
    repository, failed = common / "tiny-pipeline", common / "tiny-pipeline.failed"
    with (common / "tiny-pipeline.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if failed.exists():
            pytest.fail("the tiny pipeline run failed in another pytest-xdist worker: see its error")
        if not repository.exists():
            repository.mkdir()
            try:
                repro_tiny_pipeline(repository)
            except BaseException:
                failed.touch()
                raise
    return repository


@pytest.fixture(scope="module")
def one_torch_thread() -> Iterator[None]:
    """Batches of a few tracks: torch's intra-op threads only add contention (as in
    pipeline.tracker.models); a module asks for it with `pytestmark = pytest.mark.usefixtures(...)`."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)

"""`pipeline.bench.engine`: units run here, on a local Dask cluster, or on a scheduler started apart,
each worker with its own state; a worker lost mid-run has its units rerun."""

from __future__ import annotations

import os
import time
from pathlib import Path

import dask
import pytest

from pipeline.bench import engine
from tests.servers import dask_cluster

UNITS = [("a", 0), ("a", 1), ("b", 0), ("b", 5), ("c", 2), ("c", 3)]


def prepared(offset: int, marker: str = "") -> dict:
    return {"offset": offset, "pid": os.getpid(), "marker": marker}


def evaluated(state: dict, name: str, index: int) -> tuple[str, int, int]:
    return name, index + state["offset"], state["pid"]


def dies_once(state: dict, name: str, index: int) -> tuple[str, int, int]:
    """The first worker to run unit ("b", 5) dies in it, as a machine lost mid-run."""
    marker = Path(state["marker"])
    if (name, index) == ("b", 5) and not marker.exists():
        marker.write_text(str(os.getpid()))
        os._exit(1)
    return evaluated(state, name, index)


@pytest.mark.parametrize("workers", [1, 2])
def test_every_unit_comes_back_once_with_its_result(workers):
    here = prepared(100)
    results = dict(engine.completed_units(UNITS, workers, evaluated, here, prepared, (100,)))
    assert sorted(results) == sorted(UNITS)
    assert all(results[unit][:2] == (unit[0], unit[1] + 100) for unit in UNITS)
    pids = {result[2] for result in results.values()}
    assert (pids == {os.getpid()}) if workers == 1 else (os.getpid() not in pids)


def test_a_lost_workers_units_are_rerun_not_dropped(tmp_path):
    marker = tmp_path / "died"
    results = dict(engine.completed_units(UNITS, 2, dies_once, None, prepared, (7, str(marker))))
    assert marker.exists(), "no worker died: the test did not test a loss"
    assert sorted(results) == sorted(UNITS)
    assert results[("b", 5)][:2] == ("b", 12)
    assert results[("b", 5)][2] != int(marker.read_text())


@pytest.fixture()
def cluster(tmp_path):
    with dask_cluster(tmp_path) as address:
        yield address


def test_units_sent_to_a_running_scheduler_come_back_from_its_workers(cluster):
    with dask.config.set({"scheduler-address": cluster}):
        results = dict(engine.completed_units(UNITS, 1, evaluated, None, prepared, (3,)))
    assert {unit: result[:2] for unit, result in results.items()} == {(n, i): (n, i + 3) for n, i in UNITS}
    assert len({result[2] for result in results.values()}) >= 1 and os.getpid() not in {r[2] for r in results.values()}


def test_an_unreachable_scheduler_is_named():
    began = time.monotonic()
    with dask.config.set({"scheduler-address": "tcp://127.0.0.1:9"}), pytest.raises(
            engine.SchedulerUnreachable, match="DASK_SCHEDULER_ADDRESS=tcp://127.0.0.1:9"):
        dict(engine.completed_units(UNITS, 2, evaluated, None, prepared, (3,)))
    assert time.monotonic() - began < 60

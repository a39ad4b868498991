"""`pipeline.bench.unit_pool`: units run here or in forkserver workers, each worker with its own state."""

from __future__ import annotations

import os

import pytest

from pipeline.bench import unit_pool


def prepared(offset: int) -> dict:
    return {"offset": offset, "pid": os.getpid()}


def evaluated(state: dict, name: str, index: int) -> tuple[str, int, int]:
    return name, index + state["offset"], state["pid"]


@pytest.mark.parametrize("workers", [1, 2])
def test_every_unit_comes_back_once_with_its_result(workers):
    units = [("a", 0), ("a", 1), ("b", 0), ("b", 5)]
    here = prepared(100)
    results = dict(unit_pool.completed_units(units, workers, evaluated, here, prepared, (100,)))
    assert sorted(results) == sorted(units)
    assert all(results[unit][:2] == (unit[0], unit[1] + 100) for unit in units)
    pids = {result[2] for result in results.values()}
    assert (pids == {os.getpid()}) if workers == 1 else (os.getpid() not in pids)

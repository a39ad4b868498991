"""An evaluation's units (one run on one scenario or scene) tracked in worker processes, each
result handed back as soon as it is in, for `evaluation` and `scene_evaluation` alike.

Workers are started by the forkserver: a forked copy of a process running PyTorch or ONNX
Runtime threads can deadlock. Each worker prepares its own state once (reads the scenarios,
loads the models) and runs one PyTorch thread: a unit's network batches are a few windows, and
the workers already share the cores.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any, Callable, Iterator, TypeVar

import torch

Unit = TypeVar("Unit", bound=tuple)
Result = TypeVar("Result")

_STATE: Any = None  # a worker's prepared state, made by its initializer


def _start_worker(prepare: Callable[..., Any], arguments: tuple) -> None:
    global _STATE
    torch.set_num_threads(1)
    _STATE = prepare(*arguments)


def _unit_in_worker(evaluate: Callable[..., Result], unit: tuple) -> Result:
    return evaluate(_STATE, *unit)


def completed_units(units: list[Unit], workers: int, evaluate: Callable[..., Result], state: Any,
                    prepare: Callable[..., Any], arguments: tuple) -> Iterator[tuple[Unit, Result]]:
    """Each unit with its result `evaluate(state, *unit)`, as it completes: in this process with
    `state` when `workers` is 1, else in `workers` processes, each with its own state
    `prepare(*arguments)`. `evaluate` and `prepare` must be module-level functions (they are sent
    to the workers by name). Units are started in the order given."""
    if workers == 1:
        for unit in units:
            yield unit, evaluate(state, *unit)
        return
    pool = ProcessPoolExecutor(workers, multiprocessing.get_context("forkserver"), _start_worker, (prepare, arguments))
    try:
        pending: dict[Future, Unit] = {pool.submit(_unit_in_worker, evaluate, unit): unit for unit in units}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                yield pending.pop(future), future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)

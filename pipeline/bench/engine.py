"""The bench's units run on Dask distributed: here, on a local cluster of worker processes, or on a
running scheduler elsewhere; each result handed back as soon as it is in.

Every evaluation and the tuning stage are independent units (one run on one scenario, scene or
filter kind). `completed_units` runs them

- in this process, when `compute.workers` is 1 and no scheduler is named;
- on a `distributed.LocalCluster` of `compute.workers` processes, one thread each, started for the
  call and closed after it;
- on the scheduler at `DASK_SCHEDULER_ADDRESS` (Dask's own setting, `scheduler-address` in its
  configuration), when it is set: `dask scheduler` on one machine, `dask worker ADDRESS --nthreads 1`
  on as many as there are; every worker must import this package and read the stage's folders
  at the same paths (a shared file system, or the same checkout at the same place).

Dask was chosen over Ray by measuring both on the evaluation's units (`benchmarks/bench_engines.py`,
docs/speed.md): on the 2 shared cores neither ran the units faster beyond the noise, both start a
local cluster in 6-12 s and rerun a lost worker's units; Ray's per-unit overhead is lower (2 ms
against 5-9), which units of 0.1-10 s do not feel. Dask's local cluster is the worker processes and a
scheduler thread where Ray adds daemons of its own (GCS, raylet, dashboard, log monitor) that take
CPU on a 2-core laptop, and a Dask cluster is two commands and one environment variable on machines
that have this package's environment.

Each worker prepares its own state once per call (reads the material, loads the models), the first
time it is given a unit of the call (`prepare(*arguments)`, kept under the call's id until a unit of
another call comes: a long-lived cluster never runs on a model file read before it changed), and runs one
PyTorch thread: a unit's network batches are small, and the workers already share the cores. A
worker lost mid-run has its units rerun on the others (Dask reschedules a lost worker's tasks; a
unit is a pure function of its inputs, so its result is the same wherever it ran). Results are the
callers' to merge by unit, never by finishing order, so the outputs do not depend on where the
units ran.
"""

from __future__ import annotations

import logging
import uuid
from contextlib import contextmanager
from typing import Any, Callable, Iterator, TypeVar

import torch

log = logging.getLogger("pipeline")

Unit = TypeVar("Unit", bound=tuple)
Result = TypeVar("Result")

CONNECT_TIMEOUT_S = 10.0  # to reach a named scheduler before giving up
_STATES: dict[str, Any] = {}  # a worker's prepared state, by the id of the call it is for


class SchedulerUnreachable(RuntimeError):
    """The scheduler named by DASK_SCHEDULER_ADDRESS did not answer."""


def scheduler_address() -> str | None:
    """The address of the running scheduler to send units to (Dask's `scheduler-address` setting,
    from DASK_SCHEDULER_ADDRESS or a Dask configuration file), or None for a local cluster."""
    import dask

    return dask.config.get("scheduler-address", None) or None


def _prepared(call: str, prepare: Callable[..., Any], arguments: tuple) -> Any:
    if call not in _STATES:
        _STATES.clear()
        torch.set_num_threads(1)
        _STATES[call] = prepare(*arguments)
    return _STATES[call]


def _unit_in_worker(call: str, level: int, evaluate: Callable[..., Result], prepare: Callable[..., Any],
                    arguments: tuple, unit: tuple) -> Result:
    log.setLevel(level)  # the caller's: its records are forwarded to it (`Client.forward_logging`)
    return evaluate(_prepared(call, prepare, arguments), *unit)


def where(workers: int) -> str:
    """Where `completed_units` runs units, for a progress line: `2 workers`, `the scheduler at ADDRESS`."""
    address = scheduler_address()
    if address is not None:
        return f"the scheduler at {address}"
    return "1 worker" if workers == 1 else f"{workers} workers"


@contextmanager
def client(workers: int) -> Iterator[Any]:
    """A Dask client: of the scheduler at `scheduler_address()`, else of a new local cluster of
    `workers` processes with one thread each, closed with the client. Raises SchedulerUnreachable
    naming the address when a named scheduler does not answer within CONNECT_TIMEOUT_S."""
    from distributed import Client, LocalCluster

    address = scheduler_address()
    if address is None:
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                          silence_logs=logging.WARNING) as cluster, Client(cluster, set_as_default=False) as local:
            yield local
        return
    try:
        remote = Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError) as error:
        raise SchedulerUnreachable(f"DASK_SCHEDULER_ADDRESS={address}: no Dask scheduler answered within "
                                   f"{CONNECT_TIMEOUT_S:g} s ({error})") from error
    with remote:
        yield remote


def completed_units(units: list[Unit], workers: int, evaluate: Callable[..., Result], state: Any,
                    prepare: Callable[..., Any], arguments: tuple) -> Iterator[tuple[Unit, Result]]:
    """Each unit with its result `evaluate(state, *unit)`, as it completes: in this process with
    `state` when `workers` is 1 and no scheduler is named, else on Dask workers, each with its own
    state `prepare(*arguments)`. `evaluate` and `prepare` must be module-level functions (the workers
    import them by name). Units are started in the order given (the first has the highest priority).
    Raises SchedulerUnreachable (`client`), and the first error a unit raised."""
    if workers == 1 and scheduler_address() is None:
        for unit in units:
            yield unit, evaluate(state, *unit)
        return
    from distributed import as_completed

    call = uuid.uuid4().hex
    with client(workers) as dask_client:
        dask_client.forward_logging(log.name, level=log.getEffectiveLevel())  # the workers' progress lines
        level = log.getEffectiveLevel()
        futures = {dask_client.submit(_unit_in_worker, call, level, evaluate, prepare, arguments, unit, pure=False,
                                      priority=len(units) - position): unit
                   for position, unit in enumerate(units)}
        try:
            with dask_client.as_current():
                for future in as_completed(futures):
                    yield futures[future], future.result()
        finally:
            dask_client.cancel(list(futures))

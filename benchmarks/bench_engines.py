"""Dask distributed against Ray on the bench's own units: the measurement behind `pipeline.bench.engine`.

For each engine and number of workers, on the evaluation units of a finished pipeline run (every run
of its params over every test scenario, `pipeline.bench.evaluation`): the seconds to start the
engine's local cluster, the seconds from the first unit sent to the last result in (each worker
preparing its own state, as the stage does), and the per-unit overhead measured on empty units.
Prints a table; the choice is written up in `pipeline/bench/engine.py` and docs/speed.md.

    python benchmarks/bench_engines.py --run /tmp/tiny              # a folder where `dvc repro` ran
    python benchmarks/bench_engines.py --run . --workers 1 2 --empty 500

Ray is not a dependency of the project: `pip install ray` to run its rows (they are skipped with a
note otherwise). Run it on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))

from pipeline.bench import engine, evaluation  # noqa: E402
from pipeline.settings import load_params  # noqa: E402

def _unit_arguments(arguments: tuple, unit: tuple) -> tuple:
    """One evaluation unit as both engines run it: the engine's own worker function (importable, so
    that its prepared state stays in the worker between units), the state prepared once per worker."""
    return ("bench-engines", logging.WARNING, evaluation.evaluate_unit, evaluation.prepare, arguments, unit)


def _empty(_: int) -> int:
    return os.getpid()


def dask_rows(units: list[tuple], arguments: tuple, workers: int, empty: int) -> tuple[float, float, float]:
    from distributed import Client, LocalCluster, wait

    began = time.perf_counter()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        client.wait_for_workers(workers)
        client.submit(_empty, 0, pure=False).result()
        startup = time.perf_counter() - began
        started = time.perf_counter()
        wait(client.map(_empty, range(empty), pure=False))
        overhead = (time.perf_counter() - started) / empty
        began = time.perf_counter()
        client.gather([client.submit(engine._unit_in_worker, *_unit_arguments(arguments, unit), pure=False,
                                     priority=len(units) - i) for i, unit in enumerate(units)])
        return startup, time.perf_counter() - began, overhead


def ray_rows(units: list[tuple], arguments: tuple, workers: int, empty: int) -> tuple[float, float, float] | None:
    try:
        import ray
    except ImportError:
        return None
    began = time.perf_counter()
    ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    try:
        empty_task, unit_task = ray.remote(num_cpus=1)(_empty), ray.remote(num_cpus=1)(engine._unit_in_worker)
        ray.get(empty_task.remote(0))
        startup = time.perf_counter() - began
        started = time.perf_counter()
        ray.get([empty_task.remote(i) for i in range(empty)])
        overhead = (time.perf_counter() - started) / empty
        began = time.perf_counter()
        ray.get([unit_task.remote(*_unit_arguments(arguments, unit)) for unit in units])
        return startup, time.perf_counter() - began, overhead
    finally:
        ray.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, required=True, help="a folder where the pipeline ran (params.yaml, data/, models/)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--empty", type=int, default=300, help="empty units to measure the per-unit overhead")
    args = parser.parse_args()
    params = load_params(args.run / "params.yaml")
    arguments = (params, args.run / "data" / "simulated", args.run / "data" / "routes", args.run / "models")
    prepared = evaluation.prepare(*arguments)
    units = sorted(((run, index) for run in prepared.runs for index in range(len(prepared.scenarios))),
                   key=lambda unit: -evaluation.relative_cost(unit[0], prepared.scenarios[unit[1]]))
    began = time.perf_counter()
    for unit in units:
        evaluation.evaluate_unit(prepared, *unit)
    alone = time.perf_counter() - began
    print(f"{len(units)} evaluation units of {args.run}; in one process, no engine: {alone:.1f} s")
    print("| engine | workers | start-up s | units s | units/s | speed-up on one process | overhead per empty unit ms |")
    print("|---|---|---|---|---|---|---|")
    for name, rows in (("dask", dask_rows), ("ray", ray_rows)):
        for workers in args.workers:
            measured = rows(units, arguments, workers, args.empty)
            if measured is None:
                print(f"| {name} | {workers} | not installed | | | | |")
                continue
            startup, seconds, overhead = measured
            print(f"| {name} | {workers} | {startup:.2f} | {seconds:.1f} | {len(units) / seconds:.2f} | "
                  f"{alone / seconds:.2f} | {overhead * 1e3:.2f} |", flush=True)


if __name__ == "__main__":
    main()

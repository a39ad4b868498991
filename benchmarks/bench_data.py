"""Time and memory of the `routes`, `simulate` and `windows` stages with the default params.

Runs each stage as the pipeline does (`python -m pipeline ...`, a fresh process) into a
temporary folder, a few times, and prints wall time and peak resident memory.

    python benchmarks/bench_data.py [--params params.yaml] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq


def run(command: list[str]) -> tuple[float, float]:
    """Wall seconds and peak RSS (MiB) of one child process (os.wait4 gives that child's own usage)."""
    start = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)
    elapsed = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(command)} failed")
    return elapsed, usage.ru_maxrss / 1024.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        routes, simulated = Path(folder) / "routes", Path(folder) / "simulated"
        windows, reports = Path(folder) / "windows", Path(folder) / "reports"
        timings: dict[str, list[float]] = {"routes": [], "simulate": [], "windows": []}
        peaks: dict[str, float] = {}
        for _ in range(args.repeat):
            for stage, command in (
                ("routes", [sys.executable, "-m", "pipeline", "-q", "routes", "--params", args.params,
                            "--out", str(routes)]),
                ("simulate", [sys.executable, "-m", "pipeline", "-q", "simulate", "--params", args.params,
                              "--routes", str(routes), "--out", str(simulated)]),
                ("windows", [sys.executable, "-m", "pipeline", "-q", "windows", "--params", args.params,
                             "--simulated", str(simulated), "--out", str(windows), "--reports", str(reports)]),
            ):
                elapsed, peak = run(command)
                timings[stage].append(elapsed)
                peaks[stage] = max(peak, peaks.get(stage, 0.0))
        n_routes = sum(len(set(pq.read_table(f, columns=["route_id"]).column(0).to_pylist()))
                       for f in routes.glob("*.parquet"))
        n_plots = sum(pq.read_metadata(f).num_rows for f in simulated.glob("*/plots.parquet"))
        n_windows = sum(pq.read_metadata(f).num_rows for f in windows.glob("*.parquet"))
    print(f"routes:   {n_routes} routes, best of {args.repeat}: {min(timings['routes']):.1f} s, "
          f"peak memory {peaks['routes']:.0f} MiB")
    print(f"simulate: {n_plots} plots, best of {args.repeat}: {min(timings['simulate']):.1f} s, "
          f"peak memory {peaks['simulate']:.0f} MiB")
    print(f"routes + simulate: {min(timings['routes']) + min(timings['simulate']):.1f} s for {n_routes} routes "
          f"(goal: under 60 s)")
    print(f"windows:  {n_windows} window rows, best of {args.repeat}: {min(timings['windows']):.1f} s, "
          f"peak memory {peaks['windows']:.0f} MiB (goal: under 30 s and 2 GB)")


if __name__ == "__main__":
    main()

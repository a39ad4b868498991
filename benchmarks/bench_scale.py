"""Tracker scale (issue 16, item 4): plots/s and peak memory on synthetic dense recordings.

Builds a recording in memory, as `track` would hold it (one `Plots` table): N aircraft at once
in one radar's coverage, each detected every scan with the radar's noise (params' `radar`:
range, azimuth and altitude errors, placed and given their covariance by the pipeline's own
conversion), plus a Poisson number of false plots per scan, uniform in the coverage disc. An
aircraft flies straight or turns (0.5-3 deg/s) and changes between the two at random; one that
leaves the coverage is replaced by a new one anywhere in it, so N stay in the air. Each plot's
time within its scan follows its azimuth (the antenna's sweep).

Each configuration (recording x method) runs in a fresh child process, so its peak resident
memory (`os.wait4`) is its own: interpreter and imports, the plot table, and the tracking loop's
output (the loop holds every update until the end). Speed counts the tracking loop only (no
recording generation, no output writing): plots per wall second and per CPU second of the child
(the CPU figure is the steadier on a shared machine; the speed goal is judged on it).

Configurations: 1 (the single-aircraft reference), 10, 100 and 1000 aircraft for `--minutes`,
and `--long-aircraft` aircraft for each of `--hours`, all with `--false-plots` per scan. A
recording of more than `--max-tracked` plots is built in full (its plot table's memory is
measured) but tracked only over its first `--max-tracked` plots; the rest of its tracking
memory is extrapolated linearly from the tracked part's growth per plot, and the row is marked
`est.` (a full 24-hour run is ~5 M plots, ~5 min and ~4 GiB per method at today's speed). The
extrapolation holds: a 6-hour recording (1.26 M plots) tracked whole peaked at 1,192 MiB with
kalman_cv, extrapolated from its first 250,000 plots 1,181 MiB.

The classical methods need only filters: by default the filters at params' start values (what
`tune_kalman` starts from; tuned values change the cost little), written to a temporary models
folder. `--models` takes a folder of real models instead (needed for `via`).

Then the issue's two goals, pass or fail: at 1000 aircraft at least half the single-aircraft rate;
peak memory of a 24-hour dense recording under 1 GiB. For a goal that fails it shows where the
time goes (cProfile top 10 of the 1000-aircraft case, a shorter run) or the memory (the plot
table's arrays, the update table's arrays, and tracemalloc's top lines at the end of a short run).

    python benchmarks/bench_scale.py                    # the issue's sizes, ~2.5 min on one core
    python benchmarks/bench_scale.py --minutes 1 --aircraft 1 100 --hours 0.1 --no-diagnose  # ~10 s
    python benchmarks/bench_scale.py --methods kalman_cv --aircraft --hours 6 --max-tracked 2000000  # 6 h, whole
    python benchmarks/bench_scale.py --methods kalman_cv imm_gnn via --models models
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

GIB = 1024.0 ** 3
MIB = 1024.0 ** 2
T0 = 1.78e9                 # about the recording's start, Unix seconds (2026): made a north crossing below
GROUND_MIN_M = 20000.0      # aircraft appear between this ground range and ...
EDGE = 0.95                 # ... this fraction of the radar's range_max; they leave beyond range_max
ALTITUDE_M = (1000.0, 12000.0)
SPEED_MPS = (80.0, 280.0)
TURN_DPS = (0.5, 3.0)
MANOEUVRE_PER_SCAN = 1 / 30  # chance per scan that an aircraft draws a new manoeuvre (straight or a turn)
CHUNK_SCANS = 100           # the recording is generated this many scans at a time, into preallocated arrays


# ----------------------------------------------------------------------------- the recording

def _advance(east, north, heading, speed, rate, dt):
    """Positions after `dt` s of flight at constant speed and turn rate (rad/s; heading from north)."""
    turning = np.abs(rate) > 1e-12
    safe = np.where(turning, rate, 1.0)
    new_heading = heading + rate * dt
    de = np.where(turning, speed / safe * (np.cos(heading) - np.cos(new_heading)), speed * np.sin(heading) * dt)
    dn = np.where(turning, speed / safe * (np.sin(new_heading) - np.sin(heading)), speed * np.cos(heading) * dt)
    return east + de, north + dn, new_heading


def _manoeuvre(rng: np.random.Generator, count: int) -> np.ndarray:
    """Turn rates (rad/s): half straight, half turning either way."""
    rate = np.radians(rng.uniform(*TURN_DPS, count)) * rng.choice([-1.0, 1.0], count)
    return np.where(rng.uniform(size=count) < 0.5, 0.0, rate)


def _spawn(rng: np.random.Generator, count: int, radar) -> dict[str, np.ndarray]:
    ground = np.sqrt(rng.uniform(GROUND_MIN_M ** 2, (EDGE * radar.range_max_m) ** 2, count))
    bearing = rng.uniform(0.0, 2 * np.pi, count)
    return {"east": ground * np.sin(bearing), "north": ground * np.cos(bearing),
            "altitude": rng.uniform(*ALTITUDE_M, count), "speed": rng.uniform(*SPEED_MPS, count),
            "heading": rng.uniform(0.0, 2 * np.pi, count), "rate": _manoeuvre(rng, count)}


def _measured(times, east, north, altitude, radar, rng):
    """Plots of points on the radar's tangent plane (east, north) at `altitude`, as the pipeline's
    radar model makes them (`pipeline.radar`): Gaussian range, azimuth and altitude errors, then
    quantised to ASTERIX CAT048 resolutions (time to 1/128 s) and placed in ECEF; with the
    converted-measurement covariance `track` gives them. Returns times, ECEF positions, measured
    slant ranges and covariances."""
    from pipeline import baselines, geodesy
    from pipeline import radar as radar_model
    lat, lon, alt = geodesy.local_to_geodetic(east, north, altitude, radar)
    slant, azimuth, alt = geodesy.true_measurement(geodesy.geodetic_to_ecef(lat, lon, alt), radar)
    measured = radar_model.measure(times, *radar_model.add_measurement_noise(rng, slant, azimuth, alt, radar), radar,
                                   times)
    return (measured.time_unix_s, measured.ecef, measured.range_m,
            baselines.measurement_covariance(measured.ecef, radar))


def dense_recording(radar, aircraft: int, false_plots: float, scans: int, seed: int, detection: float = 1.0):
    """The plot table (`pipeline.plot_table.Plots`, time order, truth known) of `scans` antenna
    scans with `aircraft` aircraft in the air at every moment and Poisson(`false_plots`) false
    plots per scan; each aircraft is detected with probability `detection` per scan. Arrays are
    allocated once at their final size and filled CHUNK_SCANS scans at a time."""
    from pipeline.plot_table import NO_SCENARIO, NO_TARGET, Plots
    rng = np.random.default_rng(seed)
    period = radar.scan_period_s
    first_scan = np.ceil(T0 / period) * period  # the antenna points north at whole multiples of the period
    clutter_counts = rng.poisson(false_plots, scans)
    capacity = aircraft * scans + int(clutter_counts.sum())
    time_ = np.empty(capacity)
    position = np.empty((capacity, 3))
    range_m = np.empty(capacity)
    covariance = np.empty((capacity, 3, 3))
    target = np.empty(capacity, dtype=np.int32)
    flights = _spawn(rng, aircraft, radar)
    ids = np.arange(aircraft, dtype=np.int32)
    next_id = aircraft
    filled = 0
    for first in range(0, scans, CHUNK_SCANS):
        parts = []  # (times, east, north, altitude, target ids) per scan
        for scan in range(first, min(first + CHUNK_SCANS, scans)):
            start = first_scan + scan * period
            # aircraft: seen when the antenna sweeps their azimuth
            sweep = np.mod(np.arctan2(flights["east"], flights["north"]), 2 * np.pi) / (2 * np.pi) * period
            east, north, _ = _advance(flights["east"], flights["north"], flights["heading"], flights["speed"],
                                      flights["rate"], sweep)
            seen = rng.uniform(size=aircraft) < detection
            parts.append((start + sweep[seen], east[seen], north[seen], flights["altitude"][seen], ids[seen]))
            # false plots: uniform in the coverage disc and height
            k = clutter_counts[scan]
            ground = np.sqrt(rng.uniform(radar.range_min_m ** 2, radar.range_max_m ** 2, k))
            bearing = rng.uniform(0.0, 2 * np.pi, k)
            parts.append((start + bearing / (2 * np.pi) * period, ground * np.sin(bearing), ground * np.cos(bearing),
                          rng.uniform(0.0, radar.altitude_max_m, k), np.full(k, NO_TARGET, np.int32)))
            # one scan of flight; new manoeuvres; the ones that left replaced
            flights["east"], flights["north"], flights["heading"] = _advance(
                flights["east"], flights["north"], flights["heading"], flights["speed"], flights["rate"], period)
            change = rng.uniform(size=aircraft) < MANOEUVRE_PER_SCAN
            flights["rate"][change] = _manoeuvre(rng, int(change.sum()))
            gone = np.flatnonzero(np.hypot(flights["east"], flights["north"]) > radar.range_max_m)
            if len(gone):
                for key, values in _spawn(rng, len(gone), radar).items():
                    flights[key][gone] = values
                ids[gone] = np.arange(next_id, next_id + len(gone), dtype=np.int32)
                next_id += len(gone)
        times, east, north, altitude, who = (np.concatenate(column) for column in zip(*parts))
        order = np.argsort(times, kind="stable")  # chunks follow each other in time: global order holds
        rows = slice(filled, filled + len(order))
        target[rows] = who[order]
        time_[rows], position[rows], range_m[rows], covariance[rows] = _measured(
            times[order], east[order], north[order], altitude[order], radar, rng)
        filled += len(order)
    keep = slice(0, filled)  # views: fewer rows than allocated only when detection < 1
    n = filled
    return Plots(np.arange(n, dtype=np.int64), np.full(n, radar.radar_id, np.int32),
                 np.full(n, NO_SCENARIO, np.int32), time_[keep], position[keep], range_m[keep], covariance[keep],
                 target[keep], True, {radar.radar_id: radar})


# ----------------------------------------------------------------------------- one configuration (child)

def _rss_now() -> float:
    """This process's resident memory now, bytes."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _rss_peak() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0


def _models(spec: dict):
    from pipeline import io
    from pipeline.classical_filters import KINDS
    from pipeline.params import load_params
    from pipeline.tracker.loading import load_models
    from pipeline.tune_stage import start_settings
    params = load_params(spec["params"])
    if spec["models"]:
        return params, load_models(Path(spec["models"]), params, [spec["method"]])
    with tempfile.TemporaryDirectory() as folder:
        io.write_json({"cost": "rmse", "filters": {kind: start_settings(kind, params).to_dict() for kind in KINDS}},
                      Path(folder) / "kalman_tuned.json")
        return params, load_models(Path(folder), params, [spec["method"]])


def child(spec: dict) -> dict:
    """Build one recording, track (a prefix of) it with one method; what it measured."""
    from pipeline.tracker import registry, run
    params, models = _models(spec)
    rss_imported = _rss_now()
    plots = dense_recording(params.radar, spec["aircraft"], spec["false_plots"], spec["scans"], spec["seed"],
                            spec["detection"])
    plots_bytes = sum(getattr(plots, name).nbytes for name in ("plot_id", "radar_id", "scenario_id", "time",
                                                               "position", "range_m", "covariance", "target_id"))
    rss_built, peak_built = _rss_now(), _rss_peak()
    tracked = plots if len(plots) <= spec["max_tracked"] else plots.take(slice(0, spec["max_tracked"]))
    slots = []

    class Watched(run.LiveTracks):  # to report how many track slots the loop scanned
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            slots.append(self)

    run.LiveTracks = Watched
    tracker = registry.compose(spec["method"], models, params.tracker, spec["window"], [params.tracker.seed])
    out = {}
    if spec.get("tracemalloc"):
        import tracemalloc

        from pipeline.tracker import updates as updates_module
        table = updates_module.Updates.table

        def snapshot_then_table(self, plots_):  # the loop is done, every update still in Python lists
            out["tracemalloc"] = [(str(stat.traceback[0]), stat.size, stat.count)
                                  for stat in tracemalloc.take_snapshot().statistics("lineno")[:8]]
            out["tracemalloc_total"] = tracemalloc.get_traced_memory()[0]
            return table(self, plots_)

        updates_module.Updates.table = snapshot_then_table
        tracemalloc.start()
    profiler = None
    if spec.get("profile"):
        import cProfile
        profiler = cProfile.Profile()
        profiler.enable()
    start, cpu = time.perf_counter(), time.process_time()
    updates = run.track(tracked, tracker)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    if profiler is not None:
        import io as text_io
        import pstats
        profiler.disable()
        stream = text_io.StringIO()
        pstats.Stats(profiler, stream=stream).sort_stats("tottime").print_stats(10)
        out["profile"] = stream.getvalue()
    update_bytes = sum(np.asarray(column).nbytes for column in updates.values())
    from pipeline.tracker.updates import confirmed_associations
    aircraft = tracked.target_id[updates["plot_id"]] >= 0  # plot ids are rows here
    on_confirmed = confirmed_associations(updates, tracker.management) & aircraft
    live = slots[0]
    return {**out, "plots": len(plots), "tracked": len(tracked), "seconds": elapsed, "cpu": cpu,
            "plots_bytes": plots_bytes, "update_rows": len(updates["track_id"]), "update_bytes": update_bytes,
            "rss_imported": rss_imported, "rss_built": rss_built, "peak_built": peak_built, "peak": _rss_peak(),
            "slots": len(live.tracks), "on_confirmed": float(on_confirmed.sum() / max(aircraft.sum(), 1))}


# ----------------------------------------------------------------------------- the parent

@dataclass
class Config:
    name: str
    aircraft: int
    scans: int
    kind: str  # "aircraft" (the sweep) or "hours"
    value: float


def run_child(spec: dict) -> tuple[dict, float]:
    """One configuration in a fresh process: what it measured, and its peak RSS (bytes) from os.wait4."""
    child_process = subprocess.Popen([sys.executable, __file__, "--child", json.dumps(spec)], stdout=subprocess.PIPE,
                                     text=True)
    output = child_process.stdout.read()
    _, status, usage = os.wait4(child_process.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"configuration {spec} failed")
    return json.loads(output.strip().splitlines()[-1]), usage.ru_maxrss * 1024.0


def estimate_peak(result: dict, peak: float) -> tuple[float, bool]:
    """The peak RSS of tracking the whole recording: measured when it was tracked whole, else the
    built recording's RSS plus the tracked prefix's growth per plot times all the plots."""
    if result["tracked"] == result["plots"]:
        return peak, False
    per_plot = (result["peak"] - result["rss_built"]) / result["tracked"]
    return max(result["peak_built"], result["rss_built"] + per_plot * result["plots"]), True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", default="params.yaml", help="radar and tracker params (default: params.yaml)")
    parser.add_argument("--methods", nargs="+", default=["kalman_cv", "imm_gnn"],
                        help="methods to run (default: kalman_cv imm_gnn; via needs --models)")
    parser.add_argument("--models", default=None,
                        help="folder of trained models and tuned filters (default: untuned filters, no networks)")
    parser.add_argument("--aircraft", nargs="*", type=int, default=[1, 10, 100, 1000],
                        help="aircraft at once in the sweep (default: 1 10 100 1000; 1 is the speed goal's reference; "
                             "none: no sweep)")
    parser.add_argument("--minutes", type=float, default=5.0, help="recording length of the sweep (default: 5)")
    parser.add_argument("--hours", nargs="*", type=float, default=[1.0, 24.0],
                        help="lengths of the long recordings (default: 1 24; none: no long runs)")
    parser.add_argument("--long-aircraft", type=int, default=50, help="aircraft at once in the long recordings")
    parser.add_argument("--false-plots", type=float, default=300.0, help="mean false plots per scan (default: 300)")
    parser.add_argument("--detection", type=float, default=1.0, help="detection probability per scan (default: 1)")
    parser.add_argument("--max-tracked", type=int, default=250_000,
                        help="track at most this many plots of a recording; beyond, extrapolate its memory (est.)")
    parser.add_argument("--window", type=float, default=4000.0, help="young-track radius / VIA window, metres")
    parser.add_argument("--seed", type=int, default=16)
    parser.add_argument("--no-diagnose", action="store_true", help="skip the profiles of a failed goal")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return
    if "via" in args.methods and not args.models:
        parser.error("via needs trained networks: give --models")

    from pipeline.params import load_params
    period = load_params(args.params).radar.scan_period_s
    configs = [Config(f"{n} aircraft, {args.minutes:g} min", n, round(args.minutes * 60 / period), "aircraft", n)
               for n in args.aircraft]
    configs += [Config(f"{args.long_aircraft} aircraft, {h:g} h", args.long_aircraft, round(h * 3600 / period),
                       "hours", h) for h in args.hours]
    base = {"params": args.params, "models": args.models, "false_plots": args.false_plots, "seed": args.seed,
            "detection": args.detection, "max_tracked": args.max_tracked, "window": args.window}
    print(f"{args.false_plots:g} false plots per scan, {period:g} s scans, detection {args.detection:g}; "
          f"filters: {args.models or 'untuned (params start values)'}")
    header = (f"{'recording':24s} {'method':10s} {'plots':>10s} {'tracked':>9s} {'plots/s':>8s} {'per CPU s':>9s} "
              f"{'slots':>6s} {'conf.':>5s} {'table MiB':>9s} {'updates MiB':>11s} {'peak MiB':>9s}")
    print(header)
    rows = []
    for config in configs:
        for method in args.methods:
            spec = {**base, "method": method, "aircraft": config.aircraft, "scans": config.scans}
            result, peak = run_child(spec)
            peak, estimated = estimate_peak(result, peak)
            rows.append((config, method, result, peak, estimated))
            print(f"{config.name:24s} {method:10s} {result['plots']:10,d} {result['tracked']:9,d} "
                  f"{result['tracked'] / result['seconds']:8,.0f} {result['tracked'] / result['cpu']:9,.0f} "
                  f"{result['slots']:6,d} {result['on_confirmed']:5.0%} {result['plots_bytes'] / MIB:9.0f} "
                  f"{result['update_bytes'] / MIB:11.0f} "
                  f"{peak / MIB:9,.0f}{' est.' if estimated else ''}", flush=True)
    print("(plots/s: tracking loop only; slots: the live-track arrays' size at the end, every plot's pre-filter "
          "scans them all; conf.: share of the aircraft's plots that went to confirmed tracks; table: the plot "
          "table's arrays; updates: the update table's arrays, for the tracked plots; peak: the child's peak RSS, "
          "est. = extrapolated from the tracked prefix)")
    goals(args, rows, base)


def goals(args, rows, base) -> None:
    """The issue's two goals, pass or fail, and where the time or memory goes when one fails."""
    rate = {(c.kind, c.value, m): r["tracked"] / r["cpu"] for c, m, r, _, _ in rows}
    print("\nGoals (issue 16, item 4):")
    slow = []
    for method in args.methods:
        one, many = rate.get(("aircraft", 1, method)), rate.get(("aircraft", 1000, method))
        if one is None or many is None:
            print(f"  speed   {method:10s} needs the 1 and 1000 aircraft runs: not judged")
            continue
        ok = many >= 0.5 * one
        slow += [] if ok else [method]
        print(f"  speed   {method:10s} 1000 aircraft {many:,.0f} plots/CPU s vs single aircraft {one:,.0f}: "
              f"{many / one:.2f}x (goal >= 0.5x) {'PASS' if ok else 'FAIL'}")
    heavy = []
    for config, method, result, peak, estimated in rows:
        if config.kind == "hours" and config.value == 24:
            ok = peak < GIB
            heavy += [] if ok else [(config, method, result)]
            print(f"  memory  {method:10s} 24 h, {result['plots']:,d} plots: peak {peak / GIB:.2f} GiB"
                  f"{' (estimated)' if estimated else ''} (goal < 1 GiB) {'PASS' if ok else 'FAIL'}")
    if not any(c.kind == "hours" and c.value == 24 for c, *_ in rows):
        print("  memory  needs the 24 h run: not judged")
    if args.no_diagnose:
        return
    for method in slow:
        minutes = min(args.minutes, 2.0)
        print(f"\nWhere the time goes: {method}, 1000 aircraft, {minutes:g} min, cProfile (top 10 by own time)")
        from pipeline.params import load_params
        period = load_params(args.params).radar.scan_period_s
        result, _ = run_child({**base, "method": method, "aircraft": 1000, "scans": round(minutes * 60 / period),
                               "profile": True})
        print(result["profile"].strip())
    if heavy:
        config, method, result = heavy[0]
        per_plot = (result["peak"] - result["rss_built"]) / result["tracked"]
        print(f"\nWhere the memory goes ({method}, {config.name}):")
        print(f"  interpreter and imports        {result['rss_imported'] / MIB:8,.0f} MiB")
        print(f"  plot table arrays              {result['plots_bytes'] / MIB:8,.0f} MiB "
              f"({result['plots_bytes'] / result['plots']:.0f} B per plot, all {result['plots']:,d} plots held)")
        print(f"  tracking (update lists, table) {per_plot:8,.0f} B per tracked plot (peak RSS growth), "
              f"{per_plot * result['plots'] / MIB:,.0f} MiB for all plots")
        print(f"  of which the update table      {result['update_bytes'] / result['update_rows']:8,.0f} B per update "
              f"as arrays ({result['update_rows'] / result['tracked']:.2f} updates per plot)")
        period_scans = 100
        small, _ = run_child({**base, "method": method, "aircraft": config.aircraft, "scans": period_scans,
                              "tracemalloc": True})
        rows_ = small["update_rows"]
        print(f"  tracemalloc after the loop of a {period_scans}-scan run ({small['tracked']:,d} plots, "
              f"{rows_:,d} updates), before the update table is made: "
              f"{small['tracemalloc_total'] / rows_:,.0f} B per update traced in all; top lines:")
        for where, size, count in small["tracemalloc"]:
            print(f"    {size / rows_:7,.0f} B/update {count:9,d} blocks  {where}")


if __name__ == "__main__":
    main()

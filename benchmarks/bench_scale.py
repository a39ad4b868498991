"""Tracker scale (issue 16, item 4): plots/s and peak memory on synthetic dense recordings.

Builds a recording in memory, as `track` would hold it (one `Plots` table): N aircraft at once
in one radar's coverage, each detected every scan with the radar's noise (params' `radar`:
range, azimuth and altitude errors, placed and given their covariance by the pipeline's own
conversion), plus a Poisson number of false plots per scan, uniform in the coverage disc. An
aircraft flies straight or turns (0.5-3 deg/s) and changes between the two at random; one that
leaves the coverage is replaced by a new one anywhere in it, so N stay in the air. Each plot's
time within its scan follows its azimuth (the antenna's sweep).

Each configuration (recording x method) runs in a fresh child process, so its peak resident
memory (`os.wait4`) is its own. The sweep (1, 10, 100 and 1000 aircraft for `--minutes`) builds the
recording in memory, as one `Plots` table, and times the tracking loop only (no generation, no
output): plots per wall second and per CPU second of the child (the CPU figure is the steadier on
a shared machine; the speed goal is judged on it). The long recordings (`--long-aircraft`
aircraft for each of `--hours`) are written as a Parquet recording first (`--recordings`, a part
at a time) and tracked by `python -m pipeline track` whole, as a user would: its wall time and
peak memory, reading, tracking and writing `compute.chunk_plots` plots at a time. With
`--out-of-order` they are written with each pair of CHUNK_SCANS-scan parts swapped (files merged
out of order), so that `track` sorts them first (`pipeline.recordings.external_sort`), in a temporary folder
beside its output. `--reading` also reads each long recording without tracking it, in a fresh
process, both as `track` does and whole (`plot_table.read_parquet_recording`, which sorts in
memory): the reading's own peak memory, which the tracker's would otherwise hide.

The classical methods need only filters: by default the filters at params' start values (what
`tune_kalman` starts from; tuned values change the cost little), written to a temporary models
folder. `--models` takes a folder of real models instead (needed for `via`).

Then the issue's two goals, pass or fail: at 1000 aircraft at least half the single-aircraft rate;
peak memory of a 24-hour dense recording under 1 GiB (or, without a 24-hour run, how the peak
grows with the length). For a speed goal that fails it shows where the time goes (cProfile top 10
of the 1000-aircraft case, a shorter run).

    python benchmarks/bench_scale.py                    # the issue's sizes, ~15 min on one core
    python benchmarks/bench_scale.py --minutes 1 --aircraft 1 100 --hours 0.1 --no-diagnose  # ~15 s
    python benchmarks/bench_scale.py --methods kalman_cv --aircraft --hours 1 4 8  # memory against length
    python benchmarks/bench_scale.py --methods kalman_cv --aircraft --hours 1 4 --out-of-order  # sorted first
    python benchmarks/bench_scale.py --methods --aircraft --hours 1 4 24 --out-of-order --reading  # reading alone
    python benchmarks/bench_scale.py --methods kalman_cv imm_gnn via --models models
"""

from __future__ import annotations

import argparse
import json
import os
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
CHUNK_SCANS = 100           # the recording is generated this many scans at a time


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
    radar model makes them (`pipeline.simulation.radar`): Gaussian range, azimuth and altitude errors, then
    quantised to ASTERIX CAT048 resolutions (time to 1/128 s) and placed in ECEF; with the
    converted-measurement covariance `track` gives them. Returns times, the measurements
    (`pipeline.simulation.radar.Measurements`) and covariances."""
    from pipeline.geometry import geodesy
    from pipeline.simulation import radar as radar_model
    lat, lon, alt = geodesy.local_to_geodetic(east, north, altitude, radar)
    slant, azimuth, alt = geodesy.true_measurement(geodesy.geodetic_to_ecef(lat, lon, alt), radar)
    measured = radar_model.measure(times, *radar_model.add_measurement_noise(rng, slant, azimuth, alt, radar), radar,
                                   times)
    return measured.time_unix_s, measured, geodesy.measurement_covariance(measured.ecef, radar)


def dense_parts(radar, aircraft: int, false_plots: float, scans: int, seed: int, detection: float = 1.0):
    """The plots of `scans` antenna scans with `aircraft` aircraft in the air at every moment and
    Poisson(`false_plots`) false plots per scan, each aircraft detected with probability
    `detection` per scan, CHUNK_SCANS scans at a time, in time order: per part its times, quantised
    measurements (`pipeline.simulation.radar.Measurements`), covariances and target ids (NO_TARGET: false)."""
    from pipeline.recordings.plot_table import NO_TARGET
    rng = np.random.default_rng(seed)
    period = radar.scan_period_s
    first_scan = np.ceil(T0 / period) * period  # the antenna points north at whole multiples of the period
    clutter_counts = rng.poisson(false_plots, scans)
    flights = _spawn(rng, aircraft, radar)
    ids = np.arange(aircraft, dtype=np.int32)
    next_id = aircraft
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
        yield (*_measured(times[order], east[order], north[order], altitude[order], radar, rng), who[order])


def dense_recording(radar, aircraft: int, false_plots: float, scans: int, seed: int, detection: float = 1.0):
    """The plot table (`pipeline.recordings.plot_table.Plots`, time order, truth known) of `dense_parts`."""
    from pipeline.recordings.plot_table import NO_SCENARIO, Plots
    parts = list(dense_parts(radar, aircraft, false_plots, scans, seed, detection))
    time_, position, range_m, covariance, target = (
        np.concatenate([part[0] for part in parts]), np.concatenate([part[1].ecef for part in parts]),
        np.concatenate([part[1].range_m for part in parts]), np.concatenate([part[2] for part in parts]),
        np.concatenate([part[3] for part in parts]))
    n = len(time_)
    return Plots(np.arange(n, dtype=np.int64), np.full(n, radar.radar_id, np.int32), np.full(n, NO_SCENARIO, np.int32),
                 time_, position, range_m, covariance, target, True, {radar.radar_id: radar})


def write_recording(folder: Path, radar, aircraft: int, false_plots: float, scans: int, seed: int,
                    detection: float = 1.0, swapped: bool = False) -> tuple[Path, Path, int]:
    """`dense_parts` written as a `track` input (PLOT_INPUT_SCHEMA, no scenario id, with target ids,
    plot ids counting up in time order) and its radar description, a part at a time: the plots and
    radar files, and the plot count. `swapped`: each pair of parts (CHUNK_SCANS scans each) written
    later part first, as files merged out of order (half the plots out of time order, by up to
    2 x CHUNK_SCANS scans: no day error), so that `track` must sort the recording."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline import io
    from pipeline.recordings.plot_table import PLOT_INPUT_SCHEMA, RADAR_FILE_SCHEMA
    folder.mkdir(parents=True, exist_ok=True)
    plots_path, radar_path = folder / "plots.parquet", folder / "radar.parquet"
    count, held = 0, None
    with pq.ParquetWriter(plots_path, PLOT_INPUT_SCHEMA, compression="zstd") as writer:
        for number, (times, measured, _, target) in enumerate(dense_parts(radar, aircraft, false_plots, scans, seed,
                                                                           detection)):
            n = len(times)
            part = pa.table({
                "plot_id": np.arange(count, count + n, dtype=np.int64), "radar_id": np.full(n, radar.radar_id, np.int32),
                "time_unix_s": times, "range_m": measured.range_m, "azimuth_deg": measured.azimuth_deg,
                "altitude_m": measured.altitude_m, "scenario_id": pa.nulls(n, pa.int32()),
                "target_id": target}, schema=PLOT_INPUT_SCHEMA)
            count += n
            if swapped and number % 2 == 0:
                held = part
                continue
            writer.write_table(part)
            if held is not None:
                writer.write_table(held)
                held = None
        if held is not None:
            writer.write_table(held)
    io.write_parquet(pa.table({"radar_id": [radar.radar_id], "latitude_deg": [radar.latitude_deg],
                               "longitude_deg": [radar.longitude_deg], "height_m": [radar.height_m],
                               "scan_period_s": [radar.scan_period_s], "sigma_range_m": [radar.sigma_range_m],
                               "sigma_azimuth_deg": [radar.sigma_azimuth_deg],
                               "sigma_altitude_m": [radar.sigma_altitude_m]}, schema=RADAR_FILE_SCHEMA), radar_path)
    return plots_path, radar_path, count


# ----------------------------------------------------------------------------- one configuration (child)

def _untuned_filters(params, folder: Path) -> Path:
    """`folder` with kalman_tuned.json holding the filters at params' start values (what
    `tune_kalman` starts from; tuned values change the cost little)."""
    from pipeline import io
    from pipeline.filters.classical_filters import KINDS
    from pipeline.stages.tune_stage import start_settings
    io.write_json({"cost": "rmse", "filters": {kind: start_settings(kind, params).to_dict() for kind in KINDS}},
                  folder / "kalman_tuned.json")
    return folder


def _models(spec: dict):
    from pipeline.settings import load_params
    from pipeline.tracker.loading import load_models
    params = load_params(spec["params"])
    if spec["models"]:
        return params, load_models(Path(spec["models"]), params, [spec["method"]])
    with tempfile.TemporaryDirectory() as folder:
        return params, load_models(_untuned_filters(params, Path(folder)), params, [spec["method"]])


def child(spec: dict) -> dict:
    """Build one recording in memory and track it with one method; what it measured."""
    from pipeline.tracker import registry, run
    params, models = _models(spec)
    plots = dense_recording(params.radar, spec["aircraft"], spec["false_plots"], spec["scans"], spec["seed"],
                            spec["detection"])
    slots = []

    class Watched(run.LiveTracks):  # to report how many track slots the loop had
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            slots.append(self)

    run.LiveTracks = Watched
    tracker = registry.compose(spec["method"], models, params.tracker, spec["window"], [params.tracker.seed])
    out = {}
    profiler = None
    if spec.get("profile"):
        import cProfile
        profiler = cProfile.Profile()
        profiler.enable()
    start, cpu = time.perf_counter(), time.process_time()
    updates = run.track(plots, tracker)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    if profiler is not None:
        import io as text_io
        import pstats
        profiler.disable()
        stream = text_io.StringIO()
        pstats.Stats(profiler, stream=stream).sort_stats("tottime").print_stats(10)
        out["profile"] = stream.getvalue()
    from pipeline.tracker.updates import confirmed_associations
    aircraft = plots.target_id[updates["plot_id"]] >= 0  # plot ids are rows here
    on_confirmed = confirmed_associations(updates, tracker.management) & aircraft
    return {**out, "plots": len(plots), "seconds": elapsed, "cpu": cpu, "slots": len(slots[0].tracks),
            "on_confirmed": float(on_confirmed.sum() / max(aircraft.sum(), 1))}


# ----------------------------------------------------------------------------- the parent

@dataclass
class Config:
    name: str
    aircraft: int
    scans: int
    kind: str  # "aircraft" (the sweep, in memory) or "hours" (a recording through `track`)
    value: float


def _waited(command: list[str], **kwargs) -> tuple[subprocess.Popen, str, float, float]:
    """Run `command`; the process, its stdout, its wall seconds and its peak RSS (bytes, os.wait4)."""
    start = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True, **kwargs)
    output = process.stdout.read()
    _, status, usage = os.wait4(process.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(command)} failed")
    return process, output, time.perf_counter() - start, usage.ru_maxrss * 1024.0


def run_child(spec: dict) -> tuple[dict, float]:
    """One in-memory configuration in a fresh process: what it measured, and its peak RSS (bytes)."""
    _, output, _, peak = _waited([sys.executable, __file__, "--child", json.dumps(spec)])
    return json.loads(output.strip().splitlines()[-1]), peak


def _recording(args, config: Config, folder: Path) -> Path:
    """The folder of the config's recording in `folder`, written the first time it is asked for."""
    from pipeline.settings import load_params
    recording = folder / (config.name.replace(" ", "_").replace(",", "") + ("_swapped" if args.out_of_order else ""))
    if not (recording / "radar.parquet").exists():
        write_recording(recording, load_params(args.params).radar, config.aircraft, args.false_plots, config.scans,
                        args.seed, args.detection, args.out_of_order)
    return recording


def read_child(spec: dict) -> dict:
    """Open a recording as `track` does (`streamed_recording.read_recording`, sorting in `scratch` if
    it must) or whole (`plot_table.read_parquet_recording`, sorting in memory), and place all its
    plots chunk by chunk without tracking them: the plots and wall seconds."""
    import contextlib

    from pipeline.settings import load_params
    from pipeline.recordings import plot_table, streamed_recording
    radar = load_params(spec["params"]).radar
    paths = Path(spec["plots"]), Path(spec["radar"])
    start = time.perf_counter()
    opened = (contextlib.nullcontext(plot_table.read_parquet_recording(*paths, radar)) if spec["whole"]
              else streamed_recording.read_recording(*paths, radar, Path(spec["scratch"])))
    with opened as recording:
        plots = sum(len(chunk) for _, chunks in recording.scenarios(spec["chunk_plots"]) for chunk in chunks)
    return {"plots": plots, "seconds": time.perf_counter() - start}


def run_reading(args, config: Config, whole: bool, folder: Path) -> dict:
    """`read_child` on the config's recording in a fresh process: plots, wall seconds, peak RSS (bytes)."""
    from pipeline.settings import load_params
    recording = _recording(args, config, folder)
    spec = {"params": args.params, "plots": str(recording / "plots.parquet"), "radar": str(recording / "radar.parquet"),
            "whole": whole, "scratch": str(recording), "chunk_plots": load_params(args.params).chunk_plots}
    _, output, _, peak = _waited([sys.executable, __file__, "--read-child", json.dumps(spec)], stderr=subprocess.DEVNULL)
    return {**json.loads(output.strip().splitlines()[-1]), "peak": peak}


def run_command(args, config: Config, method: str, models: Path, folder: Path) -> dict:
    """`python -m pipeline track` on the config's recording (written to `folder` once): plots,
    wall seconds, peak RSS (bytes) and track updates."""
    recording = _recording(args, config, folder)
    out = recording / f"tracks_{method}.parquet"
    _, _, seconds, peak = _waited([sys.executable, "-m", "pipeline", "track", "--params", args.params, "--plots",
                                   str(recording / "plots.parquet"), "--radar", str(recording / "radar.parquet"),
                                   "--method", method, "--models", str(models), "--window", str(args.window),
                                   "--out", str(out)], stderr=subprocess.DEVNULL)
    summary = json.loads(out.with_name(f"{out.stem}.summary.json").read_text())
    out.unlink()
    return {"plots": summary["plots_tracked"], "seconds": seconds, "peak": peak, "updates": summary["track_updates"],
            "confirmed": summary["confirmed_tracks"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", default="params.yaml", help="radar and tracker params (default: params.yaml)")
    parser.add_argument("--methods", nargs="*", default=["kalman_cv", "imm_gnn"],
                        help="methods to run (default: kalman_cv imm_gnn; via needs --models; none: no tracking)")
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
    parser.add_argument("--out-of-order", action="store_true",
                        help=f"write the long recordings with each pair of {CHUNK_SCANS}-scan parts swapped, so that "
                             f"`track` must sort them")
    parser.add_argument("--recordings", default=None,
                        help="folder for the long recordings, kept for reruns (default: a temporary folder)")
    parser.add_argument("--window", type=float, default=4000.0, help="young-track radius / VIA window, metres")
    parser.add_argument("--seed", type=int, default=16)
    parser.add_argument("--no-diagnose", action="store_true", help="skip the profile of a failed speed goal")
    parser.add_argument("--reading", action="store_true",
                        help="also read each long recording without tracking it, as `track` does and whole "
                             "(sorted in memory): the reading's own peak memory")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--read-child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return
    if args.read_child:
        print(json.dumps(read_child(json.loads(args.read_child))))
        return
    if "via" in args.methods and not args.models:
        parser.error("via needs trained networks: give --models")

    from pipeline.settings import load_params
    params = load_params(args.params)
    period = params.radar.scan_period_s
    sweep = [Config(f"{n} aircraft, {args.minutes:g} min", n, round(args.minutes * 60 / period), "aircraft", n)
             for n in args.aircraft]
    long = [Config(f"{args.long_aircraft} aircraft, {h:g} h", args.long_aircraft, round(h * 3600 / period), "hours", h)
            for h in args.hours]
    base = {"params": args.params, "models": args.models, "false_plots": args.false_plots, "seed": args.seed,
            "detection": args.detection, "window": args.window}
    print(f"{args.false_plots:g} false plots per scan, {period:g} s scans, detection {args.detection:g}; "
          f"filters: {args.models or 'untuned (params start values)'}")
    rows = []
    width = method_width(args.methods)
    if sweep:
        print(f"{'recording':24s} {'method':{width}s} {'plots':>10s} {'plots/s':>8s} {'per CPU s':>9s} {'slots':>6s} "
              f"{'conf.':>5s} {'peak MiB':>9s}")
    for config in sweep:
        for method in args.methods:
            result, peak = run_child({**base, "method": method, "aircraft": config.aircraft, "scans": config.scans})
            rows.append((config, method, result, peak))
            print(f"{config.name:24s} {method:{width}s} {result['plots']:10,d} {result['plots'] / result['seconds']:8,.0f} "
                  f"{result['plots'] / result['cpu']:9,.0f} {result['slots']:6,d} {result['on_confirmed']:5.0%} "
                  f"{peak / MIB:9,.0f}", flush=True)
    if sweep:
        print("(in memory, the tracking loop only; slots: the live-track arrays' size at the end; conf.: share of "
              "the aircraft's plots that went to confirmed tracks; peak: the child's peak RSS)")
    if long and args.methods:
        print(f"\n{'recording':24s} {'method':{width}s} {'plots':>10s} {'seconds':>8s} {'plots/s':>8s} {'updates':>10s} "
              f"{'confirmed':>9s} {'peak MiB':>9s}   (python -m pipeline track, chunks of "
              f"{params.chunk_plots:,d} plots{'; out of order: parts swapped in pairs' if args.out_of_order else ''})")
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(args.recordings) if args.recordings else Path(scratch)
        models = Path(args.models) if args.models else _untuned_filters(params, Path(scratch))
        for config in long:
            for method in args.methods:
                result = run_command(args, config, method, models, folder)
                rows.append((config, method, result, result["peak"]))
                print(f"{config.name:24s} {method:{width}s} {result['plots']:10,d} {result['seconds']:8,.0f} "
                      f"{result['plots'] / result['seconds']:8,.0f} {result['updates']:10,d} "
                      f"{result['confirmed']:9,d} {result['peak'] / MIB:9,.0f}", flush=True)
        if long and args.reading:
            print(f"\n{'recording':24s} {'reader':{width}s} {'plots':>10s} {'seconds':>8s} {'peak MiB':>9s}   (read and "
                  f"placed chunk by chunk, not tracked)")
        for config in long if args.reading else ():
            for whole in (False, True):
                result = run_reading(args, config, whole, folder)
                print(f"{config.name:24s} {'whole' if whole else 'track':{width}s} {result['plots']:10,d} "
                      f"{result['seconds']:8,.1f} {result['peak'] / MIB:9,.0f}", flush=True)
    goals(args, rows, base)


def method_width(methods: list[str]) -> int:
    """The method column's width: the longest name, at least 10."""
    return max([10, *map(len, methods)])


def goals(args, rows, base) -> None:
    """The issue's two goals, pass or fail, and where the time goes when the speed goal fails."""
    rate = {(c.kind, c.value, m): r["plots"] / r["cpu"] for c, m, r, _ in rows if c.kind == "aircraft"}
    width = method_width(args.methods)
    print("\nGoals (issue 16, item 4; issue 29 for the learned methods):")
    slow = []
    for method in args.methods:
        one, many = rate.get(("aircraft", 1, method)), rate.get(("aircraft", 1000, method))
        if one is None or many is None:
            print(f"  speed   {method:{width}s} needs the 1 and 1000 aircraft runs: not judged")
            continue
        ok = many >= 0.5 * one
        slow += [] if ok else [method]
        print(f"  speed   {method:{width}s} 1000 aircraft {many:,.0f} plots/CPU s vs single aircraft {one:,.0f}: "
              f"{many / one:.2f}x (goal >= 0.5x) {'PASS' if ok else 'FAIL'}")
    for method in args.methods:
        long = sorted((c.value, r["plots"], peak) for c, m, r, peak in rows if c.kind == "hours" and m == method)
        for hours, plots, peak in long:
            verdict = f"(goal < 1 GiB) {'PASS' if peak < GIB else 'FAIL'}" if hours == 24 else ""
            print(f"  memory  {method:{width}s} {hours:g} h, {plots:,d} plots: peak {peak / GIB:.2f} GiB {verdict}")
        if len(long) > 1:
            (h0, p0, m0), (h1, p1, m1) = long[0], long[-1]
            print(f"  memory  {method:{width}s} from {h0:g} h to {h1:g} h: {p1 / p0:.1f}x the plots, {m1 / m0:.2f}x the peak")
    if args.no_diagnose:
        return
    for method in slow:
        minutes = min(args.minutes, 2.0)
        print(f"\nWhere the time goes: {method}, 1000 aircraft, {minutes:g} min, cProfile (top 10 by own time)")
        from pipeline.settings import load_params
        period = load_params(args.params).radar.scan_period_s
        result, _ = run_child({**base, "method": method, "aircraft": 1000, "scans": round(minutes * 60 / period),
                               "profile": True})
        print(result["profile"].strip())


if __name__ == "__main__":
    main()

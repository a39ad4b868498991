"""`python -m pipeline real-traffic`: real aircraft (OpenSky state vectors) past our simulated radar, written as a
recording `track` reads and a truth `score` reads (`pipeline.simulation.real_traffic`)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pipeline import io
from pipeline.params import Params
from pipeline.recordings import opensky_states
from pipeline.simulation import real_traffic, simulate

log = logging.getLogger("pipeline")

OUTPUTS = ("plots.parquet", "truth.parquet", "radar.parquet")


def run_real_traffic(params: Params, states_path: Path, latitude_deg: float, longitude_deg: float, height_m: float,
                     out: Path) -> None:
    """Fly the aircraft of the OpenSky CSV `states_path` past params' radar moved to the site, and write the plots,
    the per-scan truth and the radar description into the folder `out` (simulate's files). InputError for a
    site outside the earth or an output that would replace the input."""
    for name, value, low, high in (("--latitude", latitude_deg, -90.0, 90.0), ("--longitude", longitude_deg, -180.0, 180.0),
                                   ("--height", height_m, -500.0, 10000.0)):
        if not np.isfinite(value) or not low <= value <= high:
            raise io.InputError(f"{name} {value!r}: outside [{low:g}, {high:g}]")
    io.check_outputs({"--states": [states_path]}, {f"--out's {name}": out / name for name in OUTPUTS})
    truth, skipped = opensky_states.read_states(states_path)
    if skipped:
        log.warning("real-traffic: %s: left out %s", states_path,
                    ", ".join(f"{count} reports {reason}" for reason, count in skipped.items()))
    moved = real_traffic.at_site(params, latitude_deg, longitude_deg, height_m)
    routes = real_traffic.routes_of(truth)
    plots, scan_truth = real_traffic.simulate_scene(moved, routes)
    simulate.write_split(plots, scan_truth, simulate.radar_description(moved), out)
    is_target = plots.column("is_target").to_numpy(zero_copy_only=False)
    covered = scan_truth.column("in_coverage").to_numpy(zero_copy_only=False)
    seen = len(set(scan_truth.column("target_id").to_numpy()[covered].tolist()))
    log.info("real-traffic: %d aircraft (%d routes) past a radar at %.4f N, %.4f E: %d in its coverage, %d target "
             "plots and %d false -> %s", len(set(truth.column("target_id").to_pylist())), len(routes), latitude_deg,
             longitude_deg, seen, int(is_target.sum()), int((~is_target).sum()), out)

"""A scene of real aircraft: OpenSky state vectors flown past our simulated radar (issue 33's real trajectories).

Every route of the project is otherwise our own route model's. Here the trajectories are real
(`pipeline.recordings.opensky_states`): each aircraft's reports, split where they stop for more than
`GAP_S` (a track the network lost), become routes of a cubic spline through their ECEF positions (scipy
`make_interp_spline`, its derivative the velocity: ADS-B positions come every 10 s or so, and a spline
through them flies the turns between), and the radar sees them as it sees the simulator's routes
(`simulate.aircraft_plots`: beam crossings, coverage, detection by SNR, measurement noise, the ASTERIX
quantisation) with its clutter over the recording's span (`simulate.false_plots`). Every aircraft is taken as
an airliner for its radar cross-section (the recording is airline traffic). The radar is params' `radar`
moved to the given site; all aircraft are one scenario (0), one scene as `track` tracks a recording.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pyarrow as pa
from scipy.interpolate import make_interp_spline

from pipeline.params import Params
from pipeline.simulation import simulate

GAP_S = 60.0          # a longer silence in an aircraft's reports starts a new route of it
MIN_REPORTS = 4       # a route needs this many reports (a cubic spline's)
AIRCRAFT_TYPE = "airliner"
SCENARIO_ID = 0
STREAM = 33           # the draws' seed: (simulate seed, STREAM, route, stream): apart from every split's


def routes_of(truth: pa.Table) -> list[dict[str, np.ndarray]]:
    """Routes (simulate.ROUTE_COLUMNS, one dict each, `route_id` numbered from 0) of the truth table
    `opensky_states.read_states` gives, with each route's target id (its aircraft) under `target_id`."""
    target = truth.column("target_id").to_numpy()
    time = truth.column("time_unix_s").to_numpy()
    position = np.stack([truth.column(f"{axis}_ecef_m").to_numpy() for axis in "xyz"], axis=1)
    routes = []
    for aircraft in np.unique(target).tolist():
        rows = np.flatnonzero(target == aircraft)
        for part in np.split(rows, np.flatnonzero(np.diff(time[rows]) > GAP_S) + 1):
            if len(part) < MIN_REPORTS:
                continue
            spline = make_interp_spline(time[part], position[part], k=3)
            velocity = spline(time[part], nu=1)
            routes.append({"route_id": np.full(len(part), len(routes), np.int64),
                           "aircraft_type": np.full(len(part), AIRCRAFT_TYPE, dtype=object),
                           "time_unix_s": time[part], "x_ecef_m": position[part, 0], "y_ecef_m": position[part, 1],
                           "z_ecef_m": position[part, 2], "vx_ecef_mps": velocity[:, 0], "vy_ecef_mps": velocity[:, 1],
                           "vz_ecef_mps": velocity[:, 2], "target_id": np.full(len(part), aircraft, np.int32)})
    return routes


def at_site(params: Params, latitude_deg: float, longitude_deg: float, height_m: float) -> Params:
    """Params with the radar moved to the site."""
    radar = dataclasses.replace(params.radar, latitude_deg=latitude_deg, longitude_deg=longitude_deg, height_m=height_m)
    return dataclasses.replace(params, radar=radar)


def simulate_scene(params: Params, routes: list[dict[str, np.ndarray]]) -> tuple[pa.Table, pa.Table]:
    """The radar's plots (simulate.PLOT_SCHEMA, time order, plot ids from 0) and per-scan truth
    (simulate.TRUTH_SCHEMA) of the routes, one scenario, with the clutter of the scans over their span."""
    plot_parts, truth_parts = [], []
    for route in routes:
        route_id = int(route["route_id"][0])
        detection_rng, noise_rng = (np.random.default_rng([params.simulate_seed, STREAM, route_id, stream])
                                    for stream in range(2))
        plots, truth = simulate.aircraft_plots(params, route, detection_rng, noise_rng, SCENARIO_ID,
                                               int(route["target_id"][0]))
        plot_parts.append(plots)
        truth_parts.append(truth)
    if routes:
        start = min(float(route["time_unix_s"][0]) for route in routes)
        end = max(float(route["time_unix_s"][-1]) for route in routes)
        plot_parts.append(simulate.false_plots(params, np.random.default_rng([params.simulate_seed, STREAM]), start,
                                               end, SCENARIO_ID))
    joined = {name: np.concatenate([part[name] for part in plot_parts]) for name in plot_parts[0]} if plot_parts else {}
    return simulate.tables([joined] if joined else [], truth_parts)

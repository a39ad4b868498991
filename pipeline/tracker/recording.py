"""Track updates as a table: the track-update schema every tracked recording is written in, and the
tracker run over a recording's scenarios into that table.

One row per track update (TRACK_SCHEMA; docs/tracking-a-recording.md): the plot's radar, the track,
its ECEF and geodetic position, the range from the plot's radar, the management weight and status,
how the plot was associated, the position's ECEF covariance (upper triangle, null for an
estimator that gives none), and the estimator's velocity: ECEF, as ground speed, course and vertical
rate at the track's position, and its ECEF covariance (null for a track's start, for an estimator
without velocity, the thesis networks, and the covariance for one without it, the LSTM update). `track` writes it, `associate` and the two-radar bench read it
(`pipeline.association.track_tables`), so it lives with the tracker that makes it.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Iterable, Iterator, Mapping

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.geometry import geodesy
from pipeline.params import Params, Radar
from pipeline.recordings.plot_table import NO_SCENARIO, Plots
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.management import TrackManagement
from pipeline.tracker.refusals import RefusalCounts, warn_refusals
from pipeline.tracker.run import track_chunks
from pipeline.tracker.updates import positions

log = logging.getLogger("pipeline")

POSITION_COLUMNS = tuple((name, pa.float64()) for name in ("x_ecef_m", "y_ecef_m", "z_ecef_m", "latitude_deg",
                                                             "longitude_deg", "altitude_m"))  # a track's position
TRACK_SCHEMA = io.schema(
    ("radar_id", pa.int32()),
    ("scenario_id", pa.int32(), True),
    ("track_id", pa.int64()),
    ("time_unix_s", pa.float64()),
    ("plot_id", pa.int64()),
    *POSITION_COLUMNS,
    ("range_m", pa.float64()),
    ("weight", pa.float64()),
    ("status", pa.string()),
    ("association", pa.string()),
    ("association_error", pa.float64(), True),
    *((name, pa.float64(), True) for name in ("covariance_xx_m2", "covariance_xy_m2", "covariance_xz_m2",
                                              "covariance_yy_m2", "covariance_yz_m2", "covariance_zz_m2")),
    *((name, pa.float64(), True) for name in ("vx_ecef_mps", "vy_ecef_mps", "vz_ecef_mps", "ground_speed_mps",
                                              "course_deg", "vertical_rate_mps")),
    *((f"velocity_{name}_m2_s2", pa.float64(), True) for name in ("covariance_xx", "covariance_xy", "covariance_xz",
                                                                   "covariance_yy", "covariance_yz", "covariance_zz")),
)
COVARIANCE_COLUMNS = TRACK_SCHEMA.names[-18:-12]  # the position's ECEF covariance, upper triangle; null when
COVARIANCE_ENTRIES = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # the estimator gives none (the networks)
VELOCITY_COLUMNS = TRACK_SCHEMA.names[-12:-6]  # ECEF m/s, ground speed m/s, course deg (clockwise from true
                                               # north), vertical rate m/s (up); null where unknown
VELOCITY_COVARIANCE_COLUMNS = TRACK_SCHEMA.names[-6:]  # the ECEF velocity's covariance, upper triangle, m^2/s^2
SCAN_SLACK = 1.5  # scans a new track must outlive (`warn_short_silences`): half a revolution of slack for the
                  # plot's place in the scan, as M-of-N's miss (`pipeline.tracker.m_of_n`)


def covariance_columns(covariances: np.ndarray, names: tuple[str, ...] | list[str] = COVARIANCE_COLUMNS
                       ) -> dict[str, pa.Array]:
    """`names` (COVARIANCE_COLUMNS, or VELOCITY_COVARIANCE_COLUMNS) of (U, 3, 3) ECEF covariances, upper
    triangle; null where NaN (an estimator giving none)."""
    return {name: _nullable(covariances[:, i, j]) for name, (i, j) in zip(names, COVARIANCE_ENTRIES)}


def _nullable(values: np.ndarray) -> pa.Array:
    return pa.array(values, mask=np.isnan(values))


def velocity_columns(velocity: np.ndarray, latitude_deg: np.ndarray, longitude_deg: np.ndarray
                     ) -> dict[str, pa.Array]:
    """VELOCITY_COLUMNS of (U, 3) ECEF velocities, m/s, at the tracks' geodetic positions: the ECEF
    components, and in the local east-north-up frame (thesis eq. 4.6's rotation) the ground speed
    sqrt(e^2 + n^2), the course atan2(e, n) in [0, 360) degrees clockwise from true north (ICAO's track
    angle) and the vertical rate u; null where the velocity is unknown (NaN)."""
    east, north, up = np.einsum("uij,uj->iu", geodesy.enu_rotations(latitude_deg, longitude_deg), velocity)
    course = np.mod(np.degrees(np.arctan2(east, north)), 360.0)
    values = (velocity[:, 0], velocity[:, 1], velocity[:, 2], np.hypot(east, north), course, up)
    return {name: _nullable(value) for name, value in zip(VELOCITY_COLUMNS, values)}


def warn_short_silences(management: TrackManagement, rule: str, radars: Mapping[int, Radar]) -> list[int]:
    """Warn for each radar of `radars` whose new tracks the management rule `management` (named
    `rule`) lowers before SCAN_SLACK of the radar's scans: a radar sees an aircraft once a
    revolution, a little more than a scan apart for one moving clockwise in azimuth (12.07 s at
    12 s, case 25), so such a radar's tracks could not live to their second plot. Returns those
    radars' ids (sorted)."""
    short = []
    for radar_id, radar in sorted(radars.items()):
        silence = management.silence(management.start, radar.scan_period_s)
        if silence < SCAN_SLACK * radar.scan_period_s:
            short.append(radar_id)
            log.warning("track: radar %d turns every %.6g s, but track management %r lowers a new track after "
                        "%.6g s of silence, less than %.6g of its scans: its tracks may never be confirmed (raise "
                        "tracker.management.silence_s or tracker.management.silence_scans)", radar_id,
                        radar.scan_period_s, rule, silence, SCAN_SLACK)
    return short


def track_recording(plots: Plots, method: str, window_m: float, params: Params, models_dir: Path) -> pa.Table:
    """Track every scenario of a recording with `method`; one row per track update (TRACK_SCHEMA),
    `range_m` the range from the plot's radar to the track's position. Warns as `track` does when the
    method's learned gate keeps refusing plots (`refusals.warn_refusals`)."""
    refusals = RefusalCounts()
    parts = [part for _, part, _ in tracked_parts(((scenario_id, iter([scenario]))
                                                   for scenario_id, scenario in plots.scenarios()),
                                                  plots.radars, method, window_m, params, models_dir, refusals)]
    warn_refusals(method, window_m, refusals, params.tracker.refusal_warning_share,
                  params.tracker.lstm_update.young_window_fallback)
    return pa.concat_tables(parts) if parts else TRACK_SCHEMA.empty_table()


def tracked_parts(scenarios: Iterable[tuple[int, Iterable[Plots]]], radars: Mapping[int, Radar], method: str,
                  window_m: float, params: Params, models_dir: Path, refusals: RefusalCounts
                  ) -> Iterator[tuple[int, pa.Table, bool]]:
    """Track each scenario, given as its plots in time-ordered chunks, with `method`: the track
    updates (TRACK_SCHEMA) of each chunk in turn, with its scenario id and whether it is the
    scenario's first. `radars`: every radar of the recording; a radar too slow for the management
    rule's silence is warned of first (`warn_short_silences`). Each scenario's counts of plots its
    learned gate refused (`pipeline.tracker.refusals`; none for a method without one) are added to
    `refusals` once the scenario is tracked."""
    models = load_models(models_dir, params, [method])
    management = registry.management(params.tracker.management.rule, params.tracker)
    warn_short_silences(management, params.tracker.management.rule, radars)
    sites = {radar_id: geodesy.radar_site_ecef(radar) for radar_id, radar in radars.items()}
    for scenario_id, chunks in scenarios:
        seed = [params.tracker.seed, scenario_id] if scenario_id != NO_SCENARIO else [params.tracker.seed]
        tracker = dataclasses.replace(registry.compose(method, models, params.tracker, window_m, seed),
                                      records_velocity=True)
        for number, updates in enumerate(track_chunks(chunks, tracker)):
            yield scenario_id, _track_table(updates, scenario_id, sites, management), number == 0
        if tracker.refusals is not None:
            refusals.add(tracker.refusals.counts)


def _track_table(updates: dict[str, np.ndarray], scenario_id: int, sites: Mapping[int, np.ndarray],
                 management: TrackManagement) -> pa.Table:
    """Track updates (`pipeline.tracker.updates`) of one scenario as TRACK_SCHEMA rows."""
    states = positions(updates)
    site = np.array([sites[r] for r in updates["radar_id"].tolist()]).reshape(-1, 3)
    lat, lon, alt = geodesy.ecef_to_geodetic(states)
    count = len(updates["track_id"])
    return pa.Table.from_pydict({
        "radar_id": updates["radar_id"].astype(np.int32),
        "scenario_id": pa.array(np.full(count, scenario_id, np.int32), mask=np.full(count, scenario_id < 0)),
        "track_id": updates["track_id"], "time_unix_s": updates["time_unix_s"], "plot_id": updates["plot_id"],
        "x_ecef_m": states[:, 0], "y_ecef_m": states[:, 1], "z_ecef_m": states[:, 2],
        "latitude_deg": lat, "longitude_deg": lon, "altitude_m": alt,
        "range_m": np.linalg.norm(states - site, axis=1), "weight": updates["weight"],
        "status": [management.status(w) for w in updates["weight"]],
        "association": updates["association"].astype(str), "association_error": updates["association_error"],
        **covariance_columns(updates["position_covariance"]),
        **velocity_columns(updates["velocity"] if "velocity" in updates else np.full((count, 3), np.nan), lat, lon),
        **covariance_columns(updates["velocity_covariance"] if "velocity" in updates
                             else np.full((count, 3, 3), np.nan), VELOCITY_COVARIANCE_COLUMNS),
    }, schema=TRACK_SCHEMA)

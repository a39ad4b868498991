"""A user's track table (what `python -m pipeline track` writes) read for track-to-track association, and checked.

The table is in the track-update schema (`pipeline.tracker.recording.TRACK_SCHEMA`, docs/tracking-a-recording.md): one
row per update, the position in WGS-84 ECEF and geodetically, the range from the plot's radar, the status
and the position's ECEF covariance (`covariance_*_m2`). Only confirmed updates are kept: a tentative track
is as likely a false plot as an aircraft. The radar description beside it (`plot_table.RADAR_FILE_SCHEMA`,
the file `track` read) gives each radar's site.

Refused with an InputError naming the file, column, row and value:
- a radar without a site (a null latitude, longitude or height: `io.read_parquet`), an impossible site
  (`input_checks.check_radars`), or a radar id of the table the description does not list;
- a table in another frame: its ECEF position more than FRAME_TOLERANCE_M from its own latitude, longitude
  and altitude (not WGS-84 ECEF), or its range more than FRAME_TOLERANCE_M from the distance to the
  described site (the description places the radar elsewhere than the tracker did);
- a confirmed update whose time, position or range is infinite (FINITE_COLUMNS; NaN is refused on reading);
- a confirmed update whose covariance is missing (tracked by a network, which gives none), NaN, or not
  positive definite (tested on the correlation matrix, so that the test does not depend on the scale: a huge
  covariance is as definite as a small one; `track_association.correlation_eigenvalues`);
- a track id that carries two aircraft (two `track` outputs concatenated, ids restarting at 0; a tracker that
  reuses numbers), which would mix two aircraft in one state at the common times: two consecutive confirmed
  updates of one track further apart than `max_speed_mps` times their time difference by more than
  SPEED_SIGMAS standard deviations of their difference (along the jump, from their covariances), or two of
  one track by one radar less than MIN_REVISIT_SCANS of its scan period apart (the radar sees an aircraft once
  a revolution). The message names the file, the track id and both rows.

A huge but finite covariance is a legal, if useless, track state (a filter that coasted or diverged): an update
whose position variance on an axis exceeds COVARIANCE_CEILING_M2 is kept, marked `informative` False, and a
warning names the file, its first row, track id, column and value; the common times that would read it leave the
track out (`common_time_states`), so it pairs nothing there.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.association.track_association import correlation_eigenvalues
from pipeline.geometry import geodesy
from pipeline.recordings import input_checks
from pipeline.recordings.plot_table import NO_SCENARIO, OPTIONAL_RADAR_COLUMNS, RADAR_FILE_SCHEMA
from pipeline.tracker.recording import (COVARIANCE_COLUMNS, COVARIANCE_ENTRIES, TRACK_SCHEMA, VELOCITY_COLUMNS,
                                       VELOCITY_COVARIANCE_COLUMNS)

log = logging.getLogger("pipeline")

FRAME_TOLERANCE_M = 1.0   # metres: `track` writes both positions and the range from one ECEF point (float64)
CONFIRMED = "confirmed"
# read_parquet refuses NaN in these; an infinity would pass the frame check (a difference of infinities is NaN,
# and NaN > 1 m is False) and be extrapolated to the common times
FINITE_COLUMNS = ("time_unix_s", "x_ecef_m", "y_ecef_m", "z_ecef_m", "latitude_deg", "longitude_deg", "altitude_m",
                  "range_m")
# A position standard deviation beyond input_checks.RANGE_MAX_M (2000 km, the farthest a plot lies from its radar)
# says nothing of where the aircraft is; and float64 keeps about 16 digits, so a variance of 1e20 m² next to the
# other update's 1e2 m² loses the latter in the common-time covariance (A P Aᵀ; `common_time_states`), which then
# fails to be positive definite. Below this ceiling 1e2 m² keeps 6 of its digits.
COVARIANCE_CEILING_M2 = input_checks.RANGE_MAX_M ** 2
SPEED_SIGMAS = 6.0       # a jump this many standard deviations beyond max_speed_mps·Δt is not position error
MIN_REVISIT_SCANS = 0.5  # one radar updates a track of one aircraft about once a scan, never twice in half of one


@dataclass(frozen=True)
class TrackTable:
    """U confirmed updates of one user, sorted by (scenario, track, time): `scenario_id` (U,) int (NO_SCENARIO
    where null), `track_id` (U,) int64, `time` (U,) Unix s, `position` (U, 3) ECEF m, `covariance` (U, 3, 3)
    ECEF m², `row` (U,) each update's row in the file, `informative` (U,) bool: False where the covariance exceeds
    COVARIANCE_CEILING_M2 (module docstring); `sites` maps the table's radar ids to their ECEF sites (3,); `path`
    names the file in errors."""

    path: Path
    scenario_id: np.ndarray
    track_id: np.ndarray
    time: np.ndarray
    position: np.ndarray
    covariance: np.ndarray
    sites: dict[int, np.ndarray]
    row: np.ndarray
    informative: np.ndarray


def read_sites(radar_path: Path) -> tuple[dict[int, np.ndarray], dict[int, float]]:
    """Each described radar's ECEF site (3,), m, and scan period (s, for the radars whose description gives one);
    InputError for a radar without a site or an impossible one."""
    radars = io.read_parquet(radar_path, RADAR_FILE_SCHEMA, optional=OPTIONAL_RADAR_COLUMNS)
    input_checks.check_radars(radars, radar_path)
    rows = radars.to_pylist()
    sites = {int(row["radar_id"]): geodesy.site_ecef(row["latitude_deg"], row["longitude_deg"], row["height_m"])
             for row in rows}
    return sites, {int(row["radar_id"]): float(row["scan_period_s"]) for row in rows
                   if row.get("scan_period_s") is not None}


def _first_bad(path: Path, what: str, bad: np.ndarray, values: np.ndarray, rows: np.ndarray) -> None:
    """InputError naming the first bad row (its index in the file) and value, when any row is bad."""
    if bad.any():
        first = int(np.argmax(bad))
        raise io.InputError(f"{path}: {what}: row {int(rows[first])} is {values[first]:.6g} "
                            f"({int(bad.sum())} of {len(bad)} confirmed rows)")


def _check_radars(path: Path, radar_path: Path, radar_id: np.ndarray, sites: dict[int, np.ndarray]) -> None:
    unknown = ~np.isin(radar_id, list(sites))
    if unknown.any():
        first = int(np.argmax(unknown))
        raise io.InputError(f"{path}: column 'radar_id' has radar {int(radar_id[first])} (row {first}) that "
                            f"{radar_path} does not describe (it lists {sorted(sites)})")


def _check_frame(path: Path, table: pa.Table, position: np.ndarray, sites: dict[int, np.ndarray],
                 rows: np.ndarray) -> None:
    geodetic = geodesy.geodetic_to_ecef(*(table.column(c).to_numpy() for c in ("latitude_deg", "longitude_deg",
                                                                              "altitude_m")))
    apart = np.linalg.norm(geodetic - position, axis=1)
    _first_bad(path, "x/y/z_ecef_m and latitude_deg/longitude_deg/altitude_m are this many metres apart, more "
               f"than {FRAME_TOLERANCE_M}: the positions are not WGS-84 ECEF (a table in another frame?)",
               apart > FRAME_TOLERANCE_M, apart, rows)
    site = np.array([sites[int(r)] for r in table.column("radar_id").to_numpy()]).reshape(-1, 3)
    error = np.abs(np.linalg.norm(position - site, axis=1) - table.column("range_m").to_numpy())
    _first_bad(path, "range_m differs from the distance to its radar's described site by this many metres: the "
               "radar description places the radar elsewhere than the tracker did (another frame or site)",
               error > FRAME_TOLERANCE_M, error, rows)


def _covariances(path: Path, table: pa.Table, rows: np.ndarray) -> np.ndarray:
    """(U, 3, 3) ECEF covariances of the rows, checked: present, finite, positive definite."""
    covariance = np.zeros((table.num_rows, 3, 3))
    for name, (i, j) in zip(COVARIANCE_COLUMNS, COVARIANCE_ENTRIES):
        column = table.column(name)
        if column.null_count:
            first = int(np.argmax(column.is_null().to_numpy(zero_copy_only=False)))
            raise io.InputError(f"{path}: column '{name}' is missing in {column.null_count} confirmed rows (first: "
                                f"row {int(rows[first])}): the tracker gave no covariance (the networks give none; "
                                "track with a classical method such as imm_gnn)")
        values = column.to_numpy(zero_copy_only=False).astype(float)
        _first_bad(path, f"column '{name}' must be finite", ~np.isfinite(values), values, rows)
        covariance[:, i, j] = covariance[:, j, i] = values
    diagonal = np.diagonal(covariance, axis1=1, axis2=2)
    smallest = diagonal.min(axis=1, initial=np.inf)
    _first_bad(path, "the covariance (columns 'covariance_*_m2') must be positive definite; smallest variance",
               smallest <= 0.0, smallest, rows)
    smallest = correlation_eigenvalues(covariance)[:, 0]
    _first_bad(path, "the covariance (columns 'covariance_*_m2') must be positive definite; smallest eigenvalue of "
               "its correlation matrix", smallest <= 0.0, smallest, rows)
    return covariance


def _informative(path: Path, covariance: np.ndarray, track: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(U,) which updates' position variances are all within COVARIANCE_CEILING_M2; a warning names the first
    other one's file row, track id, column and value."""
    variance = np.diagonal(covariance, axis1=1, axis2=2)
    huge = variance > COVARIANCE_CEILING_M2
    if huge.any():
        first = int(np.argmax(huge.any(axis=1)))
        axis = int(np.argmax(variance[first]))
        column = COVARIANCE_COLUMNS[COVARIANCE_ENTRIES.index((axis, axis))]
        log.warning("%s: row %d (track %d) has %s = %.6g m², above %.6g (a position sigma beyond %.0f km): the track "
                    "knows nothing of the aircraft's position there, and is left out of the common times that "
                    "read it (%d of %d confirmed rows)", path, int(rows[first]), int(track[first]), column,
                    variance[first, axis], COVARIANCE_CEILING_M2, np.sqrt(COVARIANCE_CEILING_M2) / 1e3,
                    int(huge.any(axis=1).sum()), len(huge))
    return ~huge.any(axis=1)


def _consecutive(order: np.ndarray, keys: tuple[np.ndarray, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Rows (K,) and the rows after them (K,) in `order` with equal `keys`."""
    same = ~input_checks.changes(order, keys)
    return order[:-1][same], order[1:][same]


def _two_aircraft(path: Path, what: str, bad: np.ndarray, earlier: np.ndarray, later: np.ndarray,
                  track: np.ndarray, rows: np.ndarray) -> None:
    """InputError naming the track and both file rows of the bad consecutive pair whose later row comes first."""
    if bad.any():
        first = np.flatnonzero(bad)[np.argmin(rows[later[bad]])]
        raise io.InputError(
            f"{path}: track {int(track[later[first]])}, rows {int(rows[earlier[first]])} and {int(rows[later[first]])}"
            f": {what(first)} ({int(bad.sum())} of {len(bad)} consecutive updates): one track id for two aircraft "
            "(two `track` outputs concatenated, ids restarting at 0?); give each aircraft its own id")


def check_one_aircraft(path: Path, scenario: np.ndarray, track: np.ndarray, radar: np.ndarray, time: np.ndarray,
                       position: np.ndarray, covariance: np.ndarray, rows: np.ndarray, max_speed_mps: float,
                       scan_periods: Mapping[int, float]) -> None:
    """InputError when a track id carries two aircraft (module docstring): U updates' scenario, track, radar ids
    and times (U,), ECEF positions (U, 3) m and covariances (U, 3, 3) m², file rows (U,); `scan_periods` (s) of
    the radars that have one (the others are not tested for revisits)."""
    earlier, later = _consecutive(np.lexsort((time, track, scenario)), (scenario, track))
    jump = position[later] - position[earlier]
    distance = np.linalg.norm(jump, axis=1)
    along = jump / np.maximum(distance, np.finfo(float).tiny)[:, None]
    sigma = np.sqrt(np.einsum("ki,kij,kj->k", along, covariance[earlier] + covariance[later], along))
    elapsed = time[later] - time[earlier]
    _two_aircraft(path, lambda k: (f"{distance[k]:.0f} m apart in {elapsed[k]:.3g} s, faster than "
                                   f"associate.max_speed_mps = {max_speed_mps:.0f} m/s (beyond {SPEED_SIGMAS:.0f} "
                                   "sigma of their covariances)"),
                  distance > max_speed_mps * elapsed + SPEED_SIGMAS * sigma, earlier, later, track, rows)
    earlier, later = _consecutive(np.lexsort((time, radar, track, scenario)), (scenario, track, radar))
    period = np.array([scan_periods.get(int(r), 0.0) for r in radar[later]])
    elapsed = time[later] - time[earlier]
    _two_aircraft(path, lambda k: (f"radar {int(radar[later[k]])} updates it twice in {elapsed[k]:.3g} s, less "
                                   f"than {MIN_REVISIT_SCANS} of its {period[k]:.3g} s scan"),
                  elapsed < MIN_REVISIT_SCANS * period, earlier, later, track, rows)


def read_track_table(path: Path, radar_path: Path, max_speed_mps: float) -> TrackTable:
    """The confirmed updates of a track table, checked against its radar description (module docstring)."""
    sites, scan_periods = read_sites(radar_path)
    table = io.read_parquet(path, TRACK_SCHEMA, optional=("scenario_id", "association_error", *COVARIANCE_COLUMNS,
                                                              *VELOCITY_COLUMNS, *VELOCITY_COVARIANCE_COLUMNS))
    _check_radars(path, radar_path, table.column("radar_id").to_numpy(), sites)
    return track_table(table, sites, path, max_speed_mps, scan_periods)


def track_table(table: pa.Table, sites: dict[int, np.ndarray], path: Path, max_speed_mps: float,
                scan_periods: Mapping[int, float]) -> TrackTable:
    """The confirmed updates of a TRACK_SCHEMA table whose radars are all in `sites`, checked (module docstring;
    errors name `path`); `scan_periods` (s) of the radars that have one."""
    confirmed = np.asarray(table.column("status").to_pylist()) == CONFIRMED
    rows = np.flatnonzero(confirmed)
    table = table.filter(pa.array(confirmed))
    for name in FINITE_COLUMNS:
        values = table.column(name).to_numpy()
        _first_bad(path, f"column '{name}' must be finite", ~np.isfinite(values), values, rows)
    position = np.column_stack([table.column(f"{axis}_ecef_m").to_numpy() for axis in "xyz"]).reshape(-1, 3)
    _check_frame(path, table, position, sites, rows)
    covariance = _covariances(path, table, rows)
    scenario = table.column("scenario_id").fill_null(NO_SCENARIO).to_numpy().astype(np.int64)
    track = table.column("track_id").to_numpy()
    time = table.column("time_unix_s").to_numpy()
    check_one_aircraft(path, scenario, track, table.column("radar_id").to_numpy(), time, position, covariance, rows,
                       max_speed_mps, scan_periods)
    informative = _informative(path, covariance, track, rows)
    order = np.lexsort((time, track, scenario))
    return TrackTable(path, scenario[order], track[order], time[order], position[order], covariance[order], sites,
                      rows[order], informative[order])

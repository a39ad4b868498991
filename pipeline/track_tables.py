"""A user's track table (what `python -m pipeline track` writes) read for track-to-track association, and checked.

The table is in the track-update schema (`track_command.TRACK_SCHEMA`, README "Tracking a recording"): one
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
  positive definite.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import geodesy, input_checks, io
from pipeline.plot_table import NO_SCENARIO, OPTIONAL_RADAR_COLUMNS, RADAR_FILE_SCHEMA
from pipeline.track_command import COVARIANCE_COLUMNS, COVARIANCE_ENTRIES, TRACK_SCHEMA

FRAME_TOLERANCE_M = 1.0   # metres: `track` writes both positions and the range from one ECEF point (float64)
CONFIRMED = "confirmed"
# read_parquet refuses NaN in these; an infinity would pass the frame check (a difference of infinities is NaN,
# and NaN > 1 m is False) and be extrapolated to the common times
FINITE_COLUMNS = ("time_unix_s", "x_ecef_m", "y_ecef_m", "z_ecef_m", "latitude_deg", "longitude_deg", "altitude_m",
                  "range_m")


@dataclass(frozen=True)
class TrackTable:
    """U confirmed updates of one user, sorted by (scenario, track, time): `scenario_id` (U,) int (NO_SCENARIO
    where null), `track_id` (U,) int64, `time` (U,) Unix s, `position` (U, 3) ECEF m, `covariance` (U, 3, 3)
    ECEF m²; `sites` maps the table's radar ids to their ECEF sites (3,); `path` names the file in errors."""

    path: Path
    scenario_id: np.ndarray
    track_id: np.ndarray
    time: np.ndarray
    position: np.ndarray
    covariance: np.ndarray
    sites: dict[int, np.ndarray]


def read_sites(radar_path: Path) -> dict[int, np.ndarray]:
    """Each described radar's ECEF site (3,), m; InputError for a radar without a site or an impossible one."""
    radars = io.read_parquet(radar_path, RADAR_FILE_SCHEMA, optional=OPTIONAL_RADAR_COLUMNS)
    input_checks.check_radars(radars, radar_path)
    return {int(row["radar_id"]): geodesy.site_ecef(row["latitude_deg"], row["longitude_deg"], row["height_m"])
            for row in radars.to_pylist()}


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
    smallest = np.linalg.eigvalsh(covariance)[:, 0] if len(covariance) else np.zeros(0)
    _first_bad(path, "the covariance (columns 'covariance_*_m2') must be positive definite; smallest eigenvalue",
               smallest <= 0.0, smallest, rows)
    return covariance


def read_track_table(path: Path, radar_path: Path) -> TrackTable:
    """The confirmed updates of a track table, checked against its radar description (module docstring)."""
    sites = read_sites(radar_path)
    table = io.read_parquet(path, TRACK_SCHEMA, optional=("scenario_id", "association_error", *COVARIANCE_COLUMNS))
    _check_radars(path, radar_path, table.column("radar_id").to_numpy(), sites)
    return track_table(table, sites, path)


def track_table(table: pa.Table, sites: dict[int, np.ndarray], path: Path) -> TrackTable:
    """The confirmed updates of a TRACK_SCHEMA table whose radars are all in `sites`, checked (module docstring;
    errors name `path`)."""
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
    order = np.lexsort((time, track, scenario))
    return TrackTable(path, scenario[order], track[order], time[order], position[order], covariance[order], sites)

"""Real aircraft trajectories: OpenSky Network state vectors (CSV, as OpenSky's historical database and Stone
Soup's demonstration give them) read as a truth table.

A state vector is OpenSky's view of an aircraft at `time`; its position is the last one received, at
`lastposupdate`, and is repeated while no new one comes (645 of the shipped recording's 6052 rows): the
position is taken at `lastposupdate` (at `time` where that column is missing) and a repeated one is left out.

The project ships one such recording (`external/opensky/`, 84 aircraft over the UK for 20 minutes, credited
there). A state vector is an ADS-B position report resampled by OpenSky: `time` (Unix s), `icao24` (the
aircraft's 24-bit address, its identity), `lat`, `lon` (deg, WGS-84), `geoaltitude` (m, the GNSS height,
taken as above the WGS-84 ellipsoid; `baroaltitude` where it is missing), `onground`. Reports on the ground,
or without a position, any altitude, a time or an address, are left out and counted. Each aircraft becomes a target (ids in the
order of their addresses), its positions in ECEF: the truth table `python -m pipeline score` reads
(`target_id`, `time_unix_s`, `x/y/z_ecef_m`), with the address, the geodetic position and `in_coverage` (True:
coverage is the radar's to decide).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as csv

from pipeline.geometry import geodesy
from pipeline.io import InputError

COLUMNS = {"time": pa.float64(), "icao24": pa.string(), "lat": pa.float64(), "lon": pa.float64(),
           "geoaltitude": pa.float64(), "baroaltitude": pa.float64(), "onground": pa.bool_()}
POSITION_TIME = "lastposupdate"  # optional: when the position was received
TRUTH_SCHEMA = pa.schema([("target_id", pa.int32()), ("icao24", pa.string()), ("time_unix_s", pa.float64()),
                          ("latitude_deg", pa.float64()), ("longitude_deg", pa.float64()), ("altitude_m", pa.float64()),
                          ("x_ecef_m", pa.float64()), ("y_ecef_m", pa.float64()), ("z_ecef_m", pa.float64()),
                          ("in_coverage", pa.bool_())])
LIMITS = {"lat": (-90.0, 90.0), "lon": (-180.0, 180.0), "geoaltitude": (-500.0, 25000.0),
          "baroaltitude": (-500.0, 25000.0)}


def read_states(path: Path) -> tuple[pa.Table, dict[str, int]]:
    """The truth table (TRUTH_SCHEMA, by target then time) of an OpenSky state-vector CSV, and the reports left
    out by reason. InputError naming the file and column for a missing column, a value that is not of its type,
    or one outside LIMITS (with its first row)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    header = path.open(encoding="utf-8", errors="replace").readline().strip().split(",")
    wanted = {**COLUMNS, **({POSITION_TIME: pa.float64()} if POSITION_TIME in header else {})}
    try:
        table = csv.read_csv(path, convert_options=csv.ConvertOptions(column_types=wanted,
                                                                      include_columns=list(wanted)))
    except (pa.ArrowInvalid, KeyError) as error:
        raise InputError(f"{path}: not an OpenSky state-vector CSV with columns {', '.join(COLUMNS)}: {error}") from None
    for name, (low, high) in LIMITS.items():
        values = table.column(name).to_numpy(zero_copy_only=False)
        bad = np.flatnonzero(np.isfinite(values) & ((values < low) | (values > high)))
        if len(bad):
            raise InputError(f"{path}: column {name}: {float(values[bad[0]])!r} at row {bad[0]}, outside [{low:g}, {high:g}] "
                             f"({len(bad)} rows)")
    altitude = pc.coalesce(table.column("geoaltitude"), table.column("baroaltitude"))
    on_ground = table.column("onground").fill_null(False).to_numpy(zero_copy_only=False)
    no_position = (pc.is_null(table.column("lat")).to_numpy(zero_copy_only=False)
                   | pc.is_null(table.column("lon")).to_numpy(zero_copy_only=False))
    no_altitude = pc.is_null(altitude).to_numpy(zero_copy_only=False) & ~no_position
    position_time = (pc.coalesce(table.column(POSITION_TIME), table.column("time")) if POSITION_TIME in wanted
                     else table.column("time")).to_numpy(zero_copy_only=False)
    addresses = np.asarray(table.column("icao24").fill_null("").to_pylist(), dtype=object).astype(str)
    no_time = ~np.isfinite(position_time) & ~no_position & ~no_altitude
    no_address = (addresses == "") & ~no_time & ~no_position & ~no_altitude
    skipped = {"on the ground": int(np.count_nonzero(on_ground & ~no_position & ~no_altitude & ~no_time & ~no_address)),
               "without a position": int(np.count_nonzero(no_position)),
               "without an altitude": int(np.count_nonzero(no_altitude)),
               "without a time": int(np.count_nonzero(no_time)),
               "without an aircraft address": int(np.count_nonzero(no_address))}
    usable = ~(on_ground | no_position | no_altitude | no_time | no_address)
    stale = np.zeros(len(usable), bool)
    seen = set()
    for row in np.flatnonzero(usable).tolist():
        key = (addresses[row], position_time[row])
        stale[row] = key in seen
        seen.add(key)
    skipped["repeated (no new position since the last report)"] = int(np.count_nonzero(stale))
    keep = usable & ~stale
    icao24 = addresses[keep]
    time = position_time[keep]
    latitude = table.column("lat").to_numpy(zero_copy_only=False)[keep]
    longitude = table.column("lon").to_numpy(zero_copy_only=False)[keep]
    height = altitude.to_numpy(zero_copy_only=False)[keep]
    _, target = np.unique(icao24, return_inverse=True)
    order = np.lexsort((time, target))
    ecef = geodesy.geodetic_to_ecef(latitude[order], longitude[order], height[order]).reshape(-1, 3)
    truth = pa.table({"target_id": pa.array(target[order].astype(np.int32)), "icao24": pa.array(icao24[order]),
                      "time_unix_s": pa.array(time[order]), "latitude_deg": pa.array(latitude[order]),
                      "longitude_deg": pa.array(longitude[order]), "altitude_m": pa.array(height[order]),
                      "x_ecef_m": pa.array(ecef[:, 0]), "y_ecef_m": pa.array(ecef[:, 1]),
                      "z_ecef_m": pa.array(ecef[:, 2]), "in_coverage": pa.array(np.ones(len(order), bool))},
                     schema=TRUTH_SCHEMA)
    return truth, {reason: count for reason, count in skipped.items() if count}

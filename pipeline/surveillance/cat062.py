"""ASTERIX CAT062 system tracks: a track-update table written as SDPS track messages, and read back.

Air-traffic surveillance tools (SASS-C, the COMPASS evaluator, ARTAS's users) read tracks as
ASTERIX CAT062 (EUROCONTROL ASTERIX Part 9, Category 062 "SDPS Track Messages", edition 1.20, as the
asterix-specs definitions give it; decoded with libasterix, generated from them, and encoded here, as
`records` says why). One record per row of the update table (`pipeline.tracker.recording.TRACK_SCHEMA`), in time order,
with these items:

- I062/010 SAC/SIC of the tracker (the system, not a radar), I062/015 service identification
  (`SERVICE_ID`), I062/070 time of track information (time of day, 1/128 s).
- I062/040 track number: the table's tracks, (scenario, track id), numbered 1, 2, ... 65535, 1, ...
  in the order of their first update (16 bits; 0 is not used); I062/080's TSB marks a
  track's first record and TSE its last, so a reused number starts a new track for a reader.
- I062/080 track status: CNF = 0 for a confirmed track's update, 1 for a tentative or candidate
  one; MON = 1 when the table holds one radar (a monosensor track), else 0; SRC = 0 and MRH = 0
  (no geometric altitude is written, the barometric is the one there is); TSB, TSE as above.
- I062/105 position in WGS-84 (180/2^25 deg), and I062/100 the same in the system's Cartesian
  plane (0.5 m): the oblique stereographic projection (EPSG method 9809, PROJ's `sterea`, on
  WGS-84) about the system reference point, the point a CAT062 stream's users share (`track`
  takes its recording's first radar's site, and logs it).
- I062/135 calculated track barometric altitude (1/4 FL, QNH = 0): the track's altitude in
  flight levels. The tracker places each plot at its Mode C altitude (I048/090, pressure
  altitude taken as height: `asterix_units.flight_level_to_altitude`), so its altitude estimate
  is a pressure altitude; I062/130 (geometric altitude) and I062/136 (the last measured flight
  level, which the update table does not carry) are not written.
- I062/185 velocity in the system plane (0.25 m/s) and I062/220 rate of climb or descent
  (6.25 ft/min), where the estimator gives a velocity (the table's velocity columns).
- I062/290 system track update ages: TRK, the track's age since its first update, and PSR = 0
  (each record is the update by a primary radar plot), 1/4 s, at most 63.75 s (one octet).
- I062/500 estimated accuracies (standard deviations) from the table's covariances: APC (x, y)
  and COV (the sign of the x-y covariance times the square root of its size) in the system
  plane, APW (latitude, longitude) and ABA (barometric altitude) from the position covariance,
  ATV (x, y) and ARC (rate of climb) from the velocity covariance. A covariance is carried into
  the system plane by the projection's Jacobian (`plane_jacobians`).

A value beyond its item's range (an accuracy wider than one octet's 63.75 m/s, a track older than
63.75 s) is written as the item's largest value: what the standard's fixed widths allow. Reading
(`read_cat062`) gives the columns the scorecard needs back: each record's time (from the UTC date
of the first record, as for CAT048), track (a new track at each TSB), confirmation, WGS-84 position
and barometric altitude, and velocity where I062/185 is present.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from datetime import date, datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.geometry import asterix_units, geodesy
from pipeline.recordings import asterix_io
from pipeline.geometry.asterix_units import FOOT_M, SECONDS_PER_DAY
from pipeline.io import InputError

CATEGORY = 62
SERVICE_ID = 1               # I062/015: the one service this tracker provides
TRACK_NUMBERS = 65536        # I062/040 is 16 bits
RECORDS_PER_DATABLOCK = 200  # records per datablock: well below the 65535-byte datablock length
FEET_PER_MINUTE_MPS = FOOT_M / 60.0
STEPS = {  # item -> LSB in the unit it is written in (ASTERIX CAT062 ed. 1.20)
    "070": 1.0 / 128.0, "105": 180.0 / 2 ** 25, "100": 0.5, "185": 0.25, "135": 0.25, "220": 6.25,
    "290": 0.25, "APC": 0.5, "COV": 0.5, "APW": 180.0 / 2 ** 25, "ABA": 0.25, "ATV": 0.25, "ARC": 6.25,
}
READ_SCHEMA = pa.schema([  # what `read_cat062` gives: one row per CAT062 record
    ("track_id", pa.int64()), ("track_number", pa.int32()), ("time_unix_s", pa.float64()),
    ("confirmed", pa.bool_()), ("latitude_deg", pa.float64()), ("longitude_deg", pa.float64()),
    ("altitude_m", pa.float64()), ("vx_plane_mps", pa.float64()), ("vy_plane_mps", pa.float64()),
])


def _codec():  # imported lazily: libasterix's generated module is large and slow to import
    import asterix.generated as generated
    return generated.Cat_062_1_20


@dataclass(frozen=True)
class SystemReference:
    """The system reference point: the origin of I062/100's plane (degrees, WGS-84)."""

    latitude_deg: float
    longitude_deg: float

    def transformer(self):
        """ECEF (EPSG:4978) -> the system plane, metres east and north of the reference (PROJ `sterea`)."""
        import pyproj

        plane = pyproj.CRS.from_proj4(f"+proj=sterea +lat_0={self.latitude_deg!r} +lon_0={self.longitude_deg!r} "
                                      "+k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs")
        return pyproj.Transformer.from_crs("EPSG:4978", plane, always_xy=True)


def plane_jacobians(transformer, ecef: np.ndarray) -> np.ndarray:
    """(U, 2, 3): d(x, y of the system plane) / d(ECEF), by 1 m steps along each ECEF axis (the
    projection bends over hundreds of kilometres; over a metre it is linear to far below the LSB)."""
    base = np.stack(transformer.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])[:2], axis=1)
    columns = []
    for axis in range(3):
        moved = ecef.copy()
        moved[:, axis] += 1.0
        columns.append(np.stack(transformer.transform(moved[:, 0], moved[:, 1], moved[:, 2])[:2], axis=1) - base)
    return np.stack(columns, axis=2)


def _symmetric(table: pa.Table, names: list[str]) -> np.ndarray:
    """(U, 3, 3) from the six upper-triangle columns (xx, xy, xz, yy, yz, zz); NaN where null."""
    xx, xy, xz, yy, yz, zz = (table.column(name).to_numpy(zero_copy_only=False).astype(float) for name in names)
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)


def _track_numbers(scenario: np.ndarray, track: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each row's I062/040 track number (tracks numbered from 1 in order of first row, modulo 65535 so
    that 0 is not used), its track's first row (TSB where it is the row itself), and whether it is its
    track's last row (TSE)."""
    keys = np.stack([scenario, track], axis=1)
    _, first_row, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first_row, kind="stable")
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    inverse = inverse.reshape(-1)
    numbers = rank[inverse] % (TRACK_NUMBERS - 1) + 1
    rows = np.arange(len(keys))
    last_row = np.zeros(len(order), dtype=np.int64)
    np.maximum.at(last_row, inverse, rows)
    return numbers, first_row[inverse], last_row[inverse] == rows


def _raw(values: np.ndarray, item: str, bits: int, signed: bool) -> np.ndarray:
    """Values (in the item's unit) as the integers of a `bits`-bit field with the item's LSB (STEPS), rounded
    to nearest, held within the field (an unsigned accuracy wider than the field takes its largest value)."""
    raw = np.rint(np.asarray(values, dtype=float) / STEPS[item])
    low, high = (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if signed else (0, 2 ** bits - 1)
    return np.clip(np.nan_to_num(raw), low, high).astype(np.int64)


def records(tracks: pa.Table, sac: int, sic: int, reference: SystemReference) -> list[bytes]:
    """The CAT062 records (FSPEC and items, ed. 1.20's UAP order) of every row of `tracks` (TRACK_SCHEMA
    columns; the covariance and velocity columns may be null), rows in time order (stable), as the module
    docstring lists them. Encoded here with NumPy and `struct`: libasterix took 1.7 ms a record (7 minutes
    for the 285,000 updates of the test split, whose tracking takes 27 s); `tests/test_cat062.py` holds
    these bytes to what libasterix decodes and encodes again, and to an independent decoder."""
    order = np.argsort(tracks.column("time_unix_s").to_numpy(), kind="stable")
    tracks = tracks.take(pa.array(order))
    count = tracks.num_rows
    column = {name: tracks.column(name).to_numpy(zero_copy_only=False) for name in
              ("time_unix_s", "latitude_deg", "longitude_deg", "altitude_m", "status")}
    scenario = tracks.column("scenario_id").fill_null(-1).to_numpy()
    numbers, first_row, last = _track_numbers(scenario, tracks.column("track_id").to_numpy())
    first = first_row == np.arange(count)
    age = column["time_unix_s"] - column["time_unix_s"][first_row]
    ecef = np.stack([tracks.column(name).to_numpy() for name in ("x_ecef_m", "y_ecef_m", "z_ecef_m")], axis=1)
    transformer = reference.transformer()
    plane = np.stack(transformer.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])[:2], axis=1)
    jacobian = plane_jacobians(transformer, ecef)
    rotation = geodesy.enu_rotations(column["latitude_deg"], column["longitude_deg"])
    position_cov = _symmetric(tracks, ["covariance_xx_m2", "covariance_xy_m2", "covariance_xz_m2",
                                       "covariance_yy_m2", "covariance_yz_m2", "covariance_zz_m2"])
    plane_cov = jacobian @ position_cov @ jacobian.transpose(0, 2, 1)
    enu_cov = rotation @ position_cov @ rotation.transpose(0, 2, 1)
    velocity = np.stack([tracks.column(name).to_numpy(zero_copy_only=False).astype(float)
                         for name in ("vx_ecef_mps", "vy_ecef_mps", "vz_ecef_mps")], axis=1)
    plane_velocity = np.einsum("uij,uj->ui", jacobian, velocity)
    vertical_rate = tracks.column("vertical_rate_mps").to_numpy(zero_copy_only=False).astype(float)
    velocity_cov = _symmetric(tracks, [f"velocity_covariance_{e}_m2_s2" for e in ("xx", "xy", "xz", "yy", "yz", "zz")])
    plane_velocity_cov = jacobian @ velocity_cov @ jacobian.transpose(0, 2, 1)
    enu_velocity_cov = rotation @ velocity_cov @ rotation.transpose(0, 2, 1)
    meridian, parallel = _radii(column["latitude_deg"])
    monosensor = int(len(np.unique(tracks.column("radar_id").to_numpy())) <= 1)
    status_first = (monosensor << 7) | np.where(column["status"] == "confirmed", 0, 1 << 1) | 1  # MON .. CNF, FX
    status_second = (last.astype(np.int64) << 6) | (first.astype(np.int64) << 5)  # TSE, TSB; no FX
    raw = {
        "070": _raw(asterix_units.time_of_day(column["time_unix_s"]), "070", 24, False),
        "lat": _raw(column["latitude_deg"], "105", 32, True),
        "lon": _raw((column["longitude_deg"] + 180.0) % 360.0 - 180.0, "105", 32, True),
        "x": _raw(plane[:, 0], "100", 24, True), "y": _raw(plane[:, 1], "100", 24, True),
        "vx": _raw(plane_velocity[:, 0], "185", 16, True), "vy": _raw(plane_velocity[:, 1], "185", 16, True),
        "trk": _raw(age, "290", 8, False),
        "ctb": _raw(column["altitude_m"] / FOOT_M / 100.0, "135", 15, True) & 0x7FFF,  # QNH = 0
        "roc": _raw(vertical_rate / FEET_PER_MINUTE_MPS, "220", 16, True),
        "apc_x": _raw(np.sqrt(plane_cov[:, 0, 0]), "APC", 16, False),
        "apc_y": _raw(np.sqrt(plane_cov[:, 1, 1]), "APC", 16, False),
        "cov": _raw(np.sign(plane_cov[:, 0, 1]) * np.sqrt(np.abs(plane_cov[:, 0, 1])), "COV", 16, True),
        "apw_lat": _raw(np.degrees(np.sqrt(enu_cov[:, 1, 1]) / meridian), "APW", 16, False),
        "apw_lon": _raw(np.degrees(np.sqrt(enu_cov[:, 0, 0]) / parallel), "APW", 16, False),
        "aba": _raw(np.sqrt(enu_cov[:, 2, 2]) / FOOT_M / 100.0, "ABA", 8, False),
        "atv_x": _raw(np.sqrt(plane_velocity_cov[:, 0, 0]), "ATV", 8, False),
        "atv_y": _raw(np.sqrt(plane_velocity_cov[:, 1, 1]), "ATV", 8, False),
        "arc": _raw(np.sqrt(enu_velocity_cov[:, 2, 2]) / FEET_PER_MINUTE_MPS, "ARC", 8, False),
    }
    has_velocity = np.isfinite(plane_velocity).all(axis=1)
    has_rate = np.isfinite(vertical_rate)
    has_position_cov = np.isfinite(plane_cov).all(axis=(1, 2)) & np.isfinite(enu_cov).all(axis=(1, 2))
    has_velocity_cov = np.isfinite(plane_velocity_cov).all(axis=(1, 2)) & np.isfinite(enu_velocity_cov).all(axis=(1, 2))
    columns = {name: values.tolist() for name, values in raw.items()}
    flags = [values.tolist() for values in (has_velocity, has_rate, has_position_cov, has_velocity_cov, numbers,
                                            status_first, status_second)]
    source = struct.pack(">BBB", sac, sic, SERVICE_ID)
    out = []
    for u, (velocity_known, rate_known, position_known, velocity_cov_known, number, status_1, status_2) in \
            enumerate(zip(*flags)):
        value = {name: values[u] for name, values in columns.items()}
        accuracy = b""
        if position_known or velocity_cov_known:  # I062/500: APC COV APW (AGA) ABA ATV (AA) FX | ARC .. FX
            spec = (0x80 | 0x40 | 0x20 | 0x08 if position_known else 0) | (0x04 | 0x01 if velocity_cov_known else 0)
            accuracy = bytes([spec]) + (bytes([0x80]) if velocity_cov_known else b"")
            if position_known:
                accuracy += struct.pack(">HHhHHB", value["apc_x"], value["apc_y"], value["cov"], value["apw_lat"],
                                        value["apw_lon"], value["aba"])
            if velocity_cov_known:
                accuracy += struct.pack(">BBB", value["atv_x"], value["atv_y"], value["arc"])
        fspec = bytes([0x80 | 0x20 | 0x10 | 0x08 | 0x04 | (0x02 if velocity_known else 0) | 0x01,  # 010 015 070 105 100 185
                       0x08 | 0x04 | 0x02 | 0x01,  # 040 080 290
                       0x08 | (0x04 if rate_known else 0) | (0x01 if accuracy else 0)])  # 135 220
        fspec += bytes([0x04]) if accuracy else b""  # 500
        out.append(b"".join((
            fspec, source[:2], source[2:], value["070"].to_bytes(3, "big"),
            struct.pack(">ii", value["lat"], value["lon"]),
            value["x"].to_bytes(3, "big", signed=True), value["y"].to_bytes(3, "big", signed=True),
            struct.pack(">hh", value["vx"], value["vy"]) if velocity_known else b"",
            struct.pack(">HBB", number, status_1, status_2),
            struct.pack(">BBB", 0xC0, value["trk"], 0),  # I062/290: TRK, PSR (age 0)
            struct.pack(">H", value["ctb"]), struct.pack(">h", value["roc"]) if rate_known else b"",
            accuracy)))
    return out


def _radii(latitude_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """WGS-84's metres per radian of latitude (M, the meridian's radius of curvature) and of longitude
    (N cos(latitude), N the prime vertical's) at each latitude: a north or east error in metres over
    these is the error in latitude or longitude."""
    sin_lat = np.sin(np.radians(np.asarray(latitude_deg, dtype=float)))
    q = 1.0 - geodesy.WGS84_E2 * sin_lat * sin_lat
    return (geodesy.WGS84_A * (1.0 - geodesy.WGS84_E2) / (q * np.sqrt(q)),
            geodesy.WGS84_A / np.sqrt(q) * np.cos(np.radians(np.asarray(latitude_deg, dtype=float))))


def plane_velocity_to_ecef(reference: SystemReference, ecef: np.ndarray, vx_mps: np.ndarray, vy_mps: np.ndarray
                           ) -> np.ndarray:
    """(U, 3) ECEF velocities, horizontal at each ECEF position (U, 3), whose projections on the system plane
    about `reference` are (vx, vy) (I062/185): the inverse of `records`' velocity, the plane's Jacobian
    restricted to the local horizontal inverted (a CAT062 velocity has no vertical part)."""
    jacobian = plane_jacobians(reference.transformer(), ecef)
    latitude, longitude, _ = geodesy.ecef_to_geodetic(ecef)
    rotation = geodesy.enu_rotations(np.atleast_1d(latitude), np.atleast_1d(longitude))
    horizontal = jacobian @ rotation[:, :2, :].transpose(0, 2, 1)  # (U, 2, 2): (east, north) -> plane
    east_north = np.linalg.solve(horizontal, np.stack([vx_mps, vy_mps], axis=1)[..., None])[..., 0]
    return np.einsum("uij,ui->uj", rotation[:, :2, :], east_north)


def encode(tracks: pa.Table, sac: int, sic: int, reference: SystemReference) -> bytes:
    """The CAT062 stream of `tracks` (`records`), RECORDS_PER_DATABLOCK records a datablock."""
    items = records(tracks, sac, sic, reference)
    out = bytearray()
    for start in range(0, len(items), RECORDS_PER_DATABLOCK):
        body = b"".join(items[start:start + RECORDS_PER_DATABLOCK])
        out += struct.pack(">BH", CATEGORY, 3 + len(body)) + body
    return bytes(out)


def write_cat062(tracks: pa.Table, out: Path, sac: int, sic: int, reference: SystemReference) -> int:
    """Write `tracks` to `out` as CAT062 (atomically, the user's file mode); the number of records."""
    for name, value in (("SAC", sac), ("SIC", sic)):
        if not 0 <= value <= 255:
            raise InputError(f"CAT062 {name} {value} is not a byte (0 to 255)")
    io.write_bytes(encode(tracks, sac, sic, reference), out)
    return tracks.num_rows


def read_cat062(path: Path, first_date: date) -> pa.Table:
    """The tracks of a CAT062 file (READ_SCHEMA, records in file order), its times of day on the UTC date
    `first_date` of its first record (each on the day nearest the record before, as for CAT048). A track is
    a track number from a record with TSB = 1 (or its first record) to one with TSE = 1; a number seen again
    after TSE starts a new track. InputError, naming the file, datablock, record and item, for a file that
    is not CAT062 alone, a record without one of I062/010, /040, /070, /080, /105, or a value outside
    what the item allows."""
    import asterix.base as base

    codec = _codec()
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    data = path.read_bytes()
    if not data:
        raise InputError(f"{path}: empty file, no ASTERIX datablock")
    rows, current, next_id = [], {}, 0
    for number, (offset, chunk) in enumerate(asterix_io.datablocks(data, path)):
        block = f"{path}: datablock {number} at byte {offset}"
        parsed = base.RawDatablock.parse(base.Bits.from_bytes(chunk))
        if isinstance(parsed, ValueError) or len(parsed) != 1:
            raise InputError(f"{block} is corrupt: {parsed}")
        category = parsed[0].get_category()
        if category != CATEGORY:
            raise InputError(f"{block} is CAT{category:03d}: a track file for `score` holds CAT062 system tracks "
                             "alone (plots go to `track`)")
        records = codec.cv_uap.parse(parsed[0].get_raw_records())
        if isinstance(records, ValueError):
            raise InputError(f"{block} (CAT062) cannot be decoded: {records}")
        for index, record in enumerate(records):
            where = f"{block}, record {index}"
            for item in ("010", "040", "070", "080", "105"):
                if record.get_item(item) is None:
                    raise InputError(f"{where}: item I062/{item} missing (a system track record needs it)")
            track_number = record.get_item("040").variation.content.as_uint()
            status = record.get_item("080").variation
            begins, ends = _flag(status, "TSB"), _flag(status, "TSE")
            if begins or track_number not in current:
                current[track_number], next_id = next_id, next_id + 1
            track_id = current.pop(track_number) if ends else current[track_number]
            rows.append((track_id, track_number, _quantity(record, "070", None, "s", where), _flag(status, "CNF") == 0,
                         _quantity(record, "105", "LAT", "°", where), _quantity(record, "105", "LON", "°", where),
                         _altitude(record, where), *_velocity(record, where)))
    columns = list(zip(*rows)) if rows else [[] for _ in READ_SCHEMA.names]
    table = dict(zip(READ_SCHEMA.names, columns))
    midnight = datetime(first_date.year, first_date.month, first_date.day, tzinfo=timezone.utc).timestamp()
    table["time_unix_s"] = midnight + asterix_units.unwrap_time_of_day(np.asarray(table["time_unix_s"], dtype=float))
    return pa.table({name: pa.array(table[name], type=READ_SCHEMA.field(name).type) for name in READ_SCHEMA.names})


LIMITS = {  # item sub-field -> (lowest, highest) the standard allows, in the unit read
    ("070", None): (0.0, SECONDS_PER_DAY), ("105", "LAT"): (-90.0, 90.0), ("105", "LON"): (-180.0, 180.0),
}


def _quantity(record: object, item: str, sub: str | None, unit: str, where: str) -> float:
    """The value of I062/`item` (sub-field `sub`) in `unit`, checked against LIMITS."""
    variation = record.get_item(item).variation
    content = (variation.get_item(sub).variation if sub else variation).content
    value = float(content.as_quantity(unit))
    low, high = LIMITS.get((item, sub), (-np.inf, np.inf))
    if not low <= value <= high:
        raise InputError(f"{where}: item I062/{item}{' ' + sub if sub else ''} is {value:g} {unit}, outside "
                         f"[{low:g}, {high:g}] (ASTERIX CAT062)")
    return value


def _flag(variation: object, name: str) -> int:
    """A one-bit sub-field of an extended item, 0 when the extension holding it is absent."""
    sub = variation.get_item(name)
    return 0 if sub is None else sub.as_uint()


def _altitude(record: object, where: str) -> float:
    """The track's altitude (m): I062/135 (flight levels as `asterix_units.flight_level_to_altitude` takes
    them), else I062/130 (geometric, ft), else NaN."""
    if record.get_item("135") is not None:
        return float(asterix_units.flight_level_to_altitude(_quantity(record, "135", "CTB", "FL", where)))
    if record.get_item("130") is not None:
        return _quantity(record, "130", None, "ft", where) * FOOT_M
    return float("nan")


def _velocity(record: object, where: str) -> tuple[float, float]:
    """I062/185's (vx, vy) in the system plane (m/s), NaN when absent."""
    if record.get_item("185") is None:
        return float("nan"), float("nan")
    return _quantity(record, "185", "VX", "m/s", where), _quantity(record, "185", "VY", "m/s", where)

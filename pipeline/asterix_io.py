"""ASTERIX CAT048 plots and CAT034 north markers, read and written with libasterix.

libasterix (asterix-libs, generated from the asterix-specs definitions) encodes and decodes
every edition exactly; this module only maps its items to our columns:

- CAT048 I048/010 SAC/SIC, I048/140 time of day, I048/020 report type (single PSR plot),
  I048/040 slant range and azimuth, I048/090 flight level.
- CAT034 I034/000 message type 1 (north marker), I034/010 SAC/SIC, I034/030 time of day,
  I034/041 antenna rotation period, I034/120 radar position (height, latitude, longitude).

ASTERIX carries only the time of day, so decoding needs the UTC date of the recording's
first record; later records that wrap past midnight get the next day.
"""

from __future__ import annotations

from datetime import date, datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import asterix_units
from pipeline.io import InputError

RECORDS_PER_DATABLOCK = 1000
NORTH_MARKER = 1


def _codec():  # imported lazily: libasterix's generated module is large and slow to import
    import asterix.base as base
    import asterix.generated as generated
    return base, generated.Cat_048_1_32, generated.Cat_034_1_29


def encode(plots: pa.Table, radar: dict, scan_times: np.ndarray) -> bytes:
    """A recording: a CAT034 north marker at each scan start, then that scan's CAT048 plots.

    `plots` needs time_unix_s, range_m, azimuth_deg, flight_level; `radar` the columns of a
    radar description row.
    """
    base, cat048, cat034 = _codec()
    source = (("SAC", int(radar["sac"])), ("SIC", int(radar["sic"])))
    times = plots.column("time_unix_s").to_numpy()
    order = np.argsort(times, kind="stable")
    columns = {name: plots.column(name).to_numpy()[order] for name in
               ("time_unix_s", "range_m", "azimuth_deg", "flight_level")}
    scan_of_plot = np.searchsorted(scan_times, columns["time_unix_s"], side="right") - 1
    out = bytearray()
    for scan, north_time in enumerate(scan_times):
        marker = cat034.cv_record.create({
            "000": NORTH_MARKER, "010": source,
            "030": (float(asterix_units.time_of_day(north_time)), "s"),
            "041": (float(radar["scan_period_s"]), "s"),
            "120": (("HGT", (float(radar["height_m"]), "m")), ("LAT", (float(radar["latitude_deg"]), "°")),
                    ("LON", (float(radar["longitude_deg"]), "°"))),
        })
        out += cat034.create([marker]).unparse().to_bytes()
        rows = np.flatnonzero(scan_of_plot == scan)
        for start in range(0, len(rows), RECORDS_PER_DATABLOCK):
            records = [cat048.cv_record.create({
                "010": source,
                "140": (float(asterix_units.time_of_day(columns["time_unix_s"][i])), "s"),
                "020": ((("TYP", 1), ("SIM", 0), ("RDP", 0), ("SPI", 0), ("RAB", 0), None),),
                "040": (("RHO", (float(columns["range_m"][i] / asterix_units.NAUTICAL_MILE_M), "NM")),
                        ("THETA", (float(columns["azimuth_deg"][i]), "°"))),
                "090": (("V", 0), ("G", 0), ("FL", (float(columns["flight_level"][i]), "FL"))),
            }) for i in rows[start:start + RECORDS_PER_DATABLOCK]]
            out += cat048.create(records).unparse().to_bytes()
    return bytes(out)


def _quantity(record: object, item: str, sub: str | None, unit: str) -> float:
    value = record.get_item(item)
    if value is None:
        raise KeyError(item)
    variation = value.variation if sub is None else value.variation.get_item(sub).variation
    return float(variation.content.as_quantity(unit))


def datablocks(data: bytes, path: Path) -> list[tuple[int, bytes]]:
    """Split a stream into datablocks (1 byte category, 2 bytes length, then records).

    libasterix parses a whole stream recursively, one level per datablock, which overflows
    Python's stack on a recording of an hour; the framing is three bytes, so it is split
    here and each block handed to libasterix alone.
    """
    blocks, offset = [], 0
    while offset < len(data):
        if offset + 3 > len(data):
            raise InputError(f"{path}: truncated: {len(data) - offset} stray bytes at byte {offset}")
        length = int.from_bytes(data[offset + 1:offset + 3], "big")
        if length < 3 or offset + length > len(data):
            raise InputError(f"{path}: truncated or corrupt: datablock at byte {offset} claims {length} bytes, "
                             f"{len(data) - offset} remain")
        blocks.append((offset, data[offset:offset + length]))
        offset += length
    return blocks


def decode(paths: Path | str | list[Path], first_date: date) -> tuple[pa.Table, pa.Table]:
    """Plots (radar_id, time, range, azimuth, flight level, altitude) and the radars seen in north
    markers, from one recording, possibly split over several files given in time order. Errors
    name the file, the datablock and what is wrong."""
    paths = [Path(p) for p in paths] if isinstance(paths, list) else [Path(paths)]
    plots: dict[str, list] = {"radar_id": [], "time_of_day_s": [], "range_m": [], "azimuth_deg": [],
                              "flight_level": []}
    radars: dict[int, dict] = {}
    for path in paths:
        _decode_file(path, plots, radars)
    if not radars:
        raise InputError(f"{', '.join(map(str, paths))}: no CAT034 north marker with the radar position (I034/120)")
    tod = np.asarray(plots.pop("time_of_day_s"), dtype=float)
    midnight = datetime(first_date.year, first_date.month, first_date.day, tzinfo=timezone.utc).timestamp()
    wraps = np.concatenate([[0], np.cumsum(np.diff(tod) < -asterix_units.SECONDS_PER_DAY / 2)])
    flight_level = np.asarray(plots.pop("flight_level"), dtype=float)
    table = pa.table({
        "plot_id": np.arange(len(tod), dtype=np.int64),
        "radar_id": np.asarray(plots["radar_id"], dtype=np.int32),
        "time_of_day_s": tod,
        "time_unix_s": midnight + tod + wraps * asterix_units.SECONDS_PER_DAY,
        "range_m": np.asarray(plots["range_m"], dtype=float),
        "azimuth_deg": np.asarray(plots["azimuth_deg"], dtype=float),
        "flight_level": flight_level,
        "altitude_m": asterix_units.flight_level_to_altitude(flight_level),
    })
    return table, pa.Table.from_pylist(sorted(radars.values(), key=lambda r: r["radar_id"]))


def _decode_file(path: Path, plots: dict[str, list], radars: dict[int, dict]) -> None:
    """Append one file's CAT048 plots to `plots` and its CAT034 radars to `radars`."""
    base, cat048, cat034 = _codec()
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    data = path.read_bytes()
    for number, (offset, chunk) in enumerate(datablocks(data, path)):
        parsed = base.RawDatablock.parse(base.Bits.from_bytes(chunk))
        if isinstance(parsed, ValueError) or len(parsed) != 1:
            raise InputError(f"{path}: datablock {number} at byte {offset} is corrupt: {parsed}")
        block = parsed[0]
        category = block.get_category()
        if category not in (34, 48):
            continue
        uap = cat048.cv_uap if category == 48 else cat034.cv_uap
        records = uap.parse(block.get_raw_records())
        if isinstance(records, ValueError):
            raise InputError(f"{path}: datablock {number} (CAT{category:03d}) cannot be decoded: {records}")
        for record in records:
            try:
                source = record.get_item("010").variation
                radar_id = source.get_item("SAC").as_uint() * 256 + source.get_item("SIC").as_uint()
                if category == 34:
                    if record.get_item("000").as_uint() == NORTH_MARKER and record.get_item("120") is not None:
                        radars[radar_id] = {
                            "radar_id": radar_id, "sac": radar_id // 256, "sic": radar_id % 256,
                            "latitude_deg": _quantity(record, "120", "LAT", "°"),
                            "longitude_deg": _quantity(record, "120", "LON", "°"),
                            "height_m": _quantity(record, "120", "HGT", "m"),
                            "scan_period_s": _quantity(record, "041", None, "s")}
                    continue
                plots["radar_id"].append(radar_id)
                plots["time_of_day_s"].append(_quantity(record, "140", None, "s"))
                plots["range_m"].append(_quantity(record, "040", "RHO", "NM") * asterix_units.NAUTICAL_MILE_M)
                plots["azimuth_deg"].append(_quantity(record, "040", "THETA", "°"))
                plots["flight_level"].append(_quantity(record, "090", "FL", "FL"))
            except (KeyError, AttributeError) as error:
                raise InputError(f"{path}: datablock {number} (CAT{category:03d}) has a record without item "
                                 f"{error}") from None

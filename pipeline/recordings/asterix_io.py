"""ASTERIX CAT048 plots and CAT034 north markers, read and written with libasterix.

libasterix (asterix-libs, generated from the asterix-specs definitions) encodes and decodes
every edition exactly; this module maps its items to our columns (EUROCONTROL ASTERIX CAT048
ed. 1.32, CAT034 ed. 1.29):

- CAT048 I048/010 SAC/SIC, I048/140 time of day, I048/020 report type, I048/040 slant range
  and azimuth, I048/090 flight level, I048/170 track status.
- CAT034 I034/010 SAC/SIC, I034/041 antenna rotation period, I034/120 radar position (height,
  latitude, longitude), from whichever CAT034 message carries them (I034/120 is optional).

A CAT048 record is not always a plot the tracker can use. Records that are not one are left
out and counted by reason (`Recording.skipped`, one warning line):

- not an aircraft: I048/020 SIM=1 ("simulated target report"), TST=1 (first extension: "test
  target report") or RAB=1 ("report from field monitor (fixed transponder)"): a radar's test
  target and its site monitor would otherwise be tracked as aircraft (case 32).
- no position: no I048/040 (sent only "when there is a detection"), I048/020 TYP=0 (no
  detection: a track's coasted report), I048/170 TRE=1 (the last report of a radar track) or
  I048/020 ERR=1 (the range is past I048/040's 256 NM: RHO holds its maximum and the range is in
  the Reserved Expansion Field, which is not read).
- no usable altitude: no I048/090, or I048/090 with G=1 (garbled code) or V=1 (code not
  validated). The tracker places a plot from its slant range, azimuth and altitude: a wrong
  altitude moves the plot's ground position by kilometres (FL 1000 instead of FL 350 at 30 km
  puts it 17 km short), and an altitude borrowed from a neighbouring plot would be a guess the
  measurement covariance does not carry. A dropped plot is a missed detection, which the
  tracker is built for.
- datablocks of other categories (CAT062 tracks, CAT001, or a corrupted category byte),
  counted by category so that plots that vanish are visible.

The other report flags of I048/020 describe a real aircraft's reply and are read past: RDP (which
of the radar's two processing chains), SPI (the pilot's ident), XPP (X-pulse), ME and MI
(military emergency and identification), FOE/FRI (the Mode 4 reply), and the later extensions'
ADS-B, SCN, PAI and transponder-capability fields. (Meanings: CAT048 I048/020 in EUROCONTROL
ASTERIX Part 4 Category 48, as in the asterix-specs definitions libasterix is generated from.)
A file with no CAT048 record at all holds no plots (a CAT062 track file, or service messages
only): it is an InputError saying so and what the file held.

Every decoded value is checked against what the standard allows (`ALLOWED`); a value outside
it, or a mandatory item missing, is an InputError naming the file, the datablock (number and
byte offset), the record and the item.

ASTERIX carries only the time of day, so decoding needs the UTC date of the recording's first
record. Radars send plots in azimuth order, so times interleave near midnight: each plot goes on
the day that puts it nearest the plot before it (`asterix_units.unwrap_time_of_day`).
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import date, datetime, timezone
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa

from pipeline.geometry import asterix_units
from pipeline.geometry.asterix_units import NAUTICAL_MILE_M, SECONDS_PER_DAY
from pipeline.io import InputError

log = logging.getLogger("pipeline")

RECORDS_PER_DATABLOCK = 1000
NORTH_MARKER = 1   # I034/000 message type
NO_DETECTION = 0   # I048/020 TYP
TRACK_END = 1      # I048/170 TRE

SIMULATED = "CAT048 simulated target report (I048/020 SIM=1)"
TEST_TARGET = "CAT048 test target report (I048/020 TST=1)"
FIELD_MONITOR = "CAT048 report from a field monitor (I048/020 RAB=1)"
NOT_AN_AIRCRAFT = (("SIM", SIMULATED), ("TST", TEST_TARGET), ("RAB", FIELD_MONITOR))  # I048/020 flag set to 1
EXTENDED_RANGE = "CAT048 range past I048/040 (I048/020 ERR=1)"
NO_POSITION = "CAT048 record without position (I048/040)"
NOT_DETECTED = "CAT048 record without detection (I048/020 TYP=0)"
ENDED = "CAT048 track-end record (I048/170 TRE=1)"
NO_FLIGHT_LEVEL = "CAT048 record without flight level (I048/090)"
INVALID_FLIGHT_LEVEL = "CAT048 flight level garbled or not validated (I048/090 G/V)"
NO_RADAR_POSITION = "plots of radar without position"

RADAR_SCHEMA = pa.schema([  # a radar as its CAT034 messages describe it; null where no message carried the item
    ("radar_id", pa.int32()), ("sac", pa.int32()), ("sic", pa.int32()), ("latitude_deg", pa.float64()),
    ("longitude_deg", pa.float64()), ("height_m", pa.float64()), ("scan_period_s", pa.float64()),
])
SITE = ("latitude_deg", "longitude_deg", "height_m")


class Allowed(NamedTuple):
    test: Callable[[float], bool]
    text: str


ALLOWED = {  # item -> the values the standard allows, in the unit it is decoded in
    "I048/140": Allowed(lambda s: 0.0 <= s < SECONDS_PER_DAY, "0 <= s < 86400, reset at midnight (CAT048 I048/140)"),
    "I048/040 RHO": Allowed(lambda nm: 0.0 <= nm < 256.0, "0 <= NM < 256 (CAT048 I048/040)"),
    "I048/040 THETA": Allowed(lambda deg: 0.0 <= deg < 360.0, "0 <= deg < 360 (CAT048 I048/040)"),
    "I048/090 FL": Allowed(lambda fl: -12.0 <= fl <= 1270.0, "-12 <= FL <= 1270 (CAT048 I048/090)"),
    "I034/041": Allowed(lambda s: s > 0.0, "> 0 s (CAT034 I034/041)"),
    "I034/120 LAT": Allowed(lambda deg: -90.0 <= deg <= 90.0, "-90 <= deg <= 90 (CAT034 I034/120)"),
    "I034/120 LON": Allowed(lambda deg: -180.0 <= deg < 180.0, "-180 <= deg < 180 (CAT034 I034/120)"),
    # WGS-84 height of a radar site: below the Dead Sea shore or above Everest is a broken record.
    "I034/120 HGT": Allowed(lambda m: -500.0 <= m <= 9000.0, "-500 <= m <= 9000, a site on Earth (CAT034 I034/120)"),
}


def _codec():  # imported lazily: libasterix's generated module is large and slow to import
    import asterix.base as base
    import asterix.generated as generated
    return base, generated.Cat_048_1_32, generated.Cat_034_1_29


# ----------------------------------------------------------------------------- writing

def source_item(radar: dict) -> tuple:
    """I010 (SAC, SIC) of a radar description row."""
    return (("SAC", int(radar["sac"])), ("SIC", int(radar["sic"])))


def marker_items(radar: dict, north_time_unix_s: float) -> dict:
    """The items of a CAT034 north marker (I034/000 type 1) with the radar's rotation period
    (I034/041) and position (I034/120)."""
    return {
        "000": NORTH_MARKER, "010": source_item(radar),
        "030": (float(asterix_units.time_of_day(north_time_unix_s)), "s"),
        "041": (float(radar["scan_period_s"]), "s"),
        "120": (("HGT", (float(radar["height_m"]), "m")), ("LAT", (float(radar["latitude_deg"]), "°")),
                ("LON", (float(radar["longitude_deg"]), "°"))),
    }


def plot_items(radar: dict, time_unix_s: float, range_m: float, azimuth_deg: float, flight_level: float) -> dict:
    """The items of a CAT048 single PSR plot (I048/020 TYP=1) with a valid flight level."""
    return {
        "010": source_item(radar),
        "140": (float(asterix_units.time_of_day(time_unix_s)), "s"),
        "020": ((("TYP", 1), ("SIM", 0), ("RDP", 0), ("SPI", 0), ("RAB", 0), None),),
        "040": (("RHO", (float(range_m / NAUTICAL_MILE_M), "NM")), ("THETA", (float(azimuth_deg), "°"))),
        "090": (("V", 0), ("G", 0), ("FL", (float(flight_level), "FL"))),
    }


def datablock(category: int, records: list[dict]) -> bytes:
    """One CAT034 or CAT048 datablock of records given as item dicts (`marker_items`, `plot_items`)."""
    _, cat048, cat034 = _codec()
    codec = cat048 if category == 48 else cat034
    return codec.create([codec.cv_record.create(items) for items in records]).unparse().to_bytes()


def encode(plots: pa.Table, radar: dict, scan_times: np.ndarray) -> bytes:
    """A recording: a CAT034 north marker at each scan start, then that scan's CAT048 plots.

    `plots` needs time_unix_s, range_m, azimuth_deg, flight_level; `radar` the columns of a
    radar description row and its sac, sic.
    """
    times = plots.column("time_unix_s").to_numpy()
    order = np.argsort(times, kind="stable")
    columns = {name: plots.column(name).to_numpy()[order] for name in
               ("time_unix_s", "range_m", "azimuth_deg", "flight_level")}
    scan_of_plot = np.searchsorted(scan_times, columns["time_unix_s"], side="right") - 1
    out = bytearray()
    for scan, north_time in enumerate(scan_times):
        out += datablock(34, [marker_items(radar, north_time)])
        rows = np.flatnonzero(scan_of_plot == scan)
        for start in range(0, len(rows), RECORDS_PER_DATABLOCK):
            out += datablock(48, [plot_items(radar, *(columns[name][i] for name in columns))
                                  for i in rows[start:start + RECORDS_PER_DATABLOCK]])
    return bytes(out)


# ----------------------------------------------------------------------------- reading

class Recording(NamedTuple):
    """A decoded recording: `plots` (radar_id, time, range, azimuth, flight level, altitude),
    `radars` (RADAR_SCHEMA, one row per radar with a CAT034 message; or, after
    `with_radar_description`, the radars with a position in RADAR_INPUT_SCHEMA's columns), and
    `skipped`, what was left out by reason."""

    plots: pa.Table
    radars: pa.Table
    skipped: dict[str, int]


@dataclass
class _Decoding:
    plots: list[tuple[int, float, float, float, float]] = field(default_factory=list)
    radars: dict[int, dict] = field(default_factory=dict)
    skipped: Counter = field(default_factory=Counter)


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


def decode(paths: Path | str | list[Path], first_date: date) -> Recording:
    """The plots and the radars' CAT034 descriptions of one recording, possibly split over several
    files given in time order. Errors name the file, the datablock, the record and the item."""
    paths = [Path(p) for p in paths] if isinstance(paths, list) else [Path(paths)]
    decoding = _Decoding()
    for path in paths:
        _decode_file(path, decoding)
    if decoding.skipped:
        log.warning("%s: skipped %s", ", ".join(map(str, paths)),
                    ", ".join(f"{count} {reason}" for reason, count in sorted(decoding.skipped.items())))
    radar_id, tod, range_m, azimuth, flight_level = np.array(decoding.plots, dtype=float).reshape(-1, 5).T
    midnight = datetime(first_date.year, first_date.month, first_date.day, tzinfo=timezone.utc).timestamp()
    plots = pa.table({
        "plot_id": np.arange(len(tod), dtype=np.int64),
        "radar_id": radar_id.astype(np.int32),
        "time_of_day_s": tod,
        "time_unix_s": midnight + asterix_units.unwrap_time_of_day(tod),
        "range_m": range_m,
        "azimuth_deg": azimuth,
        "flight_level": flight_level,
        "altitude_m": asterix_units.flight_level_to_altitude(flight_level),
    })
    radars = pa.Table.from_pylist([decoding.radars[r] for r in sorted(decoding.radars)], schema=RADAR_SCHEMA)
    return Recording(plots, radars, dict(decoding.skipped))


def _decode_file(path: Path, decoding: _Decoding) -> None:
    """Add one file's CAT048 plots, CAT034 radars and skipped records to `decoding`."""
    base, cat048, cat034 = _codec()
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    data = path.read_bytes()
    if not data:
        raise InputError(f"{path}: empty file, no ASTERIX datablock")
    held = _Held()
    for number, (offset, chunk) in enumerate(datablocks(data, path)):
        parsed = base.RawDatablock.parse(base.Bits.from_bytes(chunk))
        if isinstance(parsed, ValueError) or len(parsed) != 1:
            raise InputError(f"{path}: datablock {number} at byte {offset} is corrupt: {parsed}")
        category = parsed[0].get_category()
        held.blocks[category] += 1
        if category not in (34, 48):
            decoding.skipped[f"datablock CAT{category:03d}"] += 1
            continue
        block = f"{path}: datablock {number} (CAT{category:03d}) at byte {offset}"
        records = (cat048 if category == 48 else cat034).cv_uap.parse(parsed[0].get_raw_records())
        if isinstance(records, ValueError):
            raise InputError(f"{block}: cannot be decoded: {records}")
        held.records[category] += len(records)
        for index, record in enumerate(records):
            where = f"{block}, record {index}"
            if category == 34:
                _read_radar(record, where, decoding.radars)
                continue
            plot = _read_plot(record, where)
            if isinstance(plot, str):
                decoding.skipped[plot] += 1
            else:
                decoding.plots.append(plot)
    if not held.records[48]:
        raise InputError(f"{path}: holds no plots: no CAT048 target report (it holds {held})")


@dataclass
class _Held:
    """What one file holds: datablocks by category, records of the categories read (34, 48)."""

    blocks: Counter = field(default_factory=Counter)
    records: Counter = field(default_factory=Counter)

    def __str__(self) -> str:
        return ", ".join(f"{count} CAT{category:03d} datablock{'s' * (count != 1)}"
                         + (f" of {self.records[category]} records" if category in (34, 48) else "")
                         for category, count in sorted(self.blocks.items()))


def _item(record: object, item: str, where: str) -> object:
    """The variation of a mandatory item ("I048/010"): every CAT048 and CAT034 record carries its
    data source (I048/010, I034/010) and time of day (I048/140), so a record without one is broken
    (a corrupt FSPEC reads as a record with the wrong items)."""
    value = record.get_item(item[-3:])
    if value is None:
        raise InputError(f"{where}: item {item} missing (every record of the category carries it)")
    return value.variation


def _value(variation: object, item: str, unit: str, where: str) -> float:
    """The quantity of `variation` in `unit`, checked against ALLOWED[item] ("I048/040 RHO")."""
    sub = item.partition(" ")[2]
    content = (variation.get_item(sub).variation if sub else variation).content
    value = float(content.as_quantity(unit))
    allowed = ALLOWED[item]
    if not allowed.test(value):
        raise InputError(f"{where}: item {item} is {value:g} {unit}, outside {allowed.text}")
    return value


def _radar_id(record: object, item: str, where: str) -> int:
    """SAC * 256 + SIC of the record's data source item (I048/010, I034/010)."""
    source = _item(record, item, where)
    return source.get_item("SAC").as_uint() * 256 + source.get_item("SIC").as_uint()


def _flag(variation: object | None, name: str) -> int | None:
    """A one-bit sub-item's value, or None when the item (or the extension holding it) is absent."""
    sub = variation.get_item(name) if variation is not None else None
    return None if sub is None else sub.as_uint()


def _read_plot(record: object, where: str) -> tuple[int, float, float, float, float] | str:
    """(radar id, time of day s, slant range m, azimuth deg, flight level) of a CAT048 record, or
    the reason it is not a plot the tracker can place (module docstring; the first that applies, in
    that order)."""
    radar_id = _radar_id(record, "I048/010", where)
    time_of_day = _value(_item(record, "I048/140", where), "I048/140", "s", where)
    variation = {name: getattr(record.get_item(name), "variation", None) for name in ("020", "040", "090", "170")}
    for flag, reason in NOT_AN_AIRCRAFT:
        if _flag(variation["020"], flag) == 1:
            return reason
    if variation["040"] is None:
        return NO_POSITION
    if _flag(variation["020"], "TYP") == NO_DETECTION:
        return NOT_DETECTED
    if _flag(variation["170"], "TRE") == TRACK_END:
        return ENDED
    if _flag(variation["020"], "ERR") == 1:
        return EXTENDED_RANGE
    range_nm = _value(variation["040"], "I048/040 RHO", "NM", where)
    azimuth = _value(variation["040"], "I048/040 THETA", "°", where)
    if variation["090"] is None:
        return NO_FLIGHT_LEVEL
    if _flag(variation["090"], "G") or _flag(variation["090"], "V"):
        return INVALID_FLIGHT_LEVEL
    level = _value(variation["090"], "I048/090 FL", "FL", where)
    return radar_id, time_of_day, range_nm * NAUTICAL_MILE_M, azimuth, level


def _read_radar(record: object, where: str, radars: dict[int, dict]) -> None:
    """Note the rotation period (I034/041) and position (I034/120) a CAT034 record carries for its
    radar; both are optional, and a later message's values replace an earlier one's."""
    radar_id = _radar_id(record, "I034/010", where)
    radar = radars.setdefault(radar_id, {"radar_id": radar_id, "sac": radar_id // 256, "sic": radar_id % 256})
    period, site = record.get_item("041"), record.get_item("120")
    if period is not None:
        radar["scan_period_s"] = _value(period.variation, "I034/041", "s", where)
    if site is not None:
        radar.update(latitude_deg=_value(site.variation, "I034/120 LAT", "°", where),
                     longitude_deg=_value(site.variation, "I034/120 LON", "°", where),
                     height_m=_value(site.variation, "I034/120 HGT", "m", where))


def with_radar_description(recording: Recording, description: pa.Table | None, source: str) -> Recording:
    """The recording with its radars' positions: a radar the description (`track --radar`, rows in
    RADAR_INPUT_SCHEMA) lists is placed there, else at its CAT034 I034/120; the scan period is the
    description's, else the CAT034 I034/041. Plots of a radar with no position cannot be placed:
    they are left out, counted and the radars named in a warning. No radar with a position at all
    is an InputError."""
    given = {row["radar_id"]: row for row in (description.to_pylist() if description is not None else [])}
    markers = {row["radar_id"]: row for row in recording.radars.to_pylist()}
    radars = []
    for radar_id in sorted(set(given) | set(markers)):
        row, marker = given.get(radar_id), markers.get(radar_id, {})
        site = row if row is not None else marker if marker.get("latitude_deg") is not None else None
        if site is None:
            continue
        period = row.get("scan_period_s") if row is not None else None
        radars.append({"radar_id": radar_id, **{name: site[name] for name in SITE},
                       "scan_period_s": period if period is not None else marker.get("scan_period_s")})
    if not radars:
        raise InputError(f"{source}: no radar position: no CAT034 message carries I034/120 and no --radar "
                         "description is given (radar_id, latitude_deg, longitude_deg, height_m)")
    placed = {radar["radar_id"] for radar in radars}
    radar_ids = recording.plots.column("radar_id").to_numpy()
    keep = np.isin(radar_ids, list(placed))
    skipped = dict(recording.skipped)
    if not keep.all():
        unplaced = sorted(set(np.unique(radar_ids[~keep]).tolist()))
        log.warning("%s: skipped %d plots of radar ids %s: no position (no CAT034 I034/120, not in --radar)",
                    source, int((~keep).sum()), unplaced)
        skipped[NO_RADAR_POSITION] = int((~keep).sum())
    return Recording(recording.plots.filter(pa.array(keep)), pa.Table.from_pylist(radars), skipped)

"""ASTERIX CAT048 plots and CAT034 north markers: the round trip, the clock across midnight, damaged
files, and `track --asterix` / `asterix-export` end to end on a simulated scenario.

Hand-made plots are quantised with pipeline.geometry.asterix_units first, as the simulator quantises its
plots, so what is encoded is exactly representable and the decoded values must agree to the
resolution of each item.
"""

from __future__ import annotations

import json
from datetime import date, datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from pipeline import cli, io
from pipeline.geometry import asterix_units as units
from pipeline.io import InputError
from pipeline.recordings import asterix_io
from pipeline.recordings.plot_table import RADAR_INPUT_SCHEMA, read_asterix_plots
from pipeline.simulation import simulate
from tests import tracker_fixtures as tf
from tests.project import run_pipeline, tiny_params_tree, write_params

DAY = date(2026, 6, 1)
MIDNIGHT = datetime(2026, 6, 1, tzinfo=timezone.utc).timestamp()
LATITUDE_STEP_DEG = 180.0 / 2 ** 23   # I034/120 latitude and longitude resolution
RADAR = {"sac": 3, "sic": 7, "scan_period_s": 6.0, "height_m": 60.4, "latitude_deg": -33.94612345,
         "longitude_deg": 151.17723456}

pytestmark = pytest.mark.filterwarnings("ignore:.*LeafSpec.* is deprecated")


def quantised_plots(times: np.ndarray, rng: np.random.Generator) -> pa.Table:
    n = len(times)
    return pa.table({
        "time_unix_s": times,
        "range_m": units.quantise_range(rng.uniform(1000.0, 400000.0, n)),
        "azimuth_deg": units.quantise_azimuth(rng.uniform(0.0, 360.0, n)),
        "flight_level": units.altitude_to_flight_level(rng.uniform(0.0, 15000.0, n)),
    })


def scan_starts(times: np.ndarray, period: float = 6.0) -> np.ndarray:
    return np.unique(np.floor(times / period)) * period


def write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> tuple[pa.Table, Path]:
    """1100 plots over three scans (one scan holds 1050, so two CAT048 datablocks) and three north markers."""
    rng = np.random.default_rng(21)
    start = MIDNIGHT + 12 * 3600.0
    times = np.sort(np.concatenate([start + rng.uniform(0.0, 6.0, 1050), start + 6.0 + rng.uniform(0.0, 12.0, 50)]))
    plots = quantised_plots(times, rng)
    path = tmp_path_factory.mktemp("asterix") / "recording.ast"
    write(path, asterix_io.encode(plots, RADAR, scan_starts(times)))
    return plots, path


# ----------------------------------------------------------------------------- the round trip

def test_round_trip_keeps_every_plot_to_the_item_resolutions(recording):
    plots, path = recording
    decoded, _, skipped = asterix_io.decode(path, DAY)
    assert decoded.num_rows == plots.num_rows and skipped == {}
    column = lambda table, name: table.column(name).to_numpy()  # noqa: E731
    np.testing.assert_array_equal(column(decoded, "plot_id"), np.arange(plots.num_rows))
    np.testing.assert_array_equal(column(decoded, "radar_id"), 3 * 256 + 7)
    np.testing.assert_allclose(column(decoded, "range_m"), column(plots, "range_m"), rtol=0.0,
                               atol=units.RANGE_STEP_M / 2)
    azimuth_error = np.abs((column(decoded, "azimuth_deg") - column(plots, "azimuth_deg") + 180.0) % 360.0 - 180.0)
    assert azimuth_error.max() <= units.AZIMUTH_STEP_DEG / 2
    np.testing.assert_allclose(column(decoded, "flight_level"), column(plots, "flight_level"), rtol=0.0,
                               atol=units.FLIGHT_LEVEL_STEP / 2)
    np.testing.assert_allclose(column(decoded, "altitude_m"),
                               units.flight_level_to_altitude(column(decoded, "flight_level")), rtol=1e-12)
    np.testing.assert_allclose(column(decoded, "time_of_day_s"), column(plots, "time_unix_s") - MIDNIGHT, rtol=0.0,
                               atol=units.TIME_OF_DAY_STEP_S)
    np.testing.assert_allclose(column(decoded, "time_unix_s"), column(plots, "time_unix_s"), rtol=0.0,
                               atol=units.TIME_OF_DAY_STEP_S)


def test_radar_position_and_id_come_from_the_north_markers(recording):
    """I034/120 to its resolution (180/2^23 deg, 1 m), I034/041 the rotation period, SAC/SIC the id."""
    _, radars, _ = asterix_io.decode(recording[1], DAY)
    assert radars.num_rows == 1
    radar = radars.to_pylist()[0]
    assert (radar["radar_id"], radar["sac"], radar["sic"]) == (775, 3, 7)
    assert abs(radar["latitude_deg"] - RADAR["latitude_deg"]) <= LATITUDE_STEP_DEG
    assert abs(radar["longitude_deg"] - RADAR["longitude_deg"]) <= LATITUDE_STEP_DEG
    assert abs(radar["height_m"] - RADAR["height_m"]) <= 1.0
    assert radar["scan_period_s"] == pytest.approx(6.0)


def test_recording_crossing_midnight_decodes_to_increasing_times(tmp_path):
    """Plots from 23:59:30 to 00:00:54 with the date of the first record: times increase through
    midnight, the ones after it on the next day, while the time of day wraps to 0."""
    rng = np.random.default_rng(3)
    times = MIDNIGHT + 86400.0 - 30.0 + np.arange(15) * 6.0 + 0.3
    path = write(tmp_path / "midnight.ast", asterix_io.encode(quantised_plots(times, rng), RADAR, scan_starts(times)))
    decoded, _, _ = asterix_io.decode(path, DAY)
    unix = decoded.column("time_unix_s").to_numpy()
    assert (np.diff(unix) > 0).all()
    np.testing.assert_allclose(unix, times, rtol=0.0, atol=units.TIME_OF_DAY_STEP_S)
    tod = decoded.column("time_of_day_s").to_numpy()
    assert (tod[:5] > 86000.0).all() and (tod[5:] < 100.0).all()


def test_recording_split_into_two_files_at_midnight_keeps_increasing_times(tmp_path):
    """`--asterix before.ast --asterix after.ast --date <day of the first record>`: the second file's
    plots come after the first file's, not 24 h before them."""
    rng = np.random.default_rng(4)
    times = MIDNIGHT + 86400.0 - 30.0 + np.arange(10) * 6.0
    plots = quantised_plots(times, rng)
    first = write(tmp_path / "before.ast", asterix_io.encode(plots.slice(0, 5), RADAR, scan_starts(times[:5])))
    second = write(tmp_path / "after.ast", asterix_io.encode(plots.slice(5), RADAR, scan_starts(times[5:])))
    plots = read_asterix_plots([first, second], DAY, tf.make_params().radar)
    np.testing.assert_allclose(plots.time, times, rtol=0.0,
                               atol=units.TIME_OF_DAY_STEP_S)


# ----------------------------------------------------------------------------- damaged files

@pytest.mark.parametrize("damage", ["drop 1 byte", "drop 5 bytes", "random bytes", "text", "appended garbage",
                                    "bogus CAT048 record", "empty"])
def test_damaged_file_is_an_input_error_naming_the_file(recording, tmp_path, damage):
    data = recording[1].read_bytes()
    rng = np.random.default_rng(9)
    damaged = {
        "drop 1 byte": data[:-1],
        "drop 5 bytes": data[:-5],
        "random bytes": rng.integers(0, 256, 500, dtype=np.uint8).tobytes(),
        "text": b"this is not an ASTERIX recording\n" * 4,
        "appended garbage": data + b"\x30\xff",
        "bogus CAT048 record": b"\x30\x00\x10" + b"\xff" * 13,
        "empty": b"",
    }[damage]
    path = write(tmp_path / "damaged.ast", damaged)
    with pytest.raises(InputError, match=str(path)):
        asterix_io.decode(path, DAY)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(InputError, match=f"{tmp_path / 'none.ast'}: file not found"):
        asterix_io.decode(tmp_path / "none.ast", DAY)


# ----------------------------------------------------------------------------- records that are not plots
# Recordings built record by record with the project's encoder (asterix_io.plot_items, marker_items,
# datablock), changed item by item where a test needs a record the simulator never sends.

SECOND = {**RADAR, "sic": 8, "latitude_deg": RADAR["latitude_deg"] + 0.5}  # a second radar, 55 km north


def target(radar: dict, scans: int, start_s: float = MIDNIGHT + 36000.0) -> list[dict]:
    """A straight radial target at FL350 from 30 km, 1 km per 6 s scan at azimuth 45 deg: one plot per scan."""
    return [asterix_io.plot_items(radar, start_s + 6.0 * scan, 30000.0 + 1000.0 * scan, 45.0, 350.0)
            for scan in range(scans)]


def changed(items: dict, **changes) -> dict:
    """`items` with items replaced (a value) or removed (None), e.g. changed(plot, i040=None)."""
    out = dict(items)
    for name, value in changes.items():
        out.pop(name[1:], None)
        if value is not None:
            out[name[1:]] = value
    return out


def recording_of(path: Path, plots: list[dict], radar: dict = RADAR, marker: dict | None = None) -> Path:
    """A CAT034 north marker (`marker`, else the radar's with I034/041 and I034/120), then the plots in one CAT048 block."""
    marker = marker if marker is not None else asterix_io.marker_items(radar, MIDNIGHT + 36000.0)
    return write(path, asterix_io.datablock(34, [marker]) + asterix_io.datablock(48, plots))


def report(typ: int) -> tuple:
    """I048/020 with the report type TYP."""
    return ((("TYP", typ), ("SIM", 0), ("RDP", 0), ("SPI", 0), ("RAB", 0), None),)


def flight_level(fl: float, v: int = 0, g: int = 0) -> tuple:
    """I048/090 with its validated (V) and garbled (G) bits."""
    return (("V", v), ("G", g), ("FL", (fl, "FL")))


TRACK_END = ((("CNF", 0), ("RAD", 0), ("DOU", 0), ("MAH", 0), ("CDM", 0), None),
             (("TRE", 1), ("GHO", 0), ("SUP", 0), ("TCC", 0), 0, None))  # I048/170 with TRE=1


def test_records_without_a_position_or_altitude_are_skipped_and_counted_in_one_warning(tmp_path, caplog):
    """CAT048 ed. 1.32: I048/040 is sent only with a detection; I048/020 TYP=0 is no detection, I048/170
    TRE=1 a track's last report (case 01's two track-end records have all three); I048/090 absent,
    garbled (G) or not validated (V) gives no altitude. Each is left out and counted by reason, the
    other plots decode; `read_asterix_plots` carries the counts in Plots.skipped."""
    plots = target(RADAR, 10)
    plots[1] = changed(plots[1], i040=None, i020=report(0), i170=TRACK_END)
    plots[2] = changed(plots[2], i040=None)
    plots[3] = changed(plots[3], i020=report(0))
    plots[4] = changed(plots[4], i170=TRACK_END)
    plots[5] = changed(plots[5], i090=None)
    plots[6] = changed(plots[6], i090=flight_level(1000.0, g=1))
    plots[7] = changed(plots[7], i090=flight_level(0.0, v=1))
    path = recording_of(tmp_path / "skips.ast", plots)
    decoded, _, skipped = asterix_io.decode(path, DAY)
    assert skipped == {asterix_io.NO_POSITION: 2, asterix_io.NOT_DETECTED: 1, asterix_io.ENDED: 1,
                       asterix_io.NO_FLIGHT_LEVEL: 1, asterix_io.INVALID_FLIGHT_LEVEL: 2}
    np.testing.assert_allclose(decoded.column("range_m").to_numpy(), [30000.0, 38000.0, 39000.0],
                               atol=units.RANGE_STEP_M)
    np.testing.assert_array_equal(decoded.column("flight_level").to_numpy(), 350.0)
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1 and warnings[0].startswith(f"{path}: skipped ")
    assert all(f"{count} {reason}" in warnings[0] for reason, count in skipped.items())
    assert read_asterix_plots([path], DAY, tf.make_params().radar).skipped == skipped


def descriptor(typ: int = 2, sim: int = 0, rdp: int = 0, spi: int = 0, rab: int = 0, **extension: int) -> tuple:
    """I048/020 with its first part's flags and, if any of TST, ERR, XPP, ME, MI, FOEFRI is given, the
    first extension (the others 0)."""
    first = (("TYP", typ), ("SIM", sim), ("RDP", rdp), ("SPI", spi), ("RAB", rab), None)
    if not extension:
        return (first,)
    names = ("TST", "ERR", "XPP", "ME", "MI", "FOEFRI")
    return first, (*((name, extension.get(name, 0)) for name in names), None)


def test_reports_flagged_as_no_aircraft_or_past_i048_040_are_skipped_and_the_other_flags_read_past(tmp_path, caplog):
    """CAT048 I048/020: SIM=1 (simulated target report), RAB=1 (field monitor, a fixed transponder) and,
    in the first extension, TST=1 (test target report) are not aircraft; ERR=1 puts the range past
    I048/040 (in the Reserved Expansion Field). Each is left out and counted by its reason in the one
    warning line. RDP, SPI, XPP, ME, MI and FOE/FRI describe a real aircraft's reply: those plots are kept."""
    plots = target(RADAR, 10)
    for scan, flags in ((1, {"sim": 1}), (2, {"rab": 1}), (3, {"TST": 1}), (4, {"ERR": 1}), (5, {"sim": 1, "rab": 1}),
                        (6, {"rdp": 1, "spi": 1}), (7, {"XPP": 1, "ME": 1, "MI": 1, "FOEFRI": 2})):
        plots[scan] = changed(plots[scan], i020=descriptor(**flags))
    path = recording_of(tmp_path / "flags.ast", plots)
    decoded, _, skipped = asterix_io.decode(path, DAY)
    assert skipped == {asterix_io.SIMULATED: 2, asterix_io.FIELD_MONITOR: 1, asterix_io.TEST_TARGET: 1,
                       asterix_io.EXTENDED_RANGE: 1}
    np.testing.assert_allclose(decoded.column("range_m").to_numpy(), [30000.0, 36000.0, 37000.0, 38000.0, 39000.0],
                               atol=units.RANGE_STEP_M)
    assert (f"{path}: skipped 1 CAT048 range past I048/040 (I048/020 ERR=1), 1 CAT048 report from a field monitor "
            "(I048/020 RAB=1), 2 CAT048 simulated target report (I048/020 SIM=1), 1 CAT048 test target report "
            "(I048/020 TST=1)") in caplog.text


def test_a_simulated_target_and_a_field_monitor_beside_an_aircraft_leave_only_the_aircrafts_track(tmp_path):
    """Case 32's kind: each scan holds the aircraft (`target`), a simulated target (SIM=1) flying beside
    it 10 km further out and the site's field monitor (RAB=1) fixed at 15 km: `track` confirms the
    aircraft only, and its summary counts the 12 + 12 reports left out."""
    plots = []
    for scan, plot in enumerate(target(RADAR, 12)):
        start = MIDNIGHT + 36000.0 + 6.0 * scan
        simulated = asterix_io.plot_items(RADAR, start + 1.0, 40000.0 + 1000.0 * scan, 45.0, 350.0)
        monitor = asterix_io.plot_items(RADAR, start + 2.0, 15000.0, 120.0, 10.0)
        plots += [plot, changed(simulated, i020=descriptor(sim=1)), changed(monitor, i020=descriptor(rab=1))]
    tracks, summary = track_asterix(tmp_path, [recording_of(tmp_path / "sim_rab.ast", plots)], "kalman_cv")
    assert summary["skipped"] == {asterix_io.SIMULATED: 12, asterix_io.FIELD_MONITOR: 12}
    assert summary["plots_tracked"] == 12 and summary["confirmed_tracks"] == 1
    assert tracks.column("plot_id").to_pylist() == list(range(12))  # the aircraft's plots, numbered in time order
    assert set(tracks.column("track_id").to_pylist()) == {0}


def test_a_file_without_cat048_reports_is_refused_saying_it_holds_no_plots_and_what_it_holds(tmp_path, caplog):
    """North markers and CAT062 system tracks but no CAT048 record (a track file given for a plot file):
    exit 2, the file named as holding no plots, with its datablocks by category and their records;
    also when it is the second of two files (the first has plots)."""
    markers = b"".join(asterix_io.datablock(34, [asterix_io.marker_items(RADAR, MIDNIGHT + 36000.0 + 6.0 * k)])
                       for k in range(3))
    block = asterix_io.datablock(48, target(RADAR, 4))
    path = write(tmp_path / "tracks.ast", markers + (bytes([62]) + block[1:]) * 2)
    message = (f"{path}: holds no plots: no CAT048 target report (it holds 3 CAT034 datablocks of 3 records, "
               "2 CAT062 datablocks)")
    with pytest.raises(InputError) as error:
        asterix_io.decode(path, DAY)
    assert str(error.value) == message
    params_path = write_params(tf.params_tree(), tmp_path / "params.yaml")
    first = recording_of(tmp_path / "plots.ast", target(RADAR, 4))
    out = tmp_path / "out.parquet"
    code = cli.main(["track", "--params", str(params_path), "--asterix", str(first), "--asterix", str(path),
                     "--date", DAY.isoformat(), "--method", "kalman_cv", "--models", str(tmp_path), "--out", str(out)])
    assert code == 2 and message in caplog.text and not out.exists()


def test_garbled_and_unvalidated_flight_levels_leave_the_target_one_confirmed_track(tmp_path):
    """Case 04's kind: a straight target with one garbled (G=1, FL 1000) and one not validated (V=1,
    FL 0) plot. Both are dropped, so neither is placed kilometres off: `track --method kalman_cv` with
    only the tuned filters gives one confirmed track through the other plots, and the summary counts
    the two."""
    plots = target(RADAR, 12)
    plots[5] = changed(plots[5], i090=flight_level(1000.0, g=1))
    plots[8] = changed(plots[8], i090=flight_level(0.0, v=1))
    path = recording_of(tmp_path / "garbled.ast", plots)
    tracks, summary = track_asterix(tmp_path, [path], "kalman_cv")
    assert tracks.column("plot_id").to_pylist() == list(range(10))  # the 10 plots kept, numbered in time order
    assert set(tracks.column("track_id").to_pylist()) == {0}
    assert tracks.column("status").to_pylist()[-1] == "confirmed"
    assert summary["skipped"] == {asterix_io.INVALID_FLIGHT_LEVEL: 2} and summary["confirmed_tracks"] == 1


def track_asterix(folder: Path, paths: list[Path], method: str, *options: str, day: str = DAY.isoformat()
                  ) -> tuple[pa.Table, dict]:
    """`track --asterix` with default params and only the tuned filters: its output and summary."""
    params_path = write_params(tf.params_tree(), folder / "params.yaml")
    models = tf.write_tuned_filters(folder / "models", tf.make_params())
    out = folder / "tracks.parquet"
    code = cli.main(["track", "--params", str(params_path), *(f"--asterix={p}" for p in paths), "--date", day,
                     "--models", str(models), "--method", method, *options, "--out", str(out)])
    assert code == 0
    return pq.read_table(out), json.loads(out.with_name("tracks.summary.json").read_text())


@pytest.mark.parametrize("item, value, change", [
    ("I048/140", "90000 s", {"i140": (90000.0, "s")}),
    ("I048/090 FL", "1300 FL", {"i090": flight_level(1300.0)}),
    ("I048/090 FL", "-20 FL", {"i090": flight_level(-20.0)}),
])
def test_a_plot_value_the_standard_does_not_allow_names_file_block_record_and_item(tmp_path, item, value, change):
    """CAT048 ed. 1.32: time of day in [0, 86400) s (I048/140), flight level -12..1270 FL (I048/090)."""
    plots = target(RADAR, 3)
    plots[2] = changed(plots[2], **change)
    path = recording_of(tmp_path / "bad.ast", plots)
    marker_bytes = len(asterix_io.datablock(34, [asterix_io.marker_items(RADAR, MIDNIGHT + 36000.0)]))
    with pytest.raises(InputError, match=rf"{path}: datablock 1 \(CAT048\) at byte {marker_bytes}, record 2: "
                                         rf"item {item} is {value}, outside"):
        asterix_io.decode(path, DAY)


@pytest.mark.parametrize("item, value, change", [
    ("I034/120 LAT", "95 °", {"LAT": 95.0}),
    ("I034/120 HGT", "12000 m", {"HGT": 12000.0}),
    ("I034/041", "0 s", {"period": 0.0}),
])
def test_a_north_marker_value_the_standard_does_not_allow_exits_2_naming_it(tmp_path, caplog, item, value, change):
    """CAT034 ed. 1.29: latitude -90..90 deg (I034/120), a radar site's height on Earth, a rotation
    period above 0 (I034/041). `track` exits 2 with the file, block, record and item, and writes nothing."""
    radar = {**RADAR, "latitude_deg": change.get("LAT", RADAR["latitude_deg"]),
             "height_m": change.get("HGT", RADAR["height_m"]), "scan_period_s": change.get("period", 6.0)}
    path = recording_of(tmp_path / "bad.ast", target(RADAR, 3), marker=asterix_io.marker_items(radar, MIDNIGHT))
    params_path = write_params(tf.params_tree(), tmp_path / "params.yaml")
    out = tmp_path / "tracks.parquet"
    code = cli.main(["track", "--params", str(params_path), "--asterix", str(path), "--date", DAY.isoformat(),
                     "--method", "kalman_cv", "--models", str(tmp_path), "--out", str(out)])
    assert code == 2 and not out.exists()
    assert f"{path}: datablock 0 (CAT034) at byte 0, record 0: item {item} is {value}, outside" in caplog.text


@pytest.mark.parametrize("missing, item", [("i010", "I048/010"), ("i140", "I048/140")])
def test_a_record_without_a_mandatory_item_names_it(tmp_path, missing, item):
    """Case 16's kind: every CAT048 record carries I048/010 and I048/140; a record without one (as a
    corrupt FSPEC reads) is named by block, byte offset, record and item, not by a Python error text."""
    plots = target(RADAR, 2)
    plots[0] = changed(plots[0], **{missing: None})
    path = write(tmp_path / "broken.ast", asterix_io.datablock(48, plots))
    with pytest.raises(InputError, match=rf"{path}: datablock 0 \(CAT048\) at byte 0, record 0: item {item} missing"):
        asterix_io.decode(path, DAY)


def test_datablocks_of_other_categories_are_counted_by_category(tmp_path, caplog):
    """Case 17's kind: CAT062 tracks, CAT001 plots or a corrupted category byte are not read, but their
    datablocks are counted by category (in the one warning line), so plots that vanish are visible."""
    marker = asterix_io.datablock(34, [asterix_io.marker_items(RADAR, MIDNIGHT + 36000.0)])
    block = asterix_io.datablock(48, target(RADAR, 4))
    path = write(tmp_path / "mixed.ast", marker + block + bytes([62]) + block[1:] + bytes([1]) + block[1:] +
                 bytes([62]) + block[1:])
    decoded, _, skipped = asterix_io.decode(path, DAY)
    assert decoded.num_rows == 4
    assert skipped == {"datablock CAT062": 2, "datablock CAT001": 1}
    assert "skipped 1 datablock CAT001, 2 datablock CAT062" in caplog.text


# ----------------------------------------------------------------------------- midnight, in azimuth order

def test_plots_interleaved_around_midnight_each_go_on_the_day_nearest_the_plot_before(tmp_path):
    """Case 03's kind: a radar sends plots in azimuth order, so times of day interleave at midnight
    (86399.5, 86399.9, 0.0547, 86399.969, 0.2, 0.5 with --date 2026-01-01). Each plot goes on the day
    nearest the one before it, both ways, so no plot jumps a day and the target is one track."""
    tod = np.array([86399.5, 86399.9, 0.0547, 86399.969, 0.2, 0.5])
    midnight = datetime(2026, 1, 1, tzinfo=timezone.utc).timestamp()
    expected = midnight + np.where(tod > 43200.0, tod, tod + 86400.0)
    first = expected.min()  # the target flies 250 m/s radially; each plot where it was at its time
    plots = [asterix_io.plot_items(RADAR, t, 50000.0 + 250.0 * (t - first), 10.0, 300.0) for t in expected]
    path = recording_of(tmp_path / "midnight.ast", plots, marker=asterix_io.marker_items(RADAR, midnight + 86390.0))
    decoded, _, _ = asterix_io.decode(path, date(2026, 1, 1))
    np.testing.assert_allclose(decoded.column("time_unix_s").to_numpy(), expected, rtol=0.0,
                               atol=units.TIME_OF_DAY_STEP_S)
    tracks, _ = track_asterix(tmp_path, [path], "kalman_cv", day="2026-01-01")
    assert sorted(tracks.column("plot_id").to_pylist()) == list(range(6))
    assert set(tracks.column("track_id").to_pylist()) == {0}


# ----------------------------------------------------------------------------- radar positions: CAT034 and --radar

@pytest.fixture()
def two_radars(tmp_path) -> Path:
    """Radars 775 (markers with I034/120) and 776 (markers with I034/041 only; I034/120 is optional), 5 plots each."""
    without_site = changed(asterix_io.marker_items(SECOND, MIDNIGHT + 36000.0), i120=None,
                           i041=(4.0, "s"))
    data = (recording_of(tmp_path / "first.ast", target(RADAR, 5)).read_bytes() +
            asterix_io.datablock(34, [without_site]) + asterix_io.datablock(48, target(SECOND, 5)))
    return write(tmp_path / "two_radars.ast", data)


def test_plots_of_a_radar_without_position_are_skipped_naming_the_radar(two_radars, caplog):
    plots = read_asterix_plots([two_radars], DAY, tf.make_params().radar)
    assert set(plots.radars) == {775} and set(plots.radar_id.tolist()) == {775} and len(plots) == 5
    assert plots.skipped == {asterix_io.NO_RADAR_POSITION: 5}
    assert "skipped 5 plots of radar ids [776]: no position" in caplog.text


def test_the_radar_option_supplies_and_overrides_positions_with_asterix(two_radars, tmp_path):
    """`--radar` with `--asterix`: its rows place the radars (775's overriding its I034/120, 776's
    supplying the missing one); the scan period is the description's, else I034/041's."""
    description = pa.Table.from_pylist([
        {"radar_id": 775, "latitude_deg": -33.9, "longitude_deg": 151.2, "height_m": 10.0, "scan_period_s": 5.0},
        {"radar_id": 776, "latitude_deg": -33.4, "longitude_deg": 151.2, "height_m": 20.0, "scan_period_s": None},
    ], schema=RADAR_INPUT_SCHEMA)
    pq.write_table(description, tmp_path / "radars.parquet")
    plots = read_asterix_plots([two_radars], DAY, tf.make_params().radar, tmp_path / "radars.parquet")
    assert plots.skipped == {} and len(plots) == 10
    assert [(r.latitude_deg, r.height_m, r.rotation_rpm) for r in (plots.radars[775], plots.radars[776])] == [
        (-33.9, 10.0, 12.0), (-33.4, 20.0, 15.0)]
    _, summary = track_asterix(tmp_path, [two_radars], "kalman_cv", "--radar", str(tmp_path / "radars.parquet"))
    assert {r: v["plots"] for r, v in summary["radars"].items()} == {"775": 5, "776": 5}


def test_the_radar_options_error_figures_and_checks_apply_with_asterix_too(two_radars, tmp_path):
    """A described radar's own `sigma_range_m` sizes its plots' covariance (776 keeps params'); a
    description with an impossible value is refused naming the file and column, as for Parquet input."""
    params = tf.make_params()
    rows = [{"radar_id": 775, "latitude_deg": -33.9, "longitude_deg": 151.2, "height_m": 10.0,
             "sigma_range_m": 4 * params.radar.sigma_range_m},
            {"radar_id": 776, "latitude_deg": -33.4, "longitude_deg": 151.2, "height_m": 20.0, "sigma_range_m": None}]
    pq.write_table(pa.Table.from_pylist(rows), tmp_path / "radars.parquet")
    plots = read_asterix_plots([two_radars], DAY, params.radar, tmp_path / "radars.parquet")
    assert plots.radars[775].sigma_range_m == 4 * params.radar.sigma_range_m
    assert plots.radars[776].sigma_range_m == params.radar.sigma_range_m
    rows[1]["latitude_deg"] = 95.0
    pq.write_table(pa.Table.from_pylist(rows), tmp_path / "bad.parquet")
    with pytest.raises(InputError, match=r"bad.parquet.*latitude_deg.*95"):
        read_asterix_plots([two_radars], DAY, params.radar, tmp_path / "bad.parquet")


def test_no_radar_position_at_all_is_an_input_error(tmp_path):
    marker = changed(asterix_io.marker_items(RADAR, MIDNIGHT + 36000.0), i120=None)
    path = recording_of(tmp_path / "nowhere.ast", target(RADAR, 3), marker=marker)
    with pytest.raises(InputError, match=rf"{path}: no radar position: no CAT034 message carries I034/120 and no "
                                         r"--radar"):
        read_asterix_plots([path], DAY, tf.make_params().radar)


def test_an_invalid_date_is_a_usage_error_naming_option_and_value(capsys):
    """Case 15: argparse refuses it (exit 2) before anything is read."""
    with pytest.raises(SystemExit) as stop:
        cli.main(["track", "--asterix", "any.ast", "--date", "2026-13-01", "--out", "tracks.parquet"])
    assert stop.value.code == 2
    assert "argument --date: '2026-13-01' is not a date (YYYY-MM-DD)" in capsys.readouterr().err


# ----------------------------------------------------------------------------- the commands end to end

@pytest.fixture(scope="module")
def simulated(tmp_path_factory) -> dict:
    """routes -> simulate with one route per strategy; the test split's smallest scenario on its own."""
    folder = tmp_path_factory.mktemp("simulated")
    write_params(tiny_params_tree(1), folder / "params.yaml")
    for arguments in (["routes", "--out", str(folder / "routes")],
                      ["simulate", "--routes", str(folder / "routes"), "--out", str(folder / "simulated")]):
        assert cli.main([arguments[0], "--params", str(folder / "params.yaml"), *arguments[1:]]) == 0
    plots_path = folder / "simulated" / "test" / "plots.parquet"
    plots = io.read_parquet(plots_path, simulate.PLOT_SCHEMA)
    scenarios, sizes = np.unique(plots.column("scenario_id").to_numpy(), return_counts=True)
    scenario = int(scenarios[np.argmin(sizes)])
    own = plots.filter(pc.equal(plots.column("scenario_id"), scenario))
    pq.write_table(own, folder / "scenario.parquet")
    first = own.column("time_unix_s").to_numpy().min()
    return {"folder": folder, "plots": plots_path, "radar": folder / "simulated" / "test" / "radar.parquet",
            "scenario": scenario, "table": own, "scenario_plots": folder / "scenario.parquet",
            "date": datetime.fromtimestamp(first, timezone.utc).date().isoformat()}


@pytest.fixture(scope="module")
def models_dir(tmp_path_factory) -> Path:
    return tf.trained_models(tmp_path_factory)


@pytest.fixture(scope="module")
def exported(simulated, models_dir) -> dict:
    """`asterix-export` of the scenario, then `python -m pipeline track --asterix` on it in a fresh process."""
    folder = simulated["folder"]
    assert cli.main(["asterix-export", "--plots", str(simulated["plots"]), "--radar", str(simulated["radar"]),
                     "--scenario", str(simulated["scenario"]), "--out", str(folder / "scenario.ast")]) == 0
    track = run_pipeline("track", "--params", "params.yaml", "--asterix", "scenario.ast", "--date", simulated["date"],
                         "--models", str(models_dir), "--method", "via", "--window", "4000", "--out",
                         "asterix_tracks.parquet", cwd=folder)
    assert track.returncode == 0, track.stderr
    return {"ast": folder / "scenario.ast", "tracks": pq.read_table(folder / "asterix_tracks.parquet"),
            "log": track.stderr}


def test_exported_scenario_decodes_to_the_simulated_plots(simulated, exported):
    """Every plot of the scenario comes back, in time order, with its measurements and Unix time."""
    table = simulated["table"]
    order = np.argsort(table.column("time_unix_s").to_numpy(), kind="stable")
    expected = table.take(order)
    decoded, radars, _ = asterix_io.decode(exported["ast"], date.fromisoformat(simulated["date"]))
    assert decoded.num_rows == table.num_rows
    for name, step in (("time_unix_s", units.TIME_OF_DAY_STEP_S), ("range_m", units.RANGE_STEP_M),
                       ("azimuth_deg", units.AZIMUTH_STEP_DEG), ("flight_level", units.FLIGHT_LEVEL_STEP),
                       ("altitude_m", units.FLIGHT_LEVEL_STEP * 100 * units.FOOT_M)):
        np.testing.assert_allclose(decoded.column(name).to_numpy(), expected.column(name).to_numpy(), rtol=0.0,
                                   atol=step / 2, err_msg=name)
    radar = pq.read_table(simulated["radar"]).to_pylist()[0]
    assert radars.column("radar_id").to_pylist() == [radar["radar_id"]]


def test_track_asterix_end_to_end_gives_one_update_per_plot_like_the_parquet_scenario(simulated, exported,
                                                                                     models_dir):
    """`track --asterix` and `track --plots` on the same scenario: one update per plot in both (the
    same number of plots), and the same tracks, weights and associations; states agree to metres
    (the radar position in CAT034 is rounded to 180/2^23 deg, about 2 m)."""
    folder = simulated["folder"]
    code = cli.main(["track", "--params", str(folder / "params.yaml"), "--plots", str(simulated["scenario_plots"]),
                     "--radar", str(simulated["radar"]), "--models", str(models_dir), "--method", "via", "--window",
                     "4000", "--out", str(folder / "parquet_tracks.parquet")])
    assert code == 0
    parquet = pq.read_table(folder / "parquet_tracks.parquet")
    asterix = exported["tracks"]
    assert asterix.num_rows == parquet.num_rows == simulated["table"].num_rows
    assert "confirmed" in asterix.column("status").to_pylist()
    # ASTERIX plot ids number the decoded plots in time order.
    table = simulated["table"]
    by_time = table.column("plot_id").to_numpy()[np.argsort(table.column("time_unix_s").to_numpy(), kind="stable")]
    np.testing.assert_array_equal(by_time[asterix.column("plot_id").to_numpy()], parquet.column("plot_id").to_numpy())
    for name in ("track_id", "association", "status", "radar_id"):
        assert asterix.column(name).to_pylist() == parquet.column(name).to_pylist(), name
    np.testing.assert_allclose(asterix.column("weight").to_numpy(), parquet.column("weight").to_numpy(), atol=1e-12)
    np.testing.assert_allclose(asterix.column("time_unix_s").to_numpy(), parquet.column("time_unix_s").to_numpy(),
                               rtol=0.0, atol=1e-3)
    for axis in "xyz":
        np.testing.assert_allclose(asterix.column(f"{axis}_ecef_m").to_numpy(),
                                   parquet.column(f"{axis}_ecef_m").to_numpy(), rtol=0.0, atol=20.0)
    assert asterix.column("scenario_id").null_count == asterix.num_rows
    assert set(parquet.column("scenario_id").to_pylist()) == {simulated["scenario"]}


def test_track_asterix_without_date_exits_2_naming_the_option(simulated, exported, models_dir, tmp_path, caplog):
    out = tmp_path / "tracks.parquet"
    code = cli.main(["track", "--params", str(simulated["folder"] / "params.yaml"), "--asterix", str(exported["ast"]),
                     "--models", str(models_dir), "--out", str(out)])
    assert code == 2
    assert "--date" in caplog.text
    assert not out.exists()


def test_track_asterix_on_a_damaged_file_exits_2_naming_it(simulated, exported, models_dir, tmp_path, caplog):
    damaged = write(tmp_path / "damaged.ast", exported["ast"].read_bytes()[:-7])
    out = tmp_path / "tracks.parquet"
    code = cli.main(["track", "--params", str(simulated["folder"] / "params.yaml"), "--asterix", str(damaged),
                     "--date", simulated["date"], "--models", str(models_dir), "--out", str(out)])
    assert code == 2
    assert f"{damaged}: truncated" in caplog.text
    assert not out.exists()


def test_export_of_a_missing_scenario_is_named(simulated, tmp_path, caplog):
    out = tmp_path / "none.ast"
    code = cli.main(["asterix-export", "--plots", str(simulated["plots"]), "--radar", str(simulated["radar"]),
                     "--scenario", "999", "--out", str(out)])
    assert code == 2
    assert "no plots of scenario 999" in caplog.text
    assert not out.exists()

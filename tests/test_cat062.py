"""CAT062 system tracks out (`pipeline.surveillance.cat062`): what `track --cat062` writes decodes, field by
field, with an independent decoder (asterix4py, CroatiaControl's XML definitions, not the asterix-specs ones
libasterix is generated from), and reads back through our own reader."""

from __future__ import annotations

import logging
from datetime import date, datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from asterix4py import AsterixParser

from pipeline.geometry import geodesy
from pipeline.geometry.asterix_units import FOOT_M
from pipeline.io import InputError
from pipeline.surveillance import cat062
from pipeline.tracker.recording import TRACK_SCHEMA, covariance_columns, velocity_columns

MIDNIGHT = datetime(2026, 6, 1, tzinfo=timezone.utc).timestamp()
REFERENCE = cat062.SystemReference(52.0, 4.0)


def track_table(tracks: dict[int, tuple[float, float]], times: np.ndarray, status: list[str] | None = None,
                velocity: bool = True) -> pa.Table:
    """Updates (TRACK_SCHEMA) of straight tracks at FL 330, each given as track id -> its (east, north)
    start offset from REFERENCE in metres, flying east at 200 m/s and climbing at 5 m/s, one update per
    time; position sigmas 60 m (east), 80 m (north), 30 m (up); velocity sigmas 4, 6 and 2 m/s."""
    rows = []
    for track_id, (east, north) in tracks.items():
        for k, t in enumerate(times):
            rows.append((track_id, t, east + 200.0 * (t - times[0]), north, 10058.4 + 5.0 * (t - times[0]),
                         status[k] if status else "confirmed"))
    rows.sort(key=lambda row: row[1])
    track_id, time, east, north, up, states = (np.array(column) for column in zip(*rows))
    rotation = geodesy.enu_rotation(REFERENCE.latitude_deg, REFERENCE.longitude_deg)
    origin = geodesy.geodetic_to_ecef(REFERENCE.latitude_deg, REFERENCE.longitude_deg, 0.0)
    ecef = origin + np.stack([east, north, up], axis=1) @ rotation  # a flat-earth offset: any position will do
    latitude, longitude, altitude = geodesy.ecef_to_geodetic(ecef)
    enu = geodesy.enu_rotations(latitude, longitude)
    count = len(time)
    position_cov = enu.transpose(0, 2, 1) @ np.diag([60.0 ** 2, 80.0 ** 2, 30.0 ** 2]) @ enu
    velocity_ecef = np.einsum("uji,uj->ui", enu, np.tile([200.0, 0.0, 5.0], (count, 1)))
    velocity_cov = enu.transpose(0, 2, 1) @ np.diag([4.0 ** 2, 6.0 ** 2, 2.0 ** 2]) @ enu
    if not velocity:
        velocity_ecef, velocity_cov = np.full((count, 3), np.nan), np.full((count, 3, 3), np.nan)
    columns = {
        "radar_id": pa.array(np.ones(count, np.int32)), "scenario_id": pa.array(np.zeros(count, np.int32)),
        "track_id": pa.array(track_id.astype(np.int64)), "time_unix_s": pa.array(time.astype(float)),
        "plot_id": pa.array(np.arange(count, dtype=np.int64)),
        "x_ecef_m": pa.array(ecef[:, 0]), "y_ecef_m": pa.array(ecef[:, 1]), "z_ecef_m": pa.array(ecef[:, 2]),
        "latitude_deg": pa.array(latitude), "longitude_deg": pa.array(longitude), "altitude_m": pa.array(altitude),
        "range_m": pa.array(np.full(count, 50e3)), "weight": pa.array(np.ones(count)),
        "status": pa.array(states.astype(str)), "association": pa.array(["nearest"] * count),
        "association_error": pa.array(np.zeros(count)),
        **covariance_columns(position_cov),
        **velocity_columns(velocity_ecef, latitude, longitude),
        **covariance_columns(velocity_cov, TRACK_SCHEMA.names[-6:]),
    }
    return pa.table({name: columns[name] for name in TRACK_SCHEMA.names}, schema=TRACK_SCHEMA)


def decoded(path: Path) -> list[dict]:
    return list(AsterixParser(path.read_bytes()).get_result().values())


def test_every_item_decodes_with_an_independent_decoder_as_written(tmp_path: Path) -> None:
    times = MIDNIGHT + 36000.0 + 4.0 * np.arange(5)
    table = track_table({7: (10e3, -20e3), 9: (-30e3, 5e3)}, times,
                        status=["tentative", "confirmed", "confirmed", "confirmed", "confirmed"])
    out = tmp_path / "tracks.ast"
    assert cat062.write_cat062(table, out, sac=25, sic=3, reference=REFERENCE) == 10
    records = decoded(out)
    assert len(records) == 10
    first, last = records[0], records[-1]
    assert all(r["cat"] == 62 and r["010"] == {"SAC": 25, "SIC": 3} and r["015"] == {"SID": 1} for r in records)
    assert [r["070"]["ToT"] for r in records] == pytest.approx(np.repeat(times - MIDNIGHT, 2), abs=1 / 256)
    assert [r["040"]["TrkN"] for r in records] == [1, 2] * 5  # numbered in order of first update
    assert [r["080"]["CNF"] for r in records] == [1, 1] + [0] * 8
    assert [r["080"]["TSB"] for r in records] == [1, 1] + [0] * 8
    assert [r["080"]["TSE"] for r in records] == [0] * 8 + [1, 1]
    assert first["080"]["MON"] == 1 and first["080"]["SRC"] == 0
    assert [r["290"]["TRK"] for r in records] == pytest.approx(np.repeat(times - times[0], 2))
    # I062/105 and /135 carry the track's own position and altitude, to the LSB
    latitude, longitude = table.column("latitude_deg").to_numpy(), table.column("longitude_deg").to_numpy()
    assert [r["105"]["Lat"] for r in records] == pytest.approx(latitude, abs=180 / 2 ** 26)
    assert [r["105"]["Lon"] for r in records] == pytest.approx(longitude, abs=180 / 2 ** 26)
    altitude_ft = table.column("altitude_m").to_numpy() / FOOT_M
    assert [r["135"]["CTBA"] for r in records] == pytest.approx(altitude_ft, abs=12.5)
    # I062/100 is the stereographic plane about the reference: a track 10 km east, 20 km south of it, seen from
    # the earth's centre at 10 km up (so 10 / 6381 nearer on the ground)
    ground = 6381e3 / (6381e3 + 10058.4)
    assert first["100"]["X"] == pytest.approx(10e3 * ground, abs=5.0)
    assert first["100"]["Y"] == pytest.approx(-20e3 * ground, abs=5.0)
    # velocity 200 m/s east in the plane (the plane's north turns from true north by under a degree here)
    assert np.hypot(first["185"]["Vx"], first["185"]["Vy"]) == pytest.approx(200.0, abs=0.5)
    assert first["185"]["Vx"] == pytest.approx(200.0, abs=3.0)
    assert first["220"]["RoC"] == pytest.approx(5.0 / FOOT_M * 60.0, abs=6.25)
    accuracy = first["500"]
    assert accuracy["APC_X"] == pytest.approx(60.0, abs=1.5) and accuracy["APC_Y"] == pytest.approx(80.0, abs=1.5)
    assert accuracy["ATV_X"] == pytest.approx(4.0, abs=0.25) and accuracy["ATV_Y"] == pytest.approx(6.0, abs=0.25)
    assert accuracy["ARC_Acc"] == pytest.approx(2.0 / FOOT_M * 60.0, abs=6.25)
    # APW and ABA: asterix4py's definitions scale them by 180/2^23 deg and 6.25 ft, where CAT062 ed. 1.20
    # (asterix-specs) gives 180/2^25 deg and 1/4 FL: the raw values are compared
    assert accuracy["APW_Lat"] / (180 / 2 ** 23) * (180 / 2 ** 25) == pytest.approx(
        np.degrees(80.0 / 6391e3), rel=0.02)
    assert accuracy["ABA_Acc"] / 6.25 * 0.25 == pytest.approx(30.0 / FOOT_M / 100.0, abs=0.25)
    assert last["080"]["TSE"] == 1


def test_libasterix_decodes_every_record_and_encodes_it_to_the_same_bytes(tmp_path: Path) -> None:
    """The records are encoded here (for speed); libasterix, generated from the asterix-specs definitions of
    CAT062 ed. 1.20, parses each with nothing left over and unparses it to the same bytes, with and without
    velocities and covariances, and with accuracies wider than their one-octet fields."""
    import asterix.base as base

    codec = cat062._codec()
    times = MIDNIGHT + 50000.0 + 4.0 * np.arange(4)
    tables = [track_table({1: (5e3, 7e3), 2: (-80e3, 120e3)}, times), track_table({3: (1e3, 2e3)}, times, velocity=False)]
    wide = track_table({4: (0.0, 0.0)}, times)
    for axis in ("xx", "yy", "zz"):  # 100 m/s in every direction
        name = f"velocity_covariance_{axis}_m2_s2"
        wide = wide.set_column(wide.schema.get_field_index(name), name, pa.array(np.full(4, 100.0 ** 2)))
    tables.append(wide)
    for table in tables:
        for record in cat062.records(table, 7, 8, REFERENCE):
            block = base.RawDatablock.parse(base.Bits.from_bytes(bytes([62]) + (3 + len(record)).to_bytes(2, "big")
                                                                 + record))
            parsed = codec.cv_uap.parse(block[0].get_raw_records())
            assert not isinstance(parsed, ValueError), parsed
            assert len(parsed) == 1 and parsed[0].unparse().to_bytes() == record
    assert decoded(_written(tmp_path, tables[2]))[0]["500"]["ATV_X"] == 63.75  # 100 m/s: the octet's largest


def _written(tmp_path: Path, table: pa.Table) -> Path:
    path = tmp_path / "written.ast"
    cat062.write_cat062(table, path, 1, 2, REFERENCE)
    return path


def test_the_reader_gives_back_what_was_written(tmp_path: Path) -> None:
    times = MIDNIGHT + 86390.0 + 4.0 * np.arange(6)  # through midnight
    table = track_table({3: (0.0, 0.0)}, times, velocity=False)
    out = tmp_path / "tracks.ast"
    cat062.write_cat062(table, out, sac=1, sic=2, reference=REFERENCE)
    read = cat062.read_cat062(out, date(2026, 6, 1)).to_pydict()
    assert read["time_unix_s"] == pytest.approx(times, abs=1 / 256)
    assert read["track_id"] == [0] * 6 and read["track_number"] == [1] * 6 and all(read["confirmed"])
    assert read["latitude_deg"] == pytest.approx(table.column("latitude_deg").to_numpy(), abs=180 / 2 ** 26)
    assert read["altitude_m"] == pytest.approx(table.column("altitude_m").to_numpy(), abs=4.0)
    assert np.isnan(read["vx_plane_mps"]).all()  # no velocity given, none written
    assert "185" not in decoded(out)[0] and "500" in decoded(out)[0]


def test_a_reused_track_number_after_its_end_is_a_new_track(tmp_path: Path) -> None:
    first = track_table({1: (0.0, 0.0)}, MIDNIGHT + 100.0 + 4.0 * np.arange(3))
    blocks = cat062.encode(first, 1, 2, REFERENCE) * 2  # the same track number, begun and ended twice
    path = tmp_path / "twice.ast"
    path.write_bytes(blocks)
    assert cat062.read_cat062(path, date(2026, 6, 1)).column("track_id").to_pylist() == [0, 0, 0, 1, 1, 1]


def test_other_categories_and_missing_items_are_named(tmp_path: Path) -> None:
    from pipeline.recordings import asterix_io

    radar = {"sac": 1, "sic": 2, "scan_period_s": 4.0, "height_m": 10.0, "latitude_deg": 52.0, "longitude_deg": 4.0}
    plots = tmp_path / "plots.ast"
    plots.write_bytes(asterix_io.datablock(34, [asterix_io.marker_items(radar, MIDNIGHT + 10.0)]))
    with pytest.raises(InputError, match=r"plots.ast: datablock 0 at byte 0 is CAT034"):
        cat062.read_cat062(plots, date(2026, 6, 1))
    first, second = cat062.records(track_table({1: (0.0, 0.0)}, MIDNIGHT + np.arange(2.0)), 1, 2, REFERENCE)
    fspec = 4 if second[2] & 1 else 3
    second = bytes([second[0] & ~0x10]) + second[1:fspec + 3] + second[fspec + 6:]  # I062/070's bit and bytes out
    timeless = tmp_path / "timeless.ast"
    timeless.write_bytes(bytes([62]) + (3 + len(first) + len(second)).to_bytes(2, "big") + first + second)
    with pytest.raises(InputError, match=r"timeless.ast: datablock 0 at byte 0, record 1: item I062/070 missing"):
        cat062.read_cat062(timeless, date(2026, 6, 1))
    with pytest.raises(InputError, match="SAC 300 is not a byte"):
        cat062.write_cat062(track_table({1: (0.0, 0.0)}, MIDNIGHT + np.arange(2.0)), tmp_path / "x.ast", 300, 1,
                            REFERENCE)
    assert not (tmp_path / "x.ast").exists()


def test_track_writes_its_updates_as_cat062_beside_the_table(tmp_path: Path) -> None:
    """`track --cat062` on a two-radar recording: one record per update written, the same tracks (numbers in
    order of first update), the same confirmed updates and positions to the LSB; MON = 0 (two radars)."""
    from pipeline import cli
    from tests import tracker_fixtures as tf
    from tests.project import write_params
    from tests.test_track_command import two_radar_recording

    params = tf.make_params()
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(2))
    plots_path, radar_path = tf.write_recording(tmp_path / "recording", plots, radars)
    models = tf.write_tuned_filters(tmp_path / "models", params)
    arguments = ["track", "--params", str(write_params(tf.params_tree(None), tmp_path / "params.yaml")),
                 "--plots", str(plots_path), "--radar", str(radar_path), "--models", str(models),
                 "--out", str(tmp_path / "tracks.parquet"), "--cat062", str(tmp_path / "tracks.ast"), "--sac", "9"]
    assert cli.main(arguments) == 0
    table = pa.parquet.read_table(tmp_path / "tracks.parquet")
    records = decoded(tmp_path / "tracks.ast")
    assert len(records) == table.num_rows > 0
    assert {r["010"]["SAC"] for r in records} == {9} and {r["080"]["MON"] for r in records} == {0}
    read = cat062.read_cat062(tmp_path / "tracks.ast", datetime.fromtimestamp(
        table.column("time_unix_s")[0].as_py(), timezone.utc).date())
    order = np.argsort(table.column("time_unix_s").to_numpy(), kind="stable")
    assert read.column("time_unix_s").to_numpy() == pytest.approx(table.column("time_unix_s").to_numpy()[order],
                                                                  abs=1 / 256)
    assert read.column("confirmed").to_pylist() == (table.column("status").to_numpy()[order] == "confirmed").tolist()
    assert read.column("latitude_deg").to_numpy() == pytest.approx(table.column("latitude_deg").to_numpy()[order],
                                                                   abs=180 / 2 ** 26)
    assert len(set(read.column("track_id").to_pylist())) == len(set(table.column("track_id").to_pylist()))
    arguments[arguments.index("--sac") + 1] = "256"
    (tmp_path / "tracks.ast").unlink()
    assert cli.main(arguments) == 2 and not (tmp_path / "tracks.ast").exists()


def test_score_of_a_cat062_file_equals_score_of_the_same_tracks_as_our_table(tmp_path: Path) -> None:
    """Tracks made by hand around a truth: `score --tracks` and `score --cat062` of what `write_cat062` made of
    the same table give the same scorecard, to CAT062's resolution (0.6 m in position, 0.25 m/s in velocity)."""
    import json

    from pipeline import cli
    from tests import tracker_fixtures as tf
    from tests.project import write_params

    times = MIDNIGHT + 36000.0 + 6.0 * np.arange(40)
    truth_table = track_table({0: (0.0, 0.0)}, times)
    table = track_table({1: (2400.0, 150.0)}, times[2:], status=["tentative"] + ["confirmed"] * 37)  # from scan 2
    truth = pa.table({"target_id": pa.array(np.zeros(len(times), np.int32)),
                      "time_unix_s": truth_table.column("time_unix_s"), "x_ecef_m": truth_table.column("x_ecef_m"),
                      "y_ecef_m": truth_table.column("y_ecef_m"), "z_ecef_m": truth_table.column("z_ecef_m")})
    pa.parquet.write_table(truth, tmp_path / "truth.parquet")
    pa.parquet.write_table(table, tmp_path / "tracks.parquet")
    cat062.write_cat062(table, tmp_path / "tracks.ast", 1, 2, REFERENCE)
    params = str(write_params(tf.params_tree(None), tmp_path / "params.yaml"))
    common = ["score", "--params", params, "--truth", str(tmp_path / "truth.parquet"), "--update-interval", "6"]
    assert cli.main([*common, "--tracks", str(tmp_path / "tracks.parquet"), "--out", str(tmp_path / "a.json")]) == 0
    assert cli.main([*common, "--cat062", str(tmp_path / "tracks.ast"), "--date", "2026-06-01", "--reference", "52",
                     "4", "--out", str(tmp_path / "b.json")]) == 0
    a, b = (json.loads((tmp_path / name).read_text())["scorecard"] for name in ("a.json", "b.json"))
    assert a.keys() == b.keys()
    for name in a:
        assert b[name] == pytest.approx(a[name], abs=1.0, nan_ok=True), name
    assert a["across_track_rms_m"] == pytest.approx(150.0, abs=1.0) and a["initiation_mean_s"] == 18.0
    assert "| single-radar | position_error_mean_m | 150 | <= 240.8 | pass |" in (tmp_path / "a.md").read_text()


def test_score_refuses_the_wrong_day_and_a_truth_without_its_columns(tmp_path: Path, caplog) -> None:
    from pipeline import cli
    from tests import tracker_fixtures as tf
    from tests.project import write_params

    times = MIDNIGHT + 36000.0 + 6.0 * np.arange(10)
    table = track_table({1: (0.0, 0.0)}, times)
    cat062.write_cat062(table, tmp_path / "tracks.ast", 1, 2, REFERENCE)
    truth = pa.table({"target_id": pa.array(np.zeros(10, np.int32)), "time_unix_s": table.column("time_unix_s"),
                      "x_ecef_m": table.column("x_ecef_m"), "y_ecef_m": table.column("y_ecef_m"),
                      "z_ecef_m": table.column("z_ecef_m")})
    pa.parquet.write_table(truth, tmp_path / "truth.parquet")
    pa.parquet.write_table(truth.drop(["z_ecef_m"]), tmp_path / "flat.parquet")
    params = str(write_params(tf.params_tree(None), tmp_path / "params.yaml"))
    common = ["score", "--params", params, "--cat062", str(tmp_path / "tracks.ast"), "--out", str(tmp_path / "s.json")]
    with caplog.at_level(logging.ERROR):
        assert cli.main([*common, "--date", "2026-06-02", "--truth", str(tmp_path / "truth.parquet")]) == 2
        assert cli.main([*common, "--date", "2026-06-01", "--truth", str(tmp_path / "flat.parquet")]) == 2
    assert "no confirmed update within the time of" in caplog.text and "another day (--date)" in caplog.text
    assert "flat.parquet" in caplog.text and "z_ecef_m" in caplog.text
    assert not (tmp_path / "s.json").exists() and not (tmp_path / "s.md").exists()

"""ASTERIX CAT048 plots and CAT034 north markers: the round trip, the clock across midnight, damaged
files, and `track --asterix` / `asterix-export` end to end on a simulated scenario.

Hand-made plots are quantised with pipeline.asterix_units first, as the simulator quantises its
plots, so what is encoded is exactly representable and the decoded values must agree to the
resolution of each item.
"""

from __future__ import annotations

from datetime import date, datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from pipeline import asterix_io, asterix_units as units, cli, io, simulate
from pipeline.io import InputError
from pipeline.plot_table import read_asterix_plots
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
    decoded, radars = asterix_io.decode(path, DAY)
    assert decoded.num_rows == plots.num_rows
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
    _, radars = asterix_io.decode(recording[1], DAY)
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
    decoded, _ = asterix_io.decode(path, DAY)
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
    decoded, radars = asterix_io.decode(exported["ast"], date.fromisoformat(simulated["date"]))
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

"""`track` with what a method needs and nothing else, and recordings of several radars.

No trained networks here: the classical methods need only the tuned filters, so a models folder
holding just `kalman_tuned.json` (the filters at params' start values, written as the tune stage
writes them) is a checkout that has run `dvc repro tune_kalman` and no training.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline import cli, io
from pipeline.association import association_net, track_tables
from pipeline.bench import association_report
from pipeline.filters import classical_filters
from pipeline.geometry import geodesy
from pipeline.learning import experiment_tracking, model_store
from pipeline.recordings import external_sort, plot_table, streamed_recording
from pipeline.stages import track_command as track_command_module
from pipeline.tracker import recording, registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.recording import TRACK_SCHEMA, track_recording
from tests import tracker_fixtures as tf
from tests.project import write_params

SECOND_SITE = (61.2, 23.1, 120.0)  # a second radar about 120 km from the default one


@pytest.fixture(scope="module")
def params():
    return tf.make_params()


@pytest.fixture()
def filters_only(tmp_path: Path, params) -> Path:
    """A models folder with the tuned filters only."""
    return tf.write_tuned_filters(tmp_path / "models", params)


def two_radar_recording(params, rng: np.random.Generator) -> tuple[pa.Table, pa.Table, np.ndarray]:
    """A straight target between two radars, seen by both (radar 1 at the default site, radar 2 at
    SECOND_SITE, their scans 3 s apart), with each radar's clutter: the plots (PLOT_INPUT_SCHEMA,
    exact measurements from each plot's own radar), the radar description, and the target's plot ids."""
    radars = {1: params.radar, 2: tf.radar_at(params.radar, *SECOND_SITE)}
    tables, target_ids = [], []
    velocity = np.array([180.0, 90.0, 0.0])
    for radar_id, offset in ((1, 0.0), (2, 3.0)):
        radar = radars[radar_id]
        start = np.array([40e3, 60e3, 9000.0]) + velocity * offset
        target = tf.straight_features(params.radar, tuple(start), tuple(velocity), 25, t_offset=offset)
        clutter = tf.clutter_features(radar, 25, 4.0, rng, half_width_m=150000.0)
        clutter[:, 0] += offset
        ids = 1000 * radar_id + np.arange(len(target) + len(clutter))
        features, plot_ids = tf.merge((target, ids[:len(target)]), (clutter, ids[len(target):]))
        tables.append(tf.measurement_table(features, plot_ids, radar, radar_id, scenario_id=7))
        target_ids.extend(ids[:len(target)].tolist())
    description = pa.concat_tables([tf.radar_table(radar_id, radar) for radar_id, radar in radars.items()])
    return pa.concat_tables(tables), description, np.array(target_ids)


def track_command(folder: Path, models: Path, method: str, plots: pa.Table, radars: pa.Table,
                  changes: dict | None = None) -> int:
    """`python -m pipeline track` on the recording, written with default params (but `changes`) in
    `folder`; the output goes to folder / "tracks.parquet"."""
    plots_path, radar_path = tf.write_recording(folder / "recording", plots, radars)
    params_path = write_params(tf.params_tree(changes), folder / "params.yaml")
    return cli.main(["track", "--params", str(params_path), "--plots", str(plots_path), "--radar", str(radar_path),
                     "--models", str(models), "--method", method, "--out", str(folder / "tracks.parquet")])


def test_two_radars_plots_each_carry_their_own_radars_covariance(params, tmp_path):
    """Plots of two radars in one recording: each is placed from its own radar's site (within the
    thesis conversion's error of the true position) and gets its own radar's converted-measurement
    covariance, which differs from the other radar's at the same place."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(1))
    table = plot_table.read_parquet_plots(*tf.write_recording(tmp_path, plots, radars), params.radar)
    assert set(table.radar_id.tolist()) == {1, 2} and len(table) == plots.num_rows
    assert (np.diff(table.time) >= 0).all()
    sites = {1: params.radar, 2: tf.radar_at(params.radar, *SECOND_SITE)}
    for radar_id, radar in sites.items():
        own = table.radar_id == radar_id
        other = sites[3 - radar_id]
        np.testing.assert_allclose(table.covariance[own], geodesy.measurement_covariance(table.position[own], radar),
                                   rtol=1e-12)
        assert not np.allclose(table.covariance[own], geodesy.measurement_covariance(table.position[own], other),
                               rtol=1e-3)
        slant, _, _ = geodesy.true_measurement(table.position[own], radar)
        np.testing.assert_allclose(slant, table.range_m[own], atol=30.0)


def test_imm_tracks_a_two_radar_recording_with_only_the_tuned_filters(params, tmp_path, filters_only):
    """`track --method imm` in a checkout with only models/kalman_tuned.json: exit 0; the target's plots
    of both radars form one confirmed track; each row carries its plot's radar and the range from it."""
    plots, radars, target_ids = two_radar_recording(params, np.random.default_rng(2))
    assert track_command(tmp_path, filters_only, "imm", plots, radars) == 0
    assert sorted(p.name for p in filters_only.iterdir()) == ["kalman_tuned.json"]
    tracks = pq.read_table(tmp_path / "tracks.parquet").to_pydict()
    target = np.isin(tracks["plot_id"], target_ids)
    assert len(set(np.asarray(tracks["track_id"])[target].tolist())) == 1
    assert {radar_id for radar_id, is_target in zip(tracks["radar_id"], target) if is_target} == {1, 2}
    assert np.asarray(tracks["status"])[target].tolist()[3:] == ["confirmed"] * (target.sum() - 3)
    confirmed = np.asarray(tracks["status"]) == "confirmed"
    assert target[confirmed].all()
    by_radar = {1: params.radar, 2: tf.radar_at(params.radar, *SECOND_SITE)}
    position = np.column_stack([tracks[f"{a}_ecef_m"] for a in "xyz"])
    site = np.array([geodesy.radar_site_ecef(by_radar[r]) for r in tracks["radar_id"]])
    np.testing.assert_allclose(tracks["range_m"], np.linalg.norm(position - site, axis=1), rtol=1e-12)


def test_two_missed_scans_end_a_young_track_under_the_thesis_rule_and_not_under_m_of_n_or_the_sprt(
        params, tmp_path, filters_only):
    """A straight target seen 3 scans, missed 2 (plots dropped, say for a garbled Mode C), seen 5 more:
    the thesis's rule deletes the candidate track at its first silence, so the target gets a second
    track; `--management m_of_n` keeps one track through all 8 plots (shared/cases 04), and so does
    `--management sprt`, which confirms at the third plot and deletes a confirmed track at its fifth miss."""
    features = np.delete(tf.straight_features(params.radar, (20e3, 25e3, 10668.0), (200.0, 0.0, 0.0), 10), [3, 4],
                         axis=0)
    plots = tf.measurement_table(features, np.arange(len(features)), params.radar, 1)
    recording = tf.write_recording(tmp_path / "recording", plots, tf.radar_table(1, params.radar))
    tracks = {}
    for rule in ("thesis", "m_of_n", "sprt"):
        out = tmp_path / f"{rule}.parquet"
        assert cli.main(["track", "--plots", str(recording[0]), "--radar", str(recording[1]), "--models",
                         str(filters_only), "--method", "kalman_cv", "--management", rule, "--out", str(out)]) == 0
        tracks[rule] = pq.read_table(out).to_pydict()
    assert tracks["thesis"]["track_id"] == [0, 0, 0, 1, 1, 1, 1, 1]
    assert tracks["m_of_n"]["track_id"] == [0] * 8
    assert tracks["m_of_n"]["status"][-1] == "confirmed"
    assert tracks["sprt"]["track_id"] == [0] * 8
    assert tracks["sprt"]["status"] == ["tentative", "tentative"] + ["confirmed"] * 6


def test_the_summary_counts_tracks_per_radar_as_scenario_and_track_id(params, tmp_path, filters_only):
    """Track ids are only unique within a scenario: the same target seen by two radars tracked
    apart (each radar in its own scenario, so both start at track 0) is one confirmed track per radar,
    two in all, in `tracks.summary.json` beside the output."""
    plots, radars, target_ids = two_radar_recording(params, np.random.default_rng(2))
    scenario = pa.array(plots.column("radar_id").to_numpy().astype(np.int32))
    plots = plots.set_column(plots.schema.get_field_index("scenario_id"), "scenario_id", scenario)
    assert track_command(tmp_path, filters_only, "imm", plots, radars) == 0
    summary = json.loads((tmp_path / "tracks.summary.json").read_text())
    tracks = pq.read_table(tmp_path / "tracks.parquet").to_pydict()
    confirmed = np.asarray(tracks["status"]) == "confirmed"
    assert set(np.asarray(tracks["track_id"])[confirmed].tolist()) == {0}
    assert summary["confirmed_tracks"] == 2
    assert summary["radars"] == {str(r): {"plots": int((plots.column("radar_id").to_numpy() == r).sum()),
                                          "confirmed_tracks": 1} for r in (1, 2)}
    assert summary["plots_tracked"] == plots.num_rows and summary["skipped"] == {}


def test_a_track_fed_by_two_radars_counts_once_in_the_summary_and_once_per_radar(params, tmp_path, filters_only):
    """Both radars in one scenario are tracked together: the target is one confirmed track holding
    plots of both, so the summary counts 1 track in all and 1 for each radar."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(2))
    assert track_command(tmp_path, filters_only, "imm", plots, radars) == 0
    summary = json.loads((tmp_path / "tracks.summary.json").read_text())
    assert summary["confirmed_tracks"] == 1
    assert {r: v["confirmed_tracks"] for r, v in summary["radars"].items()} == {"1": 1, "2": 1}


@pytest.mark.parametrize("method, missing, stage", [("via", "filter.pt", "train_filter"),
                                                    ("ae", "autoencoder.pt", "train_autoencoder")])
def test_a_method_whose_model_is_missing_names_the_file_and_stage(params, tmp_path, filters_only, caplog, method,
                                                                 missing, stage):
    """A neural method in the same checkout: exit 2, the missing model file and the `dvc repro` stage
    that makes it named, no output."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(3))
    assert track_command(tmp_path, filters_only, method, plots, radars) == 2
    assert f"{filters_only / missing}: file not found" in caplog.text and f"dvc repro {stage}" in caplog.text
    assert not (tmp_path / "tracks.parquet").exists()


def association_weights(params) -> dict:
    """An association network's config and weights (untrained): a saved network, but not of the tracker's kinds."""
    model = association_net.AssociationNet(association_report.network_config(params.association))
    return {"config": dataclasses.asdict(model.config), "state_dict": model.state_dict()}


@pytest.mark.parametrize("damage", ["truncated", "another network", "no weights"])
@pytest.mark.parametrize("load, file, stage", [
    (lambda folder, params: load_models(folder, params, ["lstm_update"]), "lstm_update.pt", "train_lstm_update"),
    (lambda folder, params: load_models(folder, params, ["kalman_net"]), "kalman_net.pt", "train_kalman_net"),
    (lambda folder, params: association_net.load(folder / "association_net.pt"), "association_net.pt",
     "train_association"),
])
def test_a_damaged_or_foreign_network_file_names_the_file_and_stage(params, tmp_path, load, file, stage, damage):
    """A network file cut short (a copy interrupted), holding another network (files swapped by hand), or a
    config without weights: an InputError (exit 2) naming the file, never a torch traceback."""
    bundle = association_weights(params)
    if file == "association_net.pt" and damage == "another network":
        bundle = {"config": {"base": "cv", "cell": "gru"}, "state_dict": {}}  # a network-scaled filter's config
    model_store.write_bundle({"config": bundle["config"]} if damage == "no weights" else bundle, tmp_path / file)
    if damage == "truncated":
        (tmp_path / file).write_bytes((tmp_path / file).read_bytes()[:300])
    with pytest.raises(io.InputError) as error:
        load(tmp_path, params)
    assert str(error.value).startswith(f"{tmp_path / file}: ")
    assert damage == "truncated" or f"dvc repro {stage}" in str(error.value)


def test_a_classical_method_without_tuned_filters_names_the_file_and_stage(params, tmp_path):
    with pytest.raises(io.InputError, match=r"kalman_tuned.json: file not found; imm_gnn needs it .*"
                                            r"dvc repro tune_kalman"):
        load_models(tmp_path, params, ["imm_gnn"])


def test_a_method_whose_filter_kalman_filters_left_out_names_the_knob(params, tmp_path):
    """imm_ca_ct is not tuned by default (kalman.filters): its method is refused before tracking, saying how."""
    tuned = {kind: classical_filters.FilterSettings(kind, (1.0,) * classical_filters.NOISE_VALUES[kind], 100.0, 10.0,
                                                    0.05, 0.9, 3.0 if kind in classical_filters.TURNING_KINDS else 0.0
                                                    ).to_dict() for kind in ("cv", "ca", "imm", "imm_ct")}
    (tmp_path / "kalman_tuned.json").write_text(json.dumps({"filters": tuned}))
    assert load_models(tmp_path, params, ["imm_ct_gnn"])
    with pytest.raises(io.InputError, match=r"kalman_tuned.json: has no tuned imm_ca_ct filter, which imm_ca_ct_gnn "
                                            r"runs \(list imm_ca_ct in kalman.filters and run `dvc repro tune_kalman`\)"):
        load_models(tmp_path, params, ["imm_ca_ct_gnn"])


def test_an_unknown_method_names_the_registered_ones(params, tmp_path):
    with pytest.raises(registry.UnknownMethod, match="'kalman_xy'.*'via'.*'imm_gnn'.*'oracle'"):
        load_models(tmp_path, params, ["kalman_xy"])


def test_plots_of_an_undescribed_radar_name_the_radar_id(params, tmp_path):
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(4))
    only_first = radars.filter(pa.compute.equal(radars.column("radar_id"), 1))
    plots_path, radar_path = tf.write_recording(tmp_path, plots, only_first)
    with pytest.raises(io.InputError, match=r"plots from radar id 2 .*it has \[1\]") as error:
        plot_table.read_parquet_plots(plots_path, radar_path, params.radar)
    assert str(plots_path) in str(error.value)


# ----------------------------------------------------------------------------- what a Parquet recording must hold

def with_column(table: pa.Table, column: str, values: np.ndarray) -> pa.Table:
    """`table` with `column` replaced by `values` (same field)."""
    index = table.schema.get_field_index(column)
    return table.set_column(index, table.schema.field(index), pa.array(values, table.schema.field(index).type))


def with_values(table: pa.Table, column: str, rows: list[int], value: float) -> pa.Table:
    """`table` with `column` set to `value` at `rows`."""
    values = table.column(column).to_numpy(zero_copy_only=False).copy()
    values[rows] = value
    return with_column(table, column, values)


def with_radar_column(radars: pa.Table, column: str, values: list[float | None]) -> pa.Table:
    """The radar description with an extra (or replaced) float column."""
    if column in radars.column_names:
        radars = radars.drop_columns([column])
    return radars.append_column(pa.field(column, pa.float64()), pa.array(values, pa.float64()))


@pytest.mark.parametrize("column, value", [
    ("range_m", 0.0), ("range_m", -30000.0), ("range_m", np.inf), ("range_m", 3e6),
    ("azimuth_deg", 360.0), ("azimuth_deg", -0.5), ("azimuth_deg", np.inf),
    ("altitude_m", np.inf), ("altitude_m", -np.inf), ("altitude_m", -2000.0), ("altitude_m", 2e5),
    ("time_unix_s", np.inf), ("time_unix_s", -1.0), ("time_unix_s", 8e9),
])
def test_an_impossible_plot_value_names_the_file_column_first_row_value_and_count(params, tmp_path, column, value):
    """Rows 5 and 9 given an impossible value (non-finite, a range <= 0 or beyond any line of sight,
    an azimuth outside [0, 360), an altitude outside [-1 km, 100 km], a time before 1970 or after 2200)."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(5))
    plots_path, radar_path = tf.write_recording(tmp_path, with_values(plots, column, [5, 9], value), radars)
    with pytest.raises(io.InputError) as error:
        plot_table.read_parquet_plots(plots_path, radar_path, params.radar)
    assert str(error.value).startswith(f"{plots_path}: column '{column}' must be ")
    assert f"row 5 is {float(value)!r} (2 of {plots.num_rows} rows bad)" in str(error.value)


def with_type(table: pa.Table, column: str, kind: pa.DataType) -> pa.Table:
    """`table` with `column` converted to `kind` (unsafely: as a user's own writer would store it); a
    timestamp from Unix seconds."""
    index = table.schema.get_field_index(column)
    values = table.column(column)
    if pa.types.is_timestamp(kind):
        values = pa.array((values.to_numpy() * 1e9).astype(np.int64)).cast(kind)
    return table.set_column(index, column, values.cast(kind, safe=False))


@pytest.mark.parametrize("kind, reason", [
    (pa.float32(), "a float32 holds a present-day Unix time only to 128 s, so the times are already lost"),
    (pa.int64(), "integer times could be seconds, milliseconds or nanoseconds, which is not guessed"),
    (pa.timestamp("ns"), "Unix seconds are read from float64 only, not converted from timestamp[ns]"),
])
def test_a_time_column_that_is_not_float64_is_refused_naming_the_file_column_and_type(params, tmp_path, filters_only,
                                                                                       caplog, kind, reason):
    """`time_unix_s` as float32 (present-day times 128 s apart: every plot would start its own track),
    as integers (seconds? nanoseconds?) or as a timestamp: `track` exits 2 naming the file, the column
    and both types, streamed or read whole, and writes nothing."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(5))
    stored = with_type(plots, "time_unix_s", kind)
    assert track_command(tmp_path, filters_only, "kalman_cv", stored, radars) == 2
    assert (f"plots.parquet: column 'time_unix_s' has type {kind}, expected double ({reason}: write them as "
            f"float64 Unix seconds)") in caplog.text
    assert not (tmp_path / "tracks.parquet").exists()
    whole = tf.write_recording(tmp_path / "whole", stored, radars)
    with pytest.raises(io.InputError) as error:
        plot_table.read_parquet_plots(*whole, params.radar)
    assert str(error.value).startswith(f"{whole[0]}: column 'time_unix_s' has type {kind}, expected double ({reason}")


def test_a_track_tables_float32_time_is_refused_by_its_reader(params, tmp_path, filters_only):
    """The track table `associate` reads, its `time_unix_s` rewritten as float32: refused naming the file
    and the column, as a recording's is."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(5))
    assert track_command(tmp_path, filters_only, "kalman_cv", plots, radars) == 0
    tracks = tmp_path / "float32.parquet"
    pq.write_table(with_type(pq.read_table(tmp_path / "tracks.parquet"), "time_unix_s", pa.float32()), tracks)
    with pytest.raises(io.InputError, match=r"float32.parquet: column 'time_unix_s' has type float, expected "
                                            r"double \(a float32 holds a present-day Unix time only to 128 s"):
        track_tables.read_track_table(tracks, tmp_path / "recording" / "radar.parquet",
                                      params.associate.max_speed_mps)


def test_float32_measurements_are_read_and_float16_or_rounded_float_ids_are_refused(params, tmp_path):
    """float32 range, azimuth and altitude are read as they are stored (within 2^-24 of the value:
    millimetres at 100 km); a float16 azimuth (0.25 deg apart near 360) is refused, and so are plot ids
    stored as float32 past 2^24 (33554433 is stored as 33554432), where ids may have been rounded.
    Whole float ids below it are read as the integers they are."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(5))
    stored = with_type(with_type(with_type(plots, "range_m", pa.float32()), "azimuth_deg", pa.float32()),
                       "altitude_m", pa.float32())
    read = plot_table.read_parquet_recording(*tf.write_recording(tmp_path / "f32", stored, radars), params.radar)
    for name in ("range_m", "azimuth_deg", "altitude_m"):
        np.testing.assert_array_equal(read.table.column(name).to_numpy(), stored.column(name).to_numpy())
    float_ids = with_type(plots, "plot_id", pa.float64())
    read = plot_table.read_parquet_recording(*tf.write_recording(tmp_path / "ids", float_ids, radars), params.radar)
    assert read.table.column("plot_id").to_pylist() == plots.column("plot_id").to_pylist()
    with pytest.raises(io.InputError, match="column 'azimuth_deg' has type halffloat, expected double "
                                            r"\(a float16 holds about 3 significant digits"):
        plot_table.read_parquet_plots(*tf.write_recording(tmp_path / "f16", with_type(plots, "azimuth_deg",
                                                                                      pa.float16()), radars),
                                      params.radar)
    rounded = with_type(with_values(plots, "plot_id", [7], 2**25 + 1), "plot_id", pa.float32())
    with pytest.raises(io.InputError, match=r"column 'plot_id' has type float, expected int64 \(row 7 is "
                                            r"33554432.0, past 2\^24, beyond which a float no longer holds every "
                                            r"integer: the id may have been rounded"):
        plot_table.read_parquet_plots(*tf.write_recording(tmp_path / "big", rounded, radars), params.radar)


@pytest.mark.parametrize("column, value", [
    ("latitude_deg", 90.5), ("latitude_deg", -np.inf), ("longitude_deg", 180.5), ("longitude_deg", -181.0),
    ("height_m", np.inf), ("height_m", 1e6), ("scan_period_s", 0.0), ("scan_period_s", -6.0),
    ("scan_period_s", np.nan), ("sigma_range_m", 0.0), ("sigma_azimuth_deg", np.inf), ("sigma_altitude_m", -30.0),
])
def test_an_impossible_radar_value_names_the_file_column_row_and_value(params, tmp_path, column, value):
    """The second radar's row given an impossible site, scan period or error figure; NaN is refused in
    the optional columns too."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(5))
    good = radars.column(column).to_pylist() if column in radars.column_names else [None, None]
    radars = with_radar_column(radars, column, [good[0], value])
    plots_path, radar_path = tf.write_recording(tmp_path, plots, radars)
    with pytest.raises(io.InputError) as error:
        plot_table.read_parquet_plots(plots_path, radar_path, params.radar)
    assert str(error.value).startswith(f"{radar_path}: column '{column}' must be ")
    assert f"row 1 is {float(value)!r} (1 of 2 rows bad)" in str(error.value)


def test_bad_input_exits_2_and_leaves_an_earlier_output_alone(params, tmp_path, filters_only, caplog):
    """`track` on plots with an infinite range: exit 2, the file, column and row in the log, and the
    output of an earlier run (and its summary) untouched."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(6))
    out = tmp_path / "tracks.parquet"
    out.write_bytes(b"earlier run")
    summary = tmp_path / "tracks.summary.json"
    summary.write_text("{}")
    assert track_command(tmp_path, filters_only, "kalman_cv", with_values(plots, "range_m", [3], np.inf), radars) == 2
    assert "plots.parquet: column 'range_m' must be in (0, 2000000]: row 3 is inf" in caplog.text
    assert out.read_bytes() == b"earlier run" and summary.read_text() == "{}"


@pytest.mark.parametrize("out_as, named", [("plots", "--out names the same file as --plots"),
                                            ("radar", "--out names the same file as --radar"),
                                            ("summary of plots", "--out's summary names the same file as --plots"),
                                            ("folder", "--out is a folder"),
                                            ("under a file", "is not a folder this user can write to")])
def test_an_output_that_would_replace_an_input_is_refused(params, tmp_path, filters_only, caplog, out_as, named):
    """`--out` naming the recording (or the radar description, or an input that `--out`'s summary,
    `<stem>.summary.json`, would replace) exits 2 before reading, and the user's files keep their bytes.
    So does an `--out` that could not be written (a folder; a path under a file), which failed at the
    rename after all the work, leaving a summary without its tracks."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(6))
    plots_path, radar_path = tf.write_recording(tmp_path / "recording", plots, radars)
    if out_as == "summary of plots":
        plots_path = plots_path.rename(plots_path.with_name("tracks.summary.json"))
        out = plots_path.with_name("tracks.parquet")
    else:
        out = {"plots": plots_path, "radar": radar_path, "folder": plots_path.parent,
               "under a file": plots_path / "tracks.parquet"}[out_as]
    before = {path: path.read_bytes() for path in (plots_path, radar_path)}
    params_path = write_params(tf.params_tree(), tmp_path / "params.yaml")
    assert cli.main(["track", "--params", str(params_path), "--plots", str(plots_path), "--radar", str(radar_path),
                     "--models", str(filters_only), "--method", "kalman_cv", "--out", str(out)]) == 2
    assert named in caplog.text, caplog.text
    assert {path: path.read_bytes() for path in before} == before
    assert sorted(p.name for p in plots_path.parent.iterdir()) == sorted(p.name for p in before)


def test_asterix_export_refuses_to_write_over_its_plots(params, tmp_path, caplog):
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(6))
    plots_path, radar_path = tf.write_recording(tmp_path, plots, radars)
    before = plots_path.read_bytes()
    assert cli.main(["asterix-export", "--plots", str(plots_path), "--radar", str(radar_path), "--scenario", "7",
                     "--out", str(plots_path)]) == 2
    assert "--out names the same file as --plots" in caplog.text and plots_path.read_bytes() == before


def test_a_recording_without_plots_gives_an_empty_track_table_and_says_so(params, tmp_path, filters_only, caplog):
    """No plots (a user's selection that matched nothing) once ended in an IndexError traceback (exit 1): now an
    empty table of the track schema, a summary of zeros and a warning."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(6))
    assert track_command(tmp_path, filters_only, "kalman_cv", plots.slice(0, 0), radars) == 0
    tracks = pq.read_table(tmp_path / "tracks.parquet")
    assert tracks.num_rows == 0 and tracks.schema.equals(TRACK_SCHEMA)
    summary = json.loads((tmp_path / "tracks.summary.json").read_text())
    assert summary["plots_tracked"] == summary["track_updates"] == summary["confirmed_tracks"] == 0
    assert "no plots to track" in caplog.text


def test_a_repeated_plot_id_names_the_value_and_its_rows(params, tmp_path):
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(7))
    ids = plots.column("plot_id").to_numpy()
    plots_path, radar_path = tf.write_recording(tmp_path, with_values(plots, "plot_id", [4, 11], ids[2]), radars)
    with pytest.raises(io.InputError, match=rf"plot_id {ids[2]} is listed 3 times \(rows 2, 4, 11\); 2 rows repeat "
                                            r"an earlier plot_id \(column 'plot_id' must be unique") as error:
        plot_table.read_parquet_plots(plots_path, radar_path, params.radar)
    assert str(error.value).startswith(str(plots_path))


@pytest.mark.parametrize("second_site", [None, SECOND_SITE], ids=["identical rows", "two sites"])
def test_a_radar_listed_twice_is_refused_whether_or_not_the_rows_agree(params, tmp_path, second_site):
    """Two rows for radar 1: which one was meant cannot be told from the file, so even identical rows
    are refused (one row per radar)."""
    plots, _, _ = two_radar_recording(params, np.random.default_rng(8))
    plots = plots.filter(pa.compute.equal(plots.column("radar_id"), 1))
    twin = params.radar if second_site is None else tf.radar_at(params.radar, *second_site)
    radars = pa.concat_tables([tf.radar_table(1, params.radar), tf.radar_table(1, twin)])
    plots_path, radar_path = tf.write_recording(tmp_path, plots, radars)
    with pytest.raises(io.InputError, match=r"radar.parquet: radar_id 1 is listed 2 times \(rows 0, 1\)"):
        plot_table.read_parquet_plots(plots_path, radar_path, params.radar)


def test_a_radars_own_error_figures_override_params_for_that_radar_only(params, tmp_path):
    """sigma_* columns in the radar description, given for radar 2 and null for radar 1: radar 2's plots
    get the covariance of its own errors, radar 1's that of params' `radar`."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(9))
    own = {"sigma_range_m": 120.0, "sigma_azimuth_deg": 0.2, "sigma_altitude_m": 60.0}
    for column, value in own.items():
        radars = with_radar_column(radars, column, [None, value])
    table = plot_table.read_parquet_plots(*tf.write_recording(tmp_path, plots, radars), params.radar)
    second = dataclasses.replace(tf.radar_at(params.radar, *SECOND_SITE), **own)
    assert table.radars[2] == second and table.radars[1] == params.radar
    for radar_id, radar in ((1, params.radar), (2, second)):
        rows = table.radar_id == radar_id
        np.testing.assert_allclose(table.covariance[rows], geodesy.measurement_covariance(table.position[rows], radar),
                                   rtol=1e-12)


def shifted(plots: pa.Table, rows: slice, seconds: float) -> pa.Table:
    """The recording with the times of `rows` moved by `seconds`."""
    times = plots.column("time_unix_s").to_numpy().copy()
    times[rows] += seconds
    return with_column(plots, "time_unix_s", times)


def test_a_backward_day_jump_within_a_radar_is_refused_as_a_day_error(params, tmp_path, filters_only, caplog):
    """The plots from row 40 on a day early (a time of day added to the date of the first plot, across
    midnight): exit 2 naming the file, column time_unix_s, the row and the jump back from the latest
    earlier plot of its radar, and how many plots jumped; no output."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(10))
    plots = plots.take(np.argsort(plots.column("time_unix_s").to_numpy(), kind="stable"))
    times, radar_ids = plots.column("time_unix_s").to_numpy(), plots.column("radar_id").to_numpy()
    jump = times[:40][radar_ids[:40] == radar_ids[40]].max() - (times[40] - 86400.0)
    assert track_command(tmp_path, filters_only, "kalman_cv", shifted(plots, slice(40, None), -86400.0), radars) == 2
    assert (f"plots.parquet: column 'time_unix_s' jumps back {jump:.0f} s at row 40 "
            f"({float(times[40] - 86400.0)!r}) within the plots of radar {radar_ids[40]}, scenario 7" in caplog.text)
    assert f"({plots.num_rows - 40} of {plots.num_rows} rows more than 3600 s earlier" in caplog.text
    assert "probably a day error (a time of day added to a fixed date?), not parts merged out of order" in caplog.text
    assert not (tmp_path / "tracks.parquet").exists()


def test_plots_out_of_order_are_counted_by_plots_moved_and_the_largest_step(params, tmp_path, caplog):
    """A recording written radar by radar (radar 2's scans interleave radar 1's, 3 s later) and with
    radar 1's plots 10..19 moved after 20..29: sorted, and the warning counts the plots earlier than a
    plot before them (not the backward steps) and gives the largest step back. Radar 2's plots, two
    hours before radar 1's last ones, are no day error: each radar's own plots are in order."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(11))
    by_radar = [plots.filter(pa.compute.equal(plots.column("radar_id"), r)) for r in (1, 2)]
    first = by_radar[0].take(np.r_[0:10, 20:30, 10:20, 30:by_radar[0].num_rows])
    second = shifted(by_radar[1], slice(None), -7200.0)
    recording = pa.concat_tables([first, second])
    times = recording.column("time_unix_s").to_numpy()
    latest = np.maximum.accumulate(times)
    moved, largest = int((times < latest).sum()), float((latest - times).max())
    assert moved == 10 + second.num_rows
    with caplog.at_level("WARNING", logger="pipeline"):
        table = plot_table.read_parquet_plots(*tf.write_recording(tmp_path, recording, radars), params.radar)
    assert (np.diff(table.time) >= 0).all() and len(table) == recording.num_rows
    assert (f"{moved} plots out of time order (up to {largest:.1f} s earlier than a plot before them); sorted by "
            "time as parts merged out of order (a step back of more than 3600 s within a radar would be refused "
            "as a day error)") in caplog.text


def test_twins_of_earlier_plots_are_dropped_and_counted_beside_what_the_reader_skipped(params):
    """plot_table on a recording with each of radar 1's first five plots given again under new plot ids
    (as from a second, redundant network), and one plot copied to the other radar: the five twins are
    dropped (the first of each pair kept), the copy for another radar kept; the reader's own counts
    (`skipped`) are carried beside "duplicate plot"."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(12))
    first_five = plots.filter(pa.compute.equal(plots.column("radar_id"), 1)).slice(0, 5)
    twins = with_column(first_five, "plot_id", np.arange(90000, 90005))
    elsewhere = with_column(with_values(first_five.slice(0, 1), "radar_id", [0], 2), "plot_id", np.array([90009]))
    table = plot_table.plot_table(pa.concat_tables([plots, twins, elsewhere]),
                                  plot_table.sensors(radars, params.radar), "test", skipped={"no position": 3})
    assert table.skipped == {"no position": 3, "duplicate plot": 5}
    assert len(table) == plots.num_rows + 1
    assert not np.isin(np.arange(90000, 90005), table.plot_id).any() and 90009 in table.plot_id


def test_one_feed_under_two_radar_ids_at_one_site_is_tracked_once(params, tmp_path, filters_only, caplog):
    """Radar 1's plots given again under radar id 3, described at radar 1's site (one feed delivered under two
    ids): the copies are dropped and counted as duplicates, so the tracks are those of radar 1's plots alone,
    not the extra confirmed clutter of each plot associated with its own copy."""
    caplog.set_level(logging.INFO, logger="pipeline")
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(13))
    alone = plots.filter(pa.compute.equal(plots.column("radar_id"), 1))
    copies = with_column(with_column(alone, "radar_id", np.full(alone.num_rows, 3, np.int32)), "plot_id",
                         alone.column("plot_id").to_numpy() + 100000)
    both = pa.concat_tables([radars.slice(0, 1), with_column(radars.slice(0, 1), "radar_id", np.array([3]))])
    assert track_command(tmp_path / "once", filters_only, "kalman_cv", alone, radars.slice(0, 1)) == 0
    assert track_command(tmp_path / "twice", filters_only, "kalman_cv", pa.concat_tables([alone, copies]), both) == 0
    once = pq.read_table(tmp_path / "once" / "tracks.parquet").to_pandas()
    assert pq.read_table(tmp_path / "twice" / "tracks.parquet").to_pandas().equals(once)
    summary = json.loads((tmp_path / "twice" / "tracks.summary.json").read_text())
    assert summary["skipped"] == {"duplicate plot": alone.num_rows} and summary["radars"]["3"]["plots"] == 0
    assert "of 1 confirmed track, on the plots of 1 radar (no plot tracked of radar 3)" in caplog.text  # not "2 radars"


def test_a_recording_with_every_plot_twice_gives_the_same_tracks(params, tmp_path, filters_only):
    """Every plot given twice, each twin right after its plot with its own plot id: the same track
    file as the recording once, and the summary counts the twins."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(13))
    twins = with_column(plots, "plot_id", plots.column("plot_id").to_numpy() + 100000)
    twice = pa.concat_tables([plots, twins]).take(np.repeat(np.arange(plots.num_rows), 2)
                                                  + np.tile([0, plots.num_rows], plots.num_rows))
    assert track_command(tmp_path / "once", filters_only, "kalman_cv", plots, radars) == 0
    assert track_command(tmp_path / "twice", filters_only, "kalman_cv", twice, radars) == 0
    once = pq.read_table(tmp_path / "once" / "tracks.parquet").to_pandas()
    assert pq.read_table(tmp_path / "twice" / "tracks.parquet").to_pandas().equals(once)  # NaN equal to NaN
    assert (once["status"] == "confirmed").any()
    summary = json.loads((tmp_path / "twice" / "tracks.summary.json").read_text())
    assert summary["skipped"] == {"duplicate plot": plots.num_rows} and summary["plots_tracked"] == plots.num_rows


@pytest.mark.parametrize("changes, warned", [({}, False), ({"tracker.management.rule": "m_of_n",
                                                                "tracker.management.silence_scans": 0.0}, False),
                                              ({"tracker.management.silence_scans": 0.0}, True)])
def test_a_radar_too_slow_for_the_silence_is_warned_of_by_its_id(params, tmp_path, filters_only, caplog, changes,
                                                                 warned):
    """Radar 2 turning every 12 s: with the silence in seconds alone (tracker.management.silence_scans 0: 12 s,
    less than 1.5 of its scans) `track` warns, naming radar 2 and its period, and still tracks
    (exit 0); radar 1 (6 s) is not named. Under the default params (silence 2 scans, 24 s there) and
    under M-of-N (1.5 scans) no radar is named."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(4))
    radars = with_radar_column(radars, "scan_period_s", [None, 12.0])
    assert track_command(tmp_path, filters_only, "kalman_cv", plots, radars, changes) == 0
    assert ("radar 2 turns every 12 s, but track management 'thesis' lowers a new track after 12 s"
            in caplog.text) == warned
    assert "radar 1 turns" not in caplog.text


@pytest.mark.parametrize("method", ["imm", "kalman_cv_gnn"])
def test_a_recording_read_in_chunks_gives_the_bytes_of_one_read_whole(params, tmp_path, filters_only, method):
    """Three scenarios of the two-radar recording (copies under other scenario and plot ids),
    in file order scenario 9, 7, 8: tracked 5 plots at a time (chunks cut scans, live tracks and
    scenarios) the output file and summary are byte for byte those of one chunk, and the one
    chunk's those of the whole plot table tracked and written at once (`track_recording`; fewer
    updates than `track`'s row group, TRACK_ROW_GROUP_ROWS)."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(4))
    copies = [with_column(with_values(plots, "scenario_id", np.arange(plots.num_rows), scenario), "plot_id",
                          plots.column("plot_id").to_numpy() + 10000 * scenario) for scenario in (9, 8)]
    recording = pa.concat_tables([copies[0], plots, copies[1]])
    outputs = {}
    for chunk in (5, 1000000):
        folder = tmp_path / str(chunk)
        assert track_command(folder, filters_only, method, recording, radars, {"compute.chunk_plots": chunk}) == 0
        outputs[chunk] = [(folder / name).read_bytes() for name in ("tracks.parquet", "tracks.summary.json")]
        assert sorted(p.name for p in folder.iterdir()) == ["params.yaml", "recording", "tracks.parquet",
                                                            "tracks.summary.json"]
    assert outputs[5] == outputs[1000000]
    whole = track_recording(plot_table.read_parquet_plots(*tf.write_recording(tmp_path / "whole", recording, radars),
                                                          params.radar), method, 4000.0, params, filters_only)
    io.write_parquet(whole, tmp_path / "whole.parquet")
    assert (tmp_path / "whole.parquet").read_bytes() == outputs[5][0]
    assert pq.read_table(tmp_path / "whole.parquet").column("scenario_id").unique().to_pylist() == [7, 8, 9]


def test_track_logs_progress_and_its_summary_says_how_the_tracks_were_made(params, tmp_path, filters_only, caplog):
    """A recording of a few thousand plots (the two-radar recording in twelve scenarios), tracked 500 plots at
    a time with a progress line after every chunk: progress lines with plots done, rate and time left; the
    summary names the method, window, management rule and the tuned filters' file with its digest (the tag
    its registered MLflow version would carry), and counts the updates by status and the tracks started.
    With --confirmed-only the file holds just the confirmed updates, and the summary counts the same."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(5))
    recording = pa.concat_tables([with_column(with_values(plots, "scenario_id", np.arange(plots.num_rows), scenario),
                                              "plot_id", plots.column("plot_id").to_numpy() + 10000 * scenario)
                                  for scenario in range(12)])
    assert recording.num_rows > 2000
    changes = {"compute.chunk_plots": 500, "compute.progress_every_s": 0.0}
    with caplog.at_level(logging.INFO, logger="pipeline"):
        assert track_command(tmp_path / "every", filters_only, "imm", recording, radars, changes) == 0
    progress = [r.getMessage() for r in caplog.records if r.getMessage().startswith("track: plots tracked: ")]
    assert len(progress) >= 2 and "a second, about" in progress[0] and progress[-1].startswith(
        f"track: plots tracked: {recording.num_rows}/{recording.num_rows} (100%)")
    assert "track: method imm, window 4000 m, track management thesis" in caplog.text
    summary = json.loads((tmp_path / "every" / "tracks.summary.json").read_text())
    tuned = filters_only / "kalman_tuned.json"
    assert (summary["method"], summary["window_m"], summary["management"]) == ("imm", 4000.0, "thesis")
    assert summary["models"] == {str(tuned): experiment_tracking.data_hash(tuned)}
    tracks = pq.read_table(tmp_path / "every" / "tracks.parquet").to_pydict()
    status = np.asarray(tracks["status"])
    assert summary["track_updates_by_status"] == {name: int((status == name).sum())
                                                  for name in ("tentative", "candidate", "confirmed")}
    assert summary["tracks"] == len(set(zip(tracks["scenario_id"], tracks["track_id"])))
    assert summary["track_updates"] == summary["rows_written"] == len(status) == recording.num_rows
    assert 0 < summary["track_updates_by_status"]["confirmed"] < len(status)

    plots_path, radar_path = tf.write_recording(tmp_path / "every" / "recording", recording, radars)
    out = tmp_path / "confirmed.parquet"
    assert cli.main(["track", "--params", str(tmp_path / "every" / "params.yaml"), "--plots", str(plots_path),
                     "--radar", str(radar_path), "--models", str(filters_only), "--method", "imm",
                     "--confirmed-only", "--out", str(out)]) == 0
    confirmed = pq.read_table(out)
    assert set(confirmed.column("status").to_pylist()) == {"confirmed"}
    assert confirmed.num_rows == summary["track_updates_by_status"]["confirmed"]
    only = json.loads(track_command_module.summary_path(out).read_text())
    assert only["rows_written"] == confirmed.num_rows and only["confirmed_only"] is True
    assert only["track_updates_by_status"] == summary["track_updates_by_status"]


def test_the_output_carries_the_filters_velocity_as_ground_speed_course_and_vertical_rate(params, tmp_path,
                                                                                            filters_only):
    """The straight level target of the two-radar recording (180 m/s east, 90 m/s north in radar 1's frame: 201 m/s
    on a course of 63.4 degrees there, exact plots) tracked by the IMM: its confirmed updates give its ground
    speed to 1 m/s, its course at its own position (the meridians converge: 64.4 degrees 70 km east) to half a
    degree and its vertical rate (level in the radar's frame, it climbs 2-3 m/s over the curved Earth at 70-100 km)
    to half a metre a second, with a positive velocity variance; a track's start has no velocity (null)."""
    plots, radars, target_ids = two_radar_recording(params, np.random.default_rng(6))
    alone = plots.filter(pa.compute.equal(plots.column("radar_id"), 1))
    assert track_command(tmp_path, filters_only, "imm", alone, radars.slice(0, 1)) == 0
    tracks = pq.read_table(tmp_path / "tracks.parquet").to_pandas()
    target = tracks[tracks["plot_id"].isin(target_ids) & (tracks["status"] == "confirmed")]
    assert len(target) >= 15
    np.testing.assert_allclose(target["ground_speed_mps"], np.hypot(180.0, 90.0), atol=1.0)
    velocity_ecef = geodesy.enu_rotation(params.radar.latitude_deg, params.radar.longitude_deg).T @ [180.0, 90.0, 0.0]
    east, north, up = np.einsum("uij,j->iu", geodesy.enu_rotations(target["latitude_deg"].to_numpy(),
                                                                  target["longitude_deg"].to_numpy()), velocity_ecef)
    np.testing.assert_allclose(target["course_deg"], np.degrees(np.arctan2(east, north)), atol=0.5)
    np.testing.assert_allclose(target["vertical_rate_mps"], up, atol=0.5)  # a straight line climbs over the Earth
    assert (target["velocity_covariance_xx_m2_s2"] > 0.0).all()
    speed = np.sqrt(target["vx_ecef_mps"] ** 2 + target["vy_ecef_mps"] ** 2 + target["vz_ecef_mps"] ** 2)
    np.testing.assert_allclose(speed, np.hypot(target["ground_speed_mps"], target["vertical_rate_mps"]), rtol=1e-9)
    starts = tracks[tracks["association"] == "start"]
    assert starts[list(recording.VELOCITY_COLUMNS)].isna().all().all()


def test_an_output_written_in_row_groups_has_the_bytes_of_one_write(tmp_path):
    """`io.ParquetChunks` with row groups of 4 rows, given chunks of 3, 6 and 2 rows in parts of 1-2
    rows: the bytes of `pq.write_table` on the chunks joined, in row groups of 4."""
    chunks = [pa.table({"x": np.arange(start, stop, dtype=np.float64)}) for start, stop in ((0, 3), (3, 9), (9, 11))]
    with pq.ParquetWriter(tmp_path / "parts.parquet", chunks[0].schema, compression="zstd",
                          write_statistics=True) as writer:
        written = io.ParquetChunks(writer, chunks[0].schema, row_group_rows=4)
        for chunk in chunks:
            for first in range(0, chunk.num_rows, 2):
                written.add(chunk.slice(first, 2), new_chunk=first == 0)
        written.close()
    pq.write_table(pa.concat_tables(chunks), tmp_path / "whole.parquet", compression="zstd", write_statistics=True,
                   row_group_size=4)
    assert (tmp_path / "parts.parquet").read_bytes() == (tmp_path / "whole.parquet").read_bytes()
    assert pq.ParquetFile(tmp_path / "parts.parquet").metadata.num_row_groups == 3


def in_order(plots: pa.Table, first_plot_id: int = 0) -> pa.Table:
    """The recording sorted by time (stable) with plot ids counting up from `first_plot_id` in that
    order: what `simulate` and a recorder write, which `track` reads from its file as it goes."""
    plots = plots.take(np.argsort(plots.column("time_unix_s").to_numpy(), kind="stable"))
    return with_column(plots, "plot_id", np.arange(first_plot_id, first_plot_id + plots.num_rows))


def test_a_file_read_a_batch_at_a_time_holds_a_row_group_not_the_file(tmp_path):
    """32 row groups of 16 384 random floats (128 KiB each, incompressible, 4 MiB in all) read a
    row group at a time through `io.parquet_file`: Arrow holds at most a few row groups' bytes at
    any time (pyarrow's default pre-buffering holds the whole file, 3 MiB by the first batch)."""
    path = tmp_path / "plots.parquet"
    rng = np.random.default_rng(5)
    with pq.ParquetWriter(path, pa.schema([("x", pa.float64())])) as writer:
        for _ in range(32):
            writer.write_table(pa.table({"x": rng.normal(size=16384)}))
    held = []
    for batch in io.parquet_file(path).iter_batches(batch_size=16384):
        held.append(pa.total_allocated_bytes())
        del batch
    assert len(held) == 32 and max(held) < 8 * 16384 * 8  # under 8 row groups' 1 MiB, a quarter of the file


def test_an_in_order_recording_is_streamed_with_the_chunks_of_the_sorting_read(params, tmp_path, monkeypatch):
    """Scenario 7, then 8 (a copy), each in time order, the plot ids increasing in 7 and decreasing
    in 8, and twins of rows 6, 12 and 30 right after them, read 7 rows at a time (runs of one time
    cross the batches' ends): `read_recording` streams it and gives, chunk for chunk (5 plots,
    cutting scans and scenarios), the plots, counts and warnings of the whole read that sorts it.
    With a plot id repeated it gives the whole read's error."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(14))
    scenario = in_order(plots)
    scenario = in_order(scenario.take(np.sort(np.r_[np.arange(scenario.num_rows), 6, 12, 30])))
    copy = with_column(scenario, "scenario_id", np.full(scenario.num_rows, 8))
    recording = pa.concat_tables([scenario, with_column(copy, "plot_id", 20000 - np.arange(scenario.num_rows))])
    monkeypatch.setattr(io, "READ_BATCH_ROWS", 7)
    repeated = tf.write_recording(tmp_path / "repeated", with_values(recording, "plot_id", [50], 3), radars)
    with pytest.raises(io.InputError, match="plot_id 3 is listed 2 times"), \
            streamed_recording.read_recording(*repeated, params.radar):
        pass
    paths = tf.write_recording(tmp_path, recording, radars)
    with streamed_recording.read_recording(*paths, params.radar) as streamed:
        assert_streamed_as_whole(streamed, plot_table.read_parquet_recording(*paths, params.radar), 5)
        assert streamed.path == paths[0]
    assert len(streamed) == recording.num_rows - 6
    assert streamed.skipped == {"duplicate plot": 6}


def assert_streamed_as_whole(streamed, whole: plot_table.Recording, chunk_plots: int) -> None:
    """`streamed` (a StreamedRecording) gives the plots, counts and chunks of the whole read."""
    assert isinstance(streamed, streamed_recording.StreamedRecording)
    assert len(streamed) == len(whole) and streamed.skipped == whole.skipped
    assert streamed.plot_counts == whole.plot_counts and streamed.has_truth == whole.has_truth
    streamed_chunks = [(s, chunk) for s, chunks in streamed.scenarios(chunk_plots) for chunk in chunks]
    whole_chunks = [(s, chunk) for s, chunks in whole.scenarios(chunk_plots) for chunk in chunks]
    assert [(s, len(c)) for s, c in streamed_chunks] == [(s, len(c)) for s, c in whole_chunks]
    for (_, got), (_, expected) in zip(streamed_chunks, whole_chunks):
        for name in ("plot_id", "radar_id", "scenario_id", "time", "position", "range_m", "covariance", "target_id"):
            np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))


def out_of_order(plots: pa.Table, case: str) -> pa.Table:
    """The in-order recording `plots` out of order as `case` says."""
    if case == "late":  # rows 20..29 after 30..39, as files merged slightly out of order
        return plots.take(np.r_[0:20, 30:40, 20:30, 40:plots.num_rows])
    if case == "late, times of scan":  # as "late", each plot stamped with the time of its 6 s scan (ties)
        times = plots.column("time_unix_s").to_numpy()
        return out_of_order(with_column(plots, "time_unix_s", times - np.mod(times - times[0], 6.0)), "late")
    if case == "radars one after the other":  # each radar's file in turn; radar 2's scans are 3 s after radar 1's
        radar_ids = plots.column("radar_id").to_numpy()
        return plots.take(np.r_[np.flatnonzero(radar_ids == 2), np.flatnonzero(radar_ids == 1)])
    # "twins and scenarios": scenario 8 (a copy) first, then 7 late as above, with twins of rows 3, 25
    # and 31 (new plot ids) at the end: their plots are in other runs
    late = out_of_order(plots, "late")
    copy = with_column(with_column(late, "scenario_id", np.full(late.num_rows, 8)), "plot_id",
                       late.column("plot_id").to_numpy() + 10000)
    twins = with_column(late.take([3, 25, 31]), "plot_id", np.array([90003, 90025, 90031]))
    return pa.concat_tables([copy, late, twins])


@contextlib.contextmanager
def whole_read(plots_path: Path, radar_path: Path, radar, scratch: Path):
    """`streamed_recording.read_recording` as it was: the whole read, sorted in memory."""
    yield plot_table.read_parquet_recording(plots_path, radar_path, radar)


@pytest.mark.parametrize("case, sizes", [
    ("late", "default"),
    ("late", "runs smaller than the batch"),
    ("late, times of scan", "runs smaller than the batch"),
    ("radars one after the other", "runs smaller than the batch"),
    ("twins and scenarios", "runs smaller than the batch"),
])
def test_an_out_of_order_recording_is_sorted_and_tracked_as_the_in_order_one(params, tmp_path, filters_only,
                                                                             monkeypatch, caplog, case, sizes):
    """An in-order recording made out of order (`out_of_order`) is sorted out of core, in a folder
    beside the output that is gone afterwards, and tracked from the sorted copy: the output file (of
    several row groups, here 16 updates each) and summary are byte for byte those of the whole read
    that sorts in memory, with the same warnings (plots moved and the largest step back, twins);
    its chunks are the whole read's. Read 7 rows at a time, runs of 5 rows merged 3 rows and 2 runs
    at a time (merges of merges), or at the default sizes. The in-order recording's output is the
    same tracks (the plot ids aside where the case renumbers them)."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(15))
    ordered = in_order(plots)
    recording = out_of_order(ordered, case)
    monkeypatch.setattr(track_command_module, "TRACK_ROW_GROUP_ROWS", 16)
    if sizes != "default":
        for module, name, value in ((io, "READ_BATCH_ROWS", 7), (external_sort, "RUN_ROWS", 5),
                                    (external_sort, "MERGE_BATCH_ROWS", 3), (external_sort, "MERGE_FAN_IN", 2)):
            monkeypatch.setattr(module, name, value)
    paths = tf.write_recording(tmp_path / "recording", recording, radars)
    with streamed_recording.read_recording(*paths, params.radar) as streamed:
        assert streamed.path != paths[0] and streamed.path.parent.name.startswith(".track-sort.")
        assert_streamed_as_whole(streamed, plot_table.read_parquet_recording(*paths, params.radar), 5)
    assert not streamed.path.parent.exists()
    outputs, logs = {}, {}
    for name in ("sorted", "whole"):
        if name == "whole":
            monkeypatch.setattr(streamed_recording, "read_recording", whole_read)
        caplog.clear()
        assert track_command(tmp_path / name, filters_only, "imm", recording, radars, {"compute.chunk_plots": 7}) == 0
        outputs[name] = [(tmp_path / name / file).read_bytes() for file in ("tracks.parquet", "tracks.summary.json")]
        logs[name] = [r.getMessage().replace(str(tmp_path / name), "") for r in caplog.records if r.levelname == "WARNING"]
        assert sorted(p.name for p in (tmp_path / name).iterdir()) == ["params.yaml", "recording", "tracks.parquet",
                                                                     "tracks.summary.json"]
    assert outputs["sorted"] == outputs["whole"]
    assert logs["sorted"] == logs["whole"] and any("out of time order" in message for message in logs["sorted"])
    assert any("duplicate plots" in message for message in logs["sorted"]) == (case == "twins and scenarios")
    assert pq.ParquetFile(tmp_path / "sorted" / "tracks.parquet").metadata.num_row_groups > 1
    if case in ("late", "radars one after the other"):
        assert track_command(tmp_path / "ordered", filters_only, "imm", ordered, radars,
                             {"compute.chunk_plots": 7}) == 0
        assert (tmp_path / "ordered" / "tracks.parquet").read_bytes() == outputs["sorted"][0]


def test_an_out_of_order_recording_with_an_error_gives_the_whole_reads_error_and_leaves_no_folder(params, tmp_path,
                                                                                                  monkeypatch):
    """The "late" recording with a plot id repeated far apart (rows 3 and 50: other runs), or with
    the plots from row 60 on a day early, sorted in runs of 5 rows: the error of the whole read,
    naming the value, and nothing left in the scratch folder."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(16))
    late = out_of_order(in_order(plots), "late")
    monkeypatch.setattr(io, "READ_BATCH_ROWS", 7)
    monkeypatch.setattr(external_sort, "RUN_ROWS", 5)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    for name, bad, message in (("repeated", with_values(late, "plot_id", [50], late.column("plot_id")[3].as_py()),
                                f"plot_id {late.column('plot_id')[3].as_py()} is listed 2 times"),
                               ("day", shifted(late, slice(60, None), -86400.0), "probably a day error")):
        paths = tf.write_recording(tmp_path / name, bad, radars)
        with pytest.raises(io.InputError, match=message), streamed_recording.read_recording(*paths, params.radar, scratch):
            pass
        assert not list(scratch.iterdir())


def finished_pid() -> int:
    """The pid of a process that has ended (a pid no process of this host runs, until it is reused)."""
    process = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                             check=True)
    return int(process.stdout)


def test_a_killed_tracks_sort_folder_is_removed_by_the_next_sort_and_a_live_ones_is_left(params, tmp_path,
                                                                                         filters_only):
    """Sort folders beside `--out` as a `track` killed during its sort (SIGKILL: no cleanup runs) left
    them, named with the owner's pid and host: the next `track` that sorts there removes the dead
    owner's (a finished process's pid), with the runs inside, and leaves a live owner's (a running
    process's), another host's and an unrelated folder alone; its own folder is gone at its end."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(15))
    running = subprocess.Popen(["sleep", "60"])
    try:
        dead = tmp_path / f".track-sort.{finished_pid()}.{io.HOST}.k1llxd_1.tmp"
        live = tmp_path / f".track-sort.{running.pid}.{io.HOST}.aliv3abc.tmp"
        elsewhere = tmp_path / f".track-sort.{finished_pid()}.other-{io.HOST}.r3mote12.tmp"
        unrelated = tmp_path / ".track-sort.notes"
        for folder in (dead / "runs", live, elsewhere, unrelated):
            folder.mkdir(parents=True)
        (dead / "runs" / "run-0.parquet").write_bytes(b"sorted run")
        assert track_command(tmp_path, filters_only, "kalman_cv", out_of_order(in_order(plots), "late"), radars) == 0
        assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".track-sort")) == sorted(
            [live.name, elsewhere.name, unrelated.name])
    finally:
        running.kill()
        running.wait()


def test_an_atomic_writes_dead_temporary_is_removed_and_its_own_named_with_pid_and_host(tmp_path):
    """`io.atomic_path`'s temporary is `.<name>.<pid>.<host>.<random>.tmp`; the next write of the same
    file removes a dead writer's (with the old name of another output left alone)."""
    out = tmp_path / "tracks.parquet"
    stale = tmp_path / f".tracks.parquet.{finished_pid()}.{io.HOST}.abcdefgh.tmp"
    other = tmp_path / f".summary.json.{finished_pid()}.{io.HOST}.abcdefgh.tmp"
    stale.write_bytes(b"half")
    other.write_bytes(b"half")
    with io.atomic_path(out) as temporary:
        assert temporary.name.startswith(f".tracks.parquet.{os.getpid()}.{io.HOST}.") and temporary.suffix == ".tmp"
        temporary.write_bytes(b"whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([other.name, out.name])


def test_a_failure_while_tracking_leaves_no_output_and_no_summary(params, tmp_path, filters_only, monkeypatch):
    """The tracker fails after the first chunk's updates were written: no output, no summary, no
    temporary file; an earlier output of the same name is left as it was."""
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(5))
    (tmp_path / "tracks.parquet").write_bytes(b"earlier")
    real = recording.track_chunks

    def failing(chunks, tracker):
        yield next(real(chunks, tracker))
        raise RuntimeError("tracker failed")

    monkeypatch.setattr(recording, "track_chunks", failing)
    with pytest.raises(RuntimeError, match="tracker failed"):
        track_command(tmp_path, filters_only, "imm", plots, radars, {"compute.chunk_plots": 10})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["models", "params.yaml", "recording", "tracks.parquet"]
    assert (tmp_path / "tracks.parquet").read_bytes() == b"earlier"


@pytest.mark.parametrize("change", ["none", "nan", "null", "type", "overflow", "missing"])
def test_the_numeric_reader_gives_read_parquets_table_and_errors_across_batches(params, tmp_path, monkeypatch,
                                                                                change):
    """`io.read_numeric_parquet`, reading 7 rows at a time, against `io.read_parquet` on the same
    file: the same values (and nulls), or the same error naming the same first row and count (a NaN
    range at rows 9 and 20, a missing azimuth at rows 3 and 15, altitude as text with "high" at row 12, radar ids
    as int64 with one past int32 at row 5, no range column). A value that cannot be converted is named."""
    plots, _, _ = two_radar_recording(params, np.random.default_rng(6))
    if change == "nan":
        plots = with_values(plots, "range_m", [9, 20], np.nan)
    elif change == "null":
        azimuth = plots.column("azimuth_deg").to_numpy()
        plots = plots.set_column(plots.schema.get_field_index("azimuth_deg"), "azimuth_deg",
                                 pa.array(azimuth, mask=np.isin(np.arange(len(azimuth)), [3, 15])))
    elif change == "type":
        text = plots.column("altitude_m").cast(pa.string()).to_pylist()
        text[12] = "high"
        plots = plots.set_column(plots.schema.get_field_index("altitude_m"), "altitude_m", pa.array(text))
    elif change == "overflow":
        ids = plots.column("radar_id").to_numpy().astype(np.int64)
        ids[5] = 2**40
        plots = plots.set_column(plots.schema.get_field_index("radar_id"), "radar_id", pa.array(ids))
    elif change == "missing":
        plots = plots.drop_columns(["range_m"])
    path = tmp_path / "plots.parquet"
    pq.write_table(plots, path, row_group_size=10)
    monkeypatch.setattr(io, "READ_BATCH_ROWS", 7)
    arguments = (path, plot_table.PLOT_INPUT_SCHEMA, plot_table.OPTIONAL_PLOT_COLUMNS)
    if change == "none":
        assert io.read_numeric_parquet(*arguments).equals(io.read_parquet(*arguments))
        return
    with pytest.raises(io.InputError) as expected:
        io.read_parquet(*arguments)
    with pytest.raises(io.InputError) as got:
        io.read_numeric_parquet(*arguments)
    assert str(got.value) == str(expected.value)
    assert {"type": "'high'", "overflow": str(2**40)}.get(change, "") in str(got.value)


def slow_trained_lstm_update(models: Path) -> Path:
    """models/lstm_update.pt: an LSTM update (untrained: the alpha-beta filter it starts as, alpha = beta =
    0.5, MC dropout 0.3 over 8 copies) whose young tracks' copies start at velocities of 150 m/s spread,
    as a model trained on targets up to about 450 m/s (3 sigma) carries."""
    from pipeline.learning.lstm_update import LSTMUpdate, LSTMUpdateConfig
    from pipeline.learning.model_store import save_network
    config = LSTMUpdateConfig(hidden=8, dropout=0.3, mc_samples=8, detach_prediction=True, position_scale_m=1000.0,
                              velocity_scale_mps=400.0, acceleration_scale_mps2=10.0, time_scale_s=6.0,
                              initial_alpha=0.5, initial_beta=0.5, floor_m=1.0, start_velocity_std_mps=150.0,
                              calibration_ages=4, calibration_gaps=3)
    models.mkdir(parents=True, exist_ok=True)
    save_network(models / "lstm_update.pt", LSTMUpdate(config))
    return models


@pytest.mark.parametrize("fallback", [False, True])
def test_lstm_update_warns_when_its_gate_refuses_a_fast_target_and_the_window_fallback_tracks_it(
        params, tmp_path, caplog, fallback):
    """Case 29's kind: a straight level target at 600 m/s (Mach 1.8) 100 km from the radar, 20 scans. The
    LSTM update's young-track gate, its copies' start velocities those of slower targets, refuses every
    second plot: 20 tracks of one plot, none confirmed; the summary counts 19 of the 19 plots within
    window_m of a track refused, and `track` warns naming the method and the count. With
    `tracker.lstm_update.young_window_fallback` the young track takes the second plot by the window, the learned
    gate the rest: one track, confirmed from its fourth plot, nothing refused, no warning."""
    features = tf.straight_features(params.radar, (0.0, 100e3, 11000.0), (600.0, 0.0, 0.0), 20)
    plots = tf.measurement_table(features, np.arange(len(features)), params.radar, 1)
    models = slow_trained_lstm_update(tmp_path / "models")
    with caplog.at_level("WARNING", logger="pipeline"):
        assert track_command(tmp_path, models, "lstm_update", plots, tf.radar_table(1, params.radar),
                             {"tracker.lstm_update.young_window_fallback": fallback}) == 0
    tracks = pq.read_table(tmp_path / "tracks.parquet").to_pydict()
    summary = json.loads((tmp_path / "tracks.summary.json").read_text())
    warned = "track: method lstm_update: its learned gate refused 19 of the 19 plots (100.0 %) that lay within " \
             "window_m = 4000 m of a track it scored"
    if fallback:
        assert tracks["track_id"] == [0] * 20 and tracks["status"][3:] == ["confirmed"] * 17
        assert summary["learned_gate"] == {"plots_in_window": 19, "plots_refused": 0}
        assert summary["confirmed_tracks"] == 1 and "learned gate refused" not in caplog.text
    else:
        assert tracks["track_id"] == list(range(20)) and "confirmed" not in tracks["status"]
        assert summary["learned_gate"] == {"plots_in_window": 19, "plots_refused": 19}
        assert summary["confirmed_tracks"] == 0 and warned in caplog.text


def test_a_method_without_a_learned_gate_counts_nothing_refused(params, tmp_path, filters_only):
    """The same fast target under the IMM (a tuned filter's chi-square gate, nothing learned): one
    confirmed track, and the summary's learned-gate counts are zero."""
    features = tf.straight_features(params.radar, (0.0, 100e3, 11000.0), (600.0, 0.0, 0.0), 20)
    plots = tf.measurement_table(features, np.arange(len(features)), params.radar, 1)
    assert track_command(tmp_path, filters_only, "imm", plots, tf.radar_table(1, params.radar)) == 0
    summary = json.loads((tmp_path / "tracks.summary.json").read_text())
    assert summary["confirmed_tracks"] == 1
    assert summary["learned_gate"] == {"plots_in_window": 0, "plots_refused": 0}

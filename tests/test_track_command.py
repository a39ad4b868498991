"""`track` with what a method needs and nothing else, and recordings of several radars.

No trained networks here: the classical methods need only the tuned filters, so a models folder
holding just `kalman_tuned.json` (the filters at params' start values, written as the tune stage
writes them) is a checkout that has run `dvc repro tune_kalman` and no training.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline import baselines, cli, geodesy, io, plot_table
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
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


def track_command(folder: Path, models: Path, method: str, plots: pa.Table, radars: pa.Table) -> int:
    """`python -m pipeline track` on the recording, written with default params in `folder`; the
    output goes to folder / "tracks.parquet"."""
    plots_path, radar_path = tf.write_recording(folder / "recording", plots, radars)
    params_path = write_params(tf.params_tree(), folder / "params.yaml")
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
        np.testing.assert_allclose(table.covariance[own], baselines.measurement_covariance(table.position[own], radar),
                                   rtol=1e-12)
        assert not np.allclose(table.covariance[own], baselines.measurement_covariance(table.position[own], other),
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


def test_the_summary_counts_tracks_per_radar_as_radar_scenario_and_track_id(params, tmp_path, filters_only):
    """Track ids are only unique within a radar's scenario: the same target seen by two radars tracked
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


def test_a_classical_method_without_tuned_filters_names_the_file_and_stage(params, tmp_path):
    with pytest.raises(io.InputError, match=r"kalman_tuned.json: file not found; imm_gnn needs it .*"
                                            r"dvc repro tune_kalman"):
        load_models(tmp_path, params, ["imm_gnn"])


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

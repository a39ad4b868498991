"""The neural tracker (thesis 4.4-4.6) on scripted scenarios with known answers, and the `track` command.

Models are tiny real networks trained in a few seconds on synthetic flights (tests/tracker_fixtures.py);
the first test checks the predictor is good enough (a few hundred metres on a straight track) for the
VIA, MIA and AE scenarios to mean something. Plots are made in a radar's local ENU frame and placed
in ECEF with pymap3d; `track` inputs carry slant range, azimuth and altitude as a radar reports them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from pipeline import cli, io
from pipeline.recordings import plot_table
from pipeline.stages.track_command import run_track
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.management import ThesisWeights
from pipeline.tracker.network_estimator import NetworkEstimator
from pipeline.tracker.recording import track_recording
from pipeline.tracker.run import track
from pipeline.tracker.tracks import LiveTracks
from tests import tracker_fixtures as tf
from tests.project import write_params

METHODS = ("radius", "via", "mia", "ae", "kalman_cv", "kalman_ca", "imm", "imm_gnn")
WINDOW_M = 4000.0

# Third-party deprecation notices (Lightning's pytree use), not ours.
pytestmark = pytest.mark.filterwarnings("ignore:.*LeafSpec.* is deprecated")


@pytest.fixture(scope="module")
def params():
    return tf.make_params()


@pytest.fixture(scope="module")
def models_dir(tmp_path_factory) -> Path:
    return tf.trained_models(tmp_path_factory)


@pytest.fixture(scope="module")
def models(models_dir):
    return tf.load_models(models_dir)


def run(features: np.ndarray, plot_ids: np.ndarray, method: str, models, params, window_m: float = WINDOW_M
        ) -> dict[str, np.ndarray]:
    return track(tf.plots_of(features, plot_ids, params.radar),
                 registry.compose(method, models, params.tracker, window_m, params.tracker.seed))


def recording_plots(plots: pa.Table, radars: pa.Table, params, source: str = "test") -> plot_table.Plots:
    """The plot table of a `track` input table and radar description."""
    return plot_table.plot_table(plots, plot_table.sensors(radars, params.radar), source)


def status(weight: float, tracker) -> str:
    return ThesisWeights.from_params(tracker.management).status(weight)


def expected_weights(count: int) -> list[float]:
    return [min(0.4 + 0.2 * n, 1.0) for n in range(count)]


# ----------------------------------------------------------------------------- the tiny models

def test_trained_predictor_extrapolates_a_straight_track_within_a_few_hundred_metres(models, params):
    """With 2 to 5 states of a constant-velocity flight (100-300 m/s), the predicted position 6 s after the
    last state is within 500 m of the truth (mean under 250 m): good enough for a 4 km VIA window."""
    estimator = NetworkEstimator(models)
    rng = np.random.default_rng(3)
    for states in (2, 3, 5):
        errors = []
        for _ in range(100):
            distance, bearing, heading = rng.uniform(30e3, 250e3), rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi)
            speed = rng.uniform(100.0, 300.0)
            flight = tf.straight_features(params.radar, (distance * np.sin(bearing), distance * np.cos(bearing),
                                                         rng.uniform(2000.0, 11000.0)),
                                          (speed * np.sin(heading), speed * np.cos(heading), 0.0), states + 1)
            live = LiveTracks(tf.plots_of(flight, np.arange(states + 1), params.radar),
                              ThesisWeights.from_params(params.tracker.management),
                              latest_plots=estimator.latest_plots)
            slot = np.array([live.start(0)])
            live.tracks[slot[0]].memory = list(flight[:states])
            assert estimator.state_windows(live, slot, flight[states, 0])[1][0] == 5 - states
            predicted = estimator.predict(live, slot, flight[states, 0])
            errors.append(np.linalg.norm(predicted.positions[0] - flight[states, 1:4]))
        assert np.max(errors) < 500.0 and np.mean(errors) < 250.0, (states, np.mean(errors), np.max(errors))


def test_autoencoder_model_carries_its_calibrated_threshold(models):
    assert models["autoencoder"].extras["threshold"] > 0.0
    assert 0.0 <= models["autoencoder"].extras["false_windows_rejected"] <= 1.0


# ----------------------------------------------------------------------------- 1a: one clean target

@pytest.mark.parametrize("method", METHODS)
def test_straight_target_without_clutter_gives_one_confirmed_track_holding_every_plot(method, models, params):
    """40 plots of a straight 216 m/s flight at FL300, 6 s apart: one track with all plots in order;
    weights 0.4, 0.6, 0.8, then 1.0 from the third association on; young tracks (1 plot; 4 for AE)
    are gated by the radius, then the method's gate decides."""
    features = tf.straight_features(params.radar, (50e3, 80e3, 9000.0), (-180.0, 120.0, 0.0), 40)
    ids = np.arange(1000, 1040)
    updates = run(features, ids, method, models, params)
    assert set(updates) >= {"track_id", "plot_id", "weight", "association"}
    assert np.unique(updates["track_id"]).tolist() == [0]
    assert updates["plot_id"].tolist() == ids.tolist()
    np.testing.assert_allclose(updates["weight"], expected_weights(40), atol=1e-9)
    assert updates["weight"][:4].tolist() == pytest.approx([0.4, 0.6, 0.8, 1.0])
    assert [status(w, params.tracker) for w in updates["weight"][:4]] == [
        "tentative", "tentative", "candidate", "confirmed"]
    young = {"radius": 39, "via": 1, "mia": 1, "ae": 4}.get(method, 1)
    assert updates["association"].tolist() == ["start"] + ["radius"] * young + [method] * (39 - young)
    assert np.isnan(updates["association_error"][0])
    assert ((updates["association_error"][1:] >= 0.0) & (updates["association_error"][1:] < 1.0)).all()
    # A track's start is its plot; the time of every update is its plot's.
    np.testing.assert_array_equal(np.array([updates[c][0] for c in ("time_unix_s", "x_ecef_m", "y_ecef_m", "z_ecef_m")]),
                                  features[0, :4])
    np.testing.assert_array_equal(updates["time_unix_s"], features[:, 0])


def test_straight_noisy_target_stays_one_track_with_via(models, params):
    """The same flight with 50 m measurement noise: still one track holding all 40 plots, and once the
    filter network runs (10 plots) the states are closer to the truth than the limit of a 4 km window."""
    true = tf.straight_features(params.radar, (-120e3, 30e3, 7000.0), (150.0, 150.0, 0.0), 40)
    rng = np.random.default_rng(8)
    times, enu = tf.straight_enu((-120e3, 30e3, 7000.0), (150.0, 150.0, 0.0), 40)
    noisy = tf.enu_to_features(times, enu + rng.normal(0.0, 50.0, enu.shape), params.radar)
    updates = run(noisy, np.arange(40), "via", models, params)
    assert np.unique(updates["track_id"]).tolist() == [0]
    states = np.column_stack([updates["x_ecef_m"], updates["y_ecef_m"], updates["z_ecef_m"]])
    assert np.linalg.norm(states[10:] - true[10:, 1:4], axis=1).max() < 1000.0


@pytest.mark.parametrize("method", (*METHODS, "oracle"))
def test_no_plots_give_no_updates(method, models, params):
    updates = track(tf.plots_of(np.empty((0, 5)), np.empty(0, dtype=np.int64), params.radar, np.empty(0)),
                    registry.compose(method, models, params.tracker, WINDOW_M, params.tracker.seed))
    assert all(len(values) == 0 for values in updates.values())
    assert updates["position_covariance"].shape == (0, 3, 3)


# ----------------------------------------------------------------------------- 1b: clutter alone

@pytest.mark.parametrize("method", METHODS)
def test_clutter_alone_never_confirms_a_track(method, models, params):
    """30 scans of Poisson(8) uniform plots over a 400 km box (seeded): every plot gives one update,
    and no update ever reaches the confirmed (or even the candidate) weight."""
    clutter = tf.clutter_features(params.radar, 30, 8.0, np.random.default_rng(2024))
    assert 180 < len(clutter) < 300
    updates = run(clutter, np.arange(len(clutter)), method, models, params)
    assert len(updates["plot_id"]) == len(clutter)
    assert sorted(updates["plot_id"].tolist()) == list(range(len(clutter)))
    assert updates["weight"].max() < params.tracker.management.weight_candidate - 1e-9
    assert "confirmed" not in {status(w, params.tracker) for w in updates["weight"]}


@pytest.mark.parametrize("method", ("via", "mia", "ae", "kalman_cv", "imm", "imm_gnn"))
def test_target_in_clutter_keeps_its_own_plots(method, models, params):
    """A straight target among 8 clutter plots per scan: its plots form one track, confirmed from its 4th
    plot on, and no clutter plot is associated to a confirmed track."""
    rng = np.random.default_rng(77)
    target = tf.straight_features(params.radar, (20e3, -90e3, 10000.0), (230.0, 40.0, 0.0), 30)
    clutter = tf.clutter_features(params.radar, 30, 8.0, rng)
    features, ids = tf.merge((target, np.arange(30)), (clutter, 100 + np.arange(len(clutter))))
    updates = run(features, ids, method, models, params)
    target_rows = updates["plot_id"] < 100
    assert len(np.unique(updates["track_id"][target_rows])) == 1
    track = updates["track_id"][target_rows][0]
    assert updates["plot_id"][updates["track_id"] == track].tolist() == list(range(30))
    confirmed = updates["weight"] >= 1.0 - 1e-9
    assert (updates["plot_id"][confirmed] < 100).all()
    assert confirmed[target_rows].sum() == 27


@pytest.mark.parametrize("method", ["via", "ae"])
def test_network_methods_tracked_in_chunks_give_the_updates_of_tracking_whole(method, models, params):
    """Chunks of 1 and 7 plots, shorter than the filter network's 10-plot window and the
    autoencoder's 5: what a track carries into the next chunk (its first plot and the latest its
    roles read) gives the whole recording's updates bit for bit, on tracks longer than the windows."""
    tracker = lambda: registry.compose(method, models, params.tracker, WINDOW_M, params.tracker.seed)
    assert tracker().latest_plots == models["filter"].config.input_steps - 1  # the widest window read
    whole = tf.assert_chunked_as_whole(tf.busy_recording(params.radar), tracker, (1, 7))
    assert max(map(len, tf.tracks_of(whole).values())) > models["filter"].config.input_steps

# ----------------------------------------------------------------------------- 1c: deletion

def live_track(params, weight_steps: int, time: float = 0.0, later: tuple[float, ...] = ()) -> LiveTracks:
    """One live track started at `time`, then associated `weight_steps` times at the same instant; its
    plots table also holds plots at the `later` times (rows weight_steps + 1 on), not yet associated."""
    times = np.array([time] * (weight_steps + 1) + list(later))
    features = np.column_stack([times, np.tile([2.9e6, 1.3e6, 5.5e6, 1.0e5], (len(times), 1))])
    live = LiveTracks(tf.plots_of(features, np.arange(len(times)), params.radar),
                      ThesisWeights.from_params(params.tracker.management), latest_plots=0)
    slot = live.start(0)
    for row in range(1, weight_steps + 1):
        live.associate(slot, row, features[row, 1:4])
    return live


def test_documented_weights_and_silence(params):
    tracker = params.tracker.management
    assert (tracker.weight_start, tracker.weight_candidate, tracker.weight_confirmed, tracker.weight_step,
            tracker.silence_s) == (0.4, 0.8, 1.0, 0.2, 12.0)


def test_new_track_is_deleted_after_one_silence_period(params):
    """Start weight 0.4: still alive 11.999 s later; at 12.01 s lowered at the start weight, so deleted."""
    live = live_track(params, 0, time=100.0)
    assert live.manage(111.999) == []
    assert len(live) == 1 and live.weight[live.alive][0] == pytest.approx(0.4)
    removed = live.manage(112.01)
    assert [track.track_id for track in removed] == [0] and len(live) == 0


def test_confirmed_track_drops_to_candidate_after_12_s_and_is_deleted_after_24_s(params):
    """Weight 1.0 (three associations at t=100): 1.0 until 112, 0.8 from 112 to 124, deleted after 124."""
    live = live_track(params, 3, time=100.0)
    assert live.weight[live.alive][0] == pytest.approx(1.0)
    assert live.manage(111.999) == [] and live.weight[live.alive][0] == pytest.approx(1.0)
    assert live.manage(112.01) == [] and live.weight[live.alive][0] == pytest.approx(0.8)
    assert live.manage(123.999) == [] and live.weight[live.alive][0] == pytest.approx(0.8)
    removed = live.manage(124.01)
    assert [track.track_id for track in removed] == [0] and len(live) == 0


def test_two_silence_periods_in_one_call_delete_a_confirmed_track(params):
    """Management first run 24.01 s after the last association lowers twice: 1.0 -> 0.8 -> deleted;
    23.999 s after it lowers once."""
    once = live_track(params, 3)
    assert once.manage(23.999) == [] and once.weight[once.alive][0] == pytest.approx(0.8)
    twice = live_track(params, 3)
    assert len(twice.manage(24.01)) == 1 and len(twice) == 0


@pytest.mark.parametrize("steps, after_12_s", [(2, None), (1, 0.4), (0, None)])
def test_lower_weights_die_at_the_candidate_or_start_weight(params, steps, after_12_s):
    """A candidate (0.8) is deleted at its first lowering, 12 s after its last association; a 0.6 track is
    lowered to 0.4 at 12 s and deleted at 24 s; a new track (0.4) is deleted at 12 s. (None: deleted.)"""
    live = live_track(params, steps)
    assert live.weight[live.alive][0] == pytest.approx(0.4 + 0.2 * steps)
    assert live.manage(11.999) == [] and len(live) == 1
    live.manage(12.01)
    if after_12_s is None:
        assert len(live) == 0
        return
    assert len(live) == 1 and live.weight[live.alive][0] == pytest.approx(after_12_s)
    assert live.manage(23.999) == [] and len(live) == 1
    assert len(live.manage(24.01)) == 1 and len(live) == 0


def test_an_association_restarts_the_silence_clock(params):
    """Associated again at t=10, a confirmed track is not lowered at 12.01 but at 22.01."""
    live = live_track(params, 3, later=(10.0,))
    slot = int(np.flatnonzero(live.alive)[0])
    live.associate(slot, 4, live.plots.position[4])
    assert live.manage(12.01) == [] and live.weight[slot] == pytest.approx(1.0)
    assert live.manage(21.999) == [] and live.weight[slot] == pytest.approx(1.0)
    assert live.manage(22.01) == [] and live.weight[slot] == pytest.approx(0.8)


@pytest.mark.parametrize("gap_s, same_track", [(18.0, True), (30.0, False)])
def test_target_that_falls_silent_is_kept_18_s_and_gone_after_24_s(gap_s, same_track, models, params):
    """A confirmed target silent for 18 s (lowered once, to 0.8) is picked up again by its own track
    (back to 1.0); silent for 30 s it was deleted at 24 s and its next plot starts a new track (0.4).
    Radius association with a 10 km radius, so only management decides."""
    first = tf.straight_features(params.radar, (0.0, 100e3, 9000.0), (200.0, 0.0, 0.0), 6)
    times, enu = tf.straight_enu((0.0, 100e3, 9000.0), (200.0, 0.0, 0.0), 1)
    resumed_enu = enu + np.array([200.0 * (30.0 + gap_s), 0.0, 0.0])
    resumed = tf.enu_to_features(times + 30.0 + gap_s, resumed_enu, params.radar)
    features = np.concatenate([first, resumed])
    updates = run(features, np.arange(7), "radius", models, params, window_m=10000.0)
    assert updates["weight"][5] == pytest.approx(1.0)
    if same_track:
        assert updates["track_id"].tolist() == [0] * 7
        assert updates["weight"][6] == pytest.approx(1.0)
    else:
        assert updates["track_id"].tolist() == [0] * 6 + [1]
        assert updates["association"][6] == "start" and updates["weight"][6] == pytest.approx(0.4)


# ----------------------------------------------------------------------------- 1d: two targets

@pytest.mark.parametrize("method", METHODS)
def test_two_targets_far_apart_give_two_tracks_of_their_own_plots(method, models, params):
    """Two flights 60 km apart (beyond the 20 km pre-filter), interleaved in time: two tracks, each with
    all of its target's plots and no other, both confirmed."""
    a = tf.straight_features(params.radar, (-50e3, 120e3, 9000.0), (220.0, 0.0, 0.0), 25)
    b = tf.straight_features(params.radar, (-50e3, 60e3, 6000.0), (0.0, -150.0, 0.0), 25, t_offset=2.5)
    features, ids = tf.merge((a, np.arange(25)), (b, 100 + np.arange(25)))
    updates = run(features, ids, method, models, params)
    tracks = tf.tracks_of(updates)
    assert sorted(tracks.values()) == [list(range(25)), list(range(100, 125))]
    for track_id in tracks:
        weights = updates["weight"][updates["track_id"] == track_id]
        np.testing.assert_allclose(weights, expected_weights(25), atol=1e-9)


# ----------------------------------------------------------------------------- 4: anywhere on Earth

FINLAND = (60.3172, 24.9633, 60.0)
AUSTRALIA = (-33.9461, 151.1772, 60.0)  # near Sydney, the antenna at the same height


def scenario_measurements(radar, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Two targets and clutter within 150 km of the radar (ECEF features, plot ids)."""
    a = tf.straight_features(radar, (-40e3, 70e3, 9000.0), (210.0, -60.0, 0.0), 30)
    b = tf.straight_features(radar, (60e3, -50e3, 5000.0), (-30.0, 160.0, 0.0), 30, t_offset=3.1)
    clutter = tf.clutter_features(radar, 30, 6.0, rng, half_width_m=150000.0)
    return tf.merge((a, np.arange(30)), (b, 100 + np.arange(30)), (clutter, 1000 + np.arange(len(clutter))))


def test_same_scenario_at_two_radar_sites_gives_the_same_tracks_in_the_default_frame(models_dir):
    """The same measurements (slant range, azimuth, altitude, with noise) tracked by a radar in Finland
    and one in Australia, with networks scaled in the default `radial` frame: identical tracks, plot
    ids, association kinds and weights, and states that agree in each radar's own ENU frame.

    The states cannot agree exactly: eq. 4.2 places a plot with the meridian radius at the radar's
    latitude (6 384 km at 60 N, 6 355 km at 34 S), which moves the elevation, and so the ENU up
    coordinate, by about r^2/(2R) * dR/R: 8 m at 150 km. The networks see their windows in the radial frame
    of each window's origin, whose relation to the radar's frame also depends slightly on the
    ellipsoid's curvature there, and a network can amplify small input differences. 50 m covers
    this; a frame error would show as kilometres.
    """
    params = tf.make_params()
    radars = [tf.radar_at(params.radar, *FINLAND), tf.radar_at(params.radar, *AUSTRALIA)]
    features, ids = scenario_measurements(radars[0], np.random.default_rng(31))
    measured = tf.measurement_table(features, ids, radars[0], radar_id=1, scenario_id=4)
    rng = np.random.default_rng(5)
    noise = {"range_m": rng.normal(0.0, 40.0, len(ids)), "azimuth_deg": rng.normal(0.0, 0.05, len(ids)),
             "altitude_m": rng.normal(0.0, 30.0, len(ids))}
    for name, values in noise.items():
        index = measured.schema.get_field_index(name)
        measured = measured.set_column(index, measured.schema.field(name),
                                       pa.array(measured.column(name).to_numpy() + values))
    results = [track_recording(recording_plots(measured, tf.radar_table(1, radar), params), "via", WINDOW_M, params,
                               models_dir) for radar in radars]
    finland, australia = results
    assert finland.num_rows == australia.num_rows == len(ids)
    for column in ("track_id", "plot_id", "association", "status", "time_unix_s", "radar_id", "scenario_id"):
        assert finland.column(column).to_pylist() == australia.column(column).to_pylist(), column
    np.testing.assert_allclose(finland.column("weight").to_numpy(), australia.column("weight").to_numpy(), atol=1e-12)
    tracks = tf.tracks_of({name: finland.column(name).to_numpy() for name in ("track_id", "plot_id")})
    assert list(range(30)) in tracks.values() and list(range(100, 130)) in tracks.values()
    assert finland.column("status").to_pylist().count("confirmed") >= 50
    ecef = [np.column_stack([table.column(f"{axis}_ecef_m").to_numpy() for axis in "xyz"]) for table in results]
    enu = [tf.ecef_to_enu(states, radar) for states, radar in zip(ecef, radars)]
    # The two runs are really at two places on Earth ...
    assert np.linalg.norm(ecef[0] - ecef[1], axis=1).min() > 1e6
    # ... and agree in their own radar's frame.
    np.testing.assert_allclose(enu[0], enu[1], rtol=0.0, atol=50.0)
    # The output range is from each plot's radar to the track's position, so it agrees as the positions do.
    np.testing.assert_allclose(finland.column("range_m").to_numpy(), australia.column("range_m").to_numpy(),
                               rtol=0.0, atol=50.0)


# ----------------------------------------------------------------------------- 5: bad input for `track`

@pytest.fixture(scope="module")
def recording(params):
    """A straight target and clutter as seen by the default radar (id 1), scenario 3."""
    rng = np.random.default_rng(12)
    target = tf.straight_features(params.radar, (30e3, 40e3, 8000.0), (-200.0, 50.0, 0.0), 20)
    clutter = tf.clutter_features(params.radar, 20, 5.0, rng)
    features, ids = tf.merge((target, np.arange(20)), (clutter, 100 + np.arange(len(clutter))))
    return (tf.measurement_table(features, ids, params.radar, params.radar.radar_id, scenario_id=3),
            tf.radar_table(params.radar.radar_id, params.radar))


def assert_same_table(got: pa.Table, expected: pa.Table) -> None:
    """Equal schema and values, NaN equal to NaN (pa.Table.equals treats NaN as unequal)."""
    assert got.schema.equals(expected.schema)
    for name in expected.column_names:
        np.testing.assert_array_equal(got.column(name).to_numpy(zero_copy_only=False),
                                      expected.column(name).to_numpy(zero_copy_only=False), err_msg=name)


def test_track_recording_tracks_the_target(recording, params, models_dir):
    plots, radars = recording
    table = track_recording(recording_plots(plots, radars, params), "via", WINDOW_M, params, models_dir)
    assert table.num_rows == plots.num_rows
    target = table.filter(pc.less(table.column("plot_id"), 100))
    assert len(set(target.column("track_id").to_pylist())) == 1
    assert target.column("status").to_pylist()[3:] == ["confirmed"] * 17
    assert set(table.column("scenario_id").to_pylist()) == {3}
    assert set(table.column("radar_id").to_pylist()) == {params.radar.radar_id}


def test_plots_missing_a_column_name_the_file_and_column_and_write_nothing(recording, params, models_dir, tmp_path,
                                                                           caplog):
    """`track --plots` without azimuth_deg: exit 2, the file and the column named, no output."""
    plots_path, radar_path = tf.write_recording(tmp_path, recording[0].drop_columns(["azimuth_deg"]), recording[1])
    params_path = write_params(tf.params_tree(), tmp_path / "params.yaml")
    out = tmp_path / "tracks.parquet"
    code = cli.main(["track", "--params", str(params_path), "--plots", str(plots_path), "--radar", str(radar_path),
                     "--models", str(models_dir), "--out", str(out)])
    assert code == 2
    assert f"{plots_path}: column 'azimuth_deg' is missing" in caplog.text
    assert not out.exists()


def test_nan_range_names_the_column_and_writes_nothing(recording, params, models_dir, tmp_path):
    plots, radars = recording
    range_m = plots.column("range_m").to_numpy().copy()
    range_m[7] = np.nan
    plots = plots.set_column(plots.schema.get_field_index("range_m"), plots.schema.field("range_m"),
                             pa.array(range_m))
    plots_path, radar_path = tf.write_recording(tmp_path, plots, radars)
    out = tmp_path / "tracks.parquet"
    with pytest.raises(io.InputError, match=r"column 'range_m' is NaN in 1 rows") as error:
        run_track(params, plots_path, radar_path, [], None, "via", WINDOW_M, models_dir, out)
    assert str(plots_path) in str(error.value)
    assert not out.exists()


def test_plots_of_a_radar_not_in_the_description_are_refused(recording, params, models_dir, tmp_path):
    plots, _ = recording
    other = tf.radar_table(9, params.radar)
    plots_path, radar_path = tf.write_recording(tmp_path, plots, other)
    out = tmp_path / "tracks.parquet"
    with pytest.raises(io.InputError, match="radar id 1") as error:
        run_track(params, plots_path, radar_path, [], None, "via", WINDOW_M, models_dir, out)
    assert str(plots_path) in str(error.value) and "[9]" in str(error.value)
    assert not out.exists()


def test_models_built_with_another_scaler_are_refused(recording, models_dir, tmp_path):
    """Params whose windows.position_max_diff_m differs from the models' scaler: InputError naming the
    model file and 'scaler', before tracking, and no output."""
    other = tf.make_params({"windows.position_max_diff_m": 500.0})
    with pytest.raises(io.InputError, match="scaler") as error:
        load_models(models_dir, other, ["via"])
    assert str(models_dir / "predictor.pt") in str(error.value)
    plots_path, radar_path = tf.write_recording(tmp_path, *recording)
    out = tmp_path / "tracks.parquet"
    with pytest.raises(io.InputError, match="scaler"):
        run_track(other, plots_path, radar_path, [], None, "via", WINDOW_M, models_dir, out)
    assert not out.exists()


def test_plots_out_of_time_order_are_sorted(recording, params, models_dir, tmp_path, caplog):
    """A shuffled recording gives exactly the result of the time-sorted one, with a warning."""
    plots, radars = recording
    order = np.argsort(plots.column("time_unix_s").to_numpy(), kind="stable")
    assert np.unique(plots.column("time_unix_s").to_numpy()).size == plots.num_rows  # no ties to reorder
    shuffled = plots.take(np.random.default_rng(4).permutation(plots.num_rows))
    expected = track_recording(recording_plots(plots.take(order), radars, params), "via", WINDOW_M, params, models_dir)
    with caplog.at_level("WARNING", logger="pipeline"):
        got = track_recording(recording_plots(shuffled, radars, params, "shuffled"), "via", WINDOW_M, params,
                              models_dir)
    assert_same_table(got, expected)
    assert "out of time order" in caplog.text
    # Through the command too: the file written is the same.
    plots_path, radar_path = tf.write_recording(tmp_path, shuffled, radars)
    run_track(params, plots_path, radar_path, [], None, "via", WINDOW_M, models_dir, tmp_path / "tracks.parquet")
    assert_same_table(pq.read_table(tmp_path / "tracks.parquet"), expected)


def test_mia_tracks_a_recording_without_scenario_ids(recording, params, models_dir):
    """`track --method mia` on plots without a scenario_id (optional in the Parquet input, always absent
    from ASTERIX input) tracks them like any other recording."""
    plots, radars = recording
    plots = plots.set_column(plots.schema.get_field_index("scenario_id"), plots.schema.field("scenario_id"),
                             pa.nulls(plots.num_rows, pa.int32()))
    table = track_recording(recording_plots(plots, radars, params), "mia", WINDOW_M, params, models_dir)
    assert table.num_rows == plots.num_rows

"""The network-scaled filter in the tracker (`pipeline.tracker.kalman_net_estimator`), registered as
`kalman_net`: with the network's scales pinned to 1 (an untrained network) it tracks exactly as
the classical estimator with the same filter; `track --method kalman_net` runs it from
`models/kalman_net.pt`. A straight flight in clutter, no training.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from pipeline import io
from pipeline.filters.torch_filters import SequenceBatch
from pipeline.learning.kalman_net import KalmanNet, KalmanNetConfig
from pipeline.learning.model_store import save_network
from pipeline.tracker import registry
from pipeline.tracker.kalman import KalmanEstimator
from pipeline.tracker.kalman_net_estimator import KalmanNetEstimator
from pipeline.tracker.loading import load_models
from pipeline.tracker.management import ThesisWeights
from pipeline.tracker.models import Models
from pipeline.tracker.run import track
from pipeline.tracker.tracks import LiveTracks
from tests import tracker_fixtures as tf
from tests.test_track_command import track_command, two_radar_recording


@pytest.fixture(scope="module")
def params():
    return tf.make_params()


def pinned_network(params, hidden: int = 4) -> KalmanNet:
    """An untrained network-scaled CV filter (every scale 1) with the untuned classical CV filter's
    noise and start spread, its GRU weights random so that the features do reach it."""
    cv = tf.untuned_filters(params)["cv"]
    config = KalmanNetConfig("cv", "gru", hidden, cv.noise_std[0], 30.0, cv.velocity_std_mps, cv.acceleration_std_mps2,
                             r0_scale=1.0, q_amplitude=50.0, r_amplitude=4.0, manoeuvre_amplitude=10.0,
                             velocity_scale_mps=400.0, nis_scale=10.0)
    torch.manual_seed(5)
    model = KalmanNet(config)
    with torch.no_grad():
        for parameter in model.network.body.parameters():
            parameter.normal_()
    return model.eval()


def test_pinned_scales_track_as_the_kalman_estimator_with_the_same_filter(params):
    """Two crossing flights in clutter tracked by `kalman_net` (an untrained network) and by
    `kalman_cv` (the same CV filter): the same updates, plot for plot and track for track, with the
    same positions and covariances to rounding, through the chi-square gate and the young-track radius."""
    rng = np.random.default_rng(7)
    first = tf.straight_features(params.radar, (40e3, 60e3, 9000.0), (180.0, 90.0, 0.0), 20)
    second = tf.straight_features(params.radar, (40e3, 70e3, 8000.0), (180.0, -60.0, 0.0), 20, t_offset=2.0)
    first[:, 1:4] += rng.normal(0.0, 40.0, (len(first), 3))
    clutter = tf.clutter_features(params.radar, 20, 3.0, rng, half_width_m=80000.0)
    features, ids = tf.merge((first, np.arange(20)), (second, 100 + np.arange(20)),
                             (clutter, 1000 + np.arange(len(clutter))))
    plots = tf.plots_of(features, ids, params.radar)
    models = Models({"kalman_tuned": tf.untuned_filters(params), "kalman_net": pinned_network(params)})
    network, classical = (track(plots, registry.compose(name, models, params.tracker, 4000.0, 0))
                          for name in ("kalman_net", "kalman_cv"))
    for column in ("track_id", "plot_id"):
        np.testing.assert_array_equal(network[column], classical[column])
    gated = network["association"] == "kalman_net"
    np.testing.assert_array_equal(gated, classical["association"] == "kalman_cv")
    assert gated.sum() >= 30  # both flights' mature updates
    for column in ("x_ecef_m", "y_ecef_m", "z_ecef_m"):
        np.testing.assert_allclose(network[column], classical[column], rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(network["position_covariance"], classical["position_covariance"], rtol=1e-9)


def test_prediction_without_a_plot_is_the_kalman_estimators_with_pinned_scales(params):
    """`predict` (no plot, so no network step: the scales of the track's last plot) of a track started
    at its first plot and updated with its second equals the classical CV estimator's prediction."""
    flight = tf.straight_features(params.radar, (40e3, 60e3, 9000.0), (180.0, 90.0, 0.0), 3)
    plots = tf.plots_of(flight, np.arange(3), params.radar)
    predictions = []
    for estimator in (KalmanNetEstimator(pinned_network(params)), KalmanEstimator(tf.untuned_filters(params)["cv"])):
        live = LiveTracks(plots, ThesisWeights.from_params(params.tracker.management),
                          latest_plots=estimator.latest_plots)
        slot = live.start(0)
        estimator.start(live, slot)
        live.associate(slot, 1, estimator.update(live, slot, 1, None, 0)[0])
        predictions.append(estimator.predict(live, np.array([slot]), plots.time[2]))
    np.testing.assert_allclose(predictions[0].positions, predictions[1].positions, rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(predictions[0].covariances, predictions[1].covariances, rtol=1e-9)


@pytest.mark.parametrize("base", ["cv", "singer"])
def test_a_track_is_filtered_as_in_training(params, base):
    """A track updated plot by plot (the update stepping itself, as for a young track) gives the
    positions and covariances of the training recursion (`KalmanNet.forward`) over the same plots,
    with a network whose scales are not 1."""
    config = replace(pinned_network(params).config, base=base, r0_scale=1.5)
    torch.manual_seed(6)
    model = KalmanNet(config)
    with torch.no_grad():
        for parameter in model.network.parameters():
            parameter.normal_(0.0, 0.5)
    model.eval()
    flight = tf.straight_features(params.radar, (40e3, 60e3, 9000.0), (180.0, 90.0, 0.0), 8)
    flight[:, 1:4] += np.random.default_rng(8).normal(0.0, 60.0, (len(flight), 3))
    plots = tf.plots_of(flight, np.arange(len(flight)), params.radar)
    estimator = KalmanNetEstimator(model)
    live = LiveTracks(plots, ThesisWeights.from_params(params.tracker.management), latest_plots=estimator.latest_plots)
    slot = live.start(0)
    estimator.start(live, slot)
    stepped = [estimator.update(live, slot, row, None, 0) for row in range(1, len(flight))]
    as_batch = lambda values: torch.as_tensor(values)[None]
    valid = torch.ones((1, len(flight)), dtype=torch.bool)
    with torch.no_grad():
        trained = model(SequenceBatch(as_batch(plots.time), as_batch(plots.position), as_batch(plots.covariance),
                                      as_batch(plots.position), valid, torch.arange(len(flight))[None] == 0, valid))
    np.testing.assert_allclose(np.array([p for p, _ in stepped]), trained.position[0, 1:].numpy(), rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(np.array([c for _, c in stepped]), trained.covariance[0, 1:].numpy(), rtol=1e-9)


def test_track_runs_kalman_net_from_its_model_file_and_names_the_stage_when_it_is_missing(params, tmp_path):
    """`track --method kalman_net` with `kalman_net.pt` in the models folder: exit 0, the target of a
    two-radar recording one confirmed track. Without the file:
    io.InputError naming it and `dvc repro train_kalman_net`."""
    models = tmp_path / "models"
    with pytest.raises(io.InputError, match=r"kalman_net.pt: file not found; kalman_net needs it .*"
                                            r"dvc repro train_kalman_net"):
        load_models(models, params, ["kalman_net"])
    save_network(models / "kalman_net.pt", pinned_network(params))
    plots, radars, target_ids = two_radar_recording(params, np.random.default_rng(2))
    assert track_command(tmp_path, models, "kalman_net", plots, radars) == 0
    tracks = pq.read_table(tmp_path / "tracks.parquet").to_pydict()
    target = np.isin(tracks["plot_id"], target_ids)
    assert len(set(np.asarray(tracks["track_id"])[target].tolist())) == 1
    assert np.asarray(tracks["status"])[target].tolist()[-1] == "confirmed"

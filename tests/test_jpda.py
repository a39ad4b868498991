"""Joint probabilistic data association (`pipeline.tracker.jpda`, the `*_jpda` methods): its marginal
probabilities against the joint events enumerated by hand, its update against the PDA's closed form, and
the tracker it makes on flights built here."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pipeline.filters import batch_filters
from pipeline.filters.batch_filters import BatchState
from pipeline.recordings.plot_table import NO_TARGET
from pipeline.tracker import jpda, registry
from pipeline.tracker.models import Models
from pipeline.tracker.run import track
from tests import tracker_fixtures as tf
from tests.test_kalman_tracker import crossing_flights_among_clutter


@pytest.fixture(scope="module")
def params():
    return tf.make_params()


def enumerated(valid: np.ndarray, likelihood: np.ndarray, missed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every joint event of tracks (rows of `valid`, (T, D)) and plots summed by brute force: each track
    one valid plot or none, no plot twice; an event's weight the product of its tracks' likelihoods."""
    tracks, plots = valid.shape
    weight_of = np.zeros((tracks, plots + 1))
    total = 0.0
    for event in itertools.product(range(plots + 1), repeat=tracks):
        taken = [plot for plot in event if plot]
        if len(taken) != len(set(taken)) or any(plot and not valid[i, plot - 1] for i, plot in enumerate(event)):
            continue
        weight = np.prod([likelihood[i, plot - 1] if plot else missed[i] for i, plot in enumerate(event)])
        total += weight
        for i, plot in enumerate(event):
            weight_of[i, plot] += weight
    return weight_of[:, 1:] / total, weight_of[:, 0] / total


def test_marginals_are_the_joint_events_summed():
    """Three tracks sharing four plots (one cluster, EHM2) and a fifth track alone with two plots (the closed
    form): each hypothesis's probability and each track's probability of none are the sums over the joint
    events enumerated one by one; a track's probabilities sum to 1."""
    rng = np.random.default_rng(4)
    valid = np.array([[1, 1, 0, 0, 0, 0], [0, 1, 1, 1, 0, 0], [1, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 1]], dtype=bool)
    likelihood = rng.uniform(0.1, 5.0, valid.shape)
    log_missed = np.log(0.3)
    track, plot = np.nonzero(valid)
    weights, missed = jpda.marginals(track, plot, np.log(likelihood[track, plot]), log_missed, len(valid))
    expected, expected_missed = enumerated(valid, likelihood, np.full(len(valid), 0.3))
    np.testing.assert_allclose(weights, expected[track, plot], rtol=1e-12)
    np.testing.assert_allclose(missed, expected_missed, rtol=1e-12)
    np.testing.assert_allclose(missed + np.bincount(track, weights), 1.0, rtol=1e-12)


def test_marginals_survive_likelihoods_far_below_a_doubles_range():
    """Log-likelihoods of -2000 (a plot at the gate's edge with a tiny clutter density gives such
    magnitudes the other way) are scaled per track before they leave log space: no NaN, and a plot
    e^-5 less likely than its neighbour takes e^-5 of its weight."""
    weights, missed = jpda.marginals(np.array([0, 0]), np.array([0, 1]), np.array([-2000.0, -2005.0]), -3000.0, 1)
    np.testing.assert_allclose(weights, [1 / (1 + np.exp(-5)), np.exp(-5) / (1 + np.exp(-5))], rtol=1e-12)
    assert missed[0] == 0.0 or missed[0] < 1e-300


def test_pda_update_of_one_filter_is_the_closed_form(params):
    """A CV filter's track with three plots of one covariance R in its gate: the merged update (each
    hypothesis's Kalman update, moment-matched) is the PDA's closed form, x = x^- + K sum_j beta_j nu_j,
    P = beta_0 P^- + (1 - beta_0) (I - K H) P^- + K (sum_j beta_j nu_j nu_j' - nu nu') K'."""
    settings = tf.untuned_filters(params)["cv"]
    rng = np.random.default_rng(2)
    n = 6
    root = rng.normal(0.0, 1.0, (n, n))
    prior = BatchState(rng.normal(0.0, 500.0, (1, 1, n)), (root @ root.T * 1e4 + np.eye(n) * 1e4)[None, None],
                       np.ones((1, 1)))
    R = np.diag([150.0, 200.0, 90.0]) ** 2
    plots = prior.x[0, 0, ::2] + rng.normal(0.0, 300.0, (3, 3))
    beta, beta_0 = np.array([0.5, 0.3, 0.15]), 0.05
    each = BatchState(np.repeat(prior.x, 3, axis=0), np.repeat(prior.P, 3, axis=0), np.ones((3, 1)))
    posteriors = batch_filters.updated(settings, each, plots, np.repeat(R[None], 3, axis=0))
    merged = batch_filters.collapsed(prior, posteriors, np.zeros(3, dtype=np.int64), beta, np.array([beta_0]))

    H = np.zeros((3, n))
    H[[0, 1, 2], [0, 2, 4]] = 1.0
    P = prior.P[0, 0]
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    innovations = plots - H @ prior.x[0, 0]
    combined = beta @ innovations
    spread = (beta[:, None, None] * innovations[:, :, None] * innovations[:, None, :]).sum(axis=0)
    x = prior.x[0, 0] + K @ combined
    P_closed = beta_0 * P + (1 - beta_0) * (np.eye(n) - K @ H) @ P + K @ (spread - np.outer(combined, combined)) @ K.T
    np.testing.assert_allclose(merged.x[0, 0], x, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(merged.P[0, 0], P_closed, rtol=1e-8, atol=1e-4)
    np.testing.assert_allclose(merged.mu, 1.0)


def test_one_certain_hypothesis_is_the_plain_update(params):
    """An IMM track whose one plot is certainly its own (beta 1, none 0) gets exactly the update GNN gives
    it, mode probabilities included."""
    settings = tf.untuned_filters(params)["imm"]
    first = batch_filters.start(settings, np.array([[4.0e6, 1.0e6, 4.7e6]]), np.eye(3)[None] * 1e4)
    moved = batch_filters.moved(batch_filters.mixed(settings, first), *np.moveaxis(
        batch_filters.motion(settings, np.array([6.0])), 1, 0))
    plot, R = np.array([[4.0e6 + 800.0, 1.0e6 - 300.0, 4.7e6 + 200.0]]), np.eye(3)[None] * 2e4
    plain = batch_filters.updated(settings, moved, plot, R)
    merged = batch_filters.collapsed(moved, plain, np.array([0]), np.array([1.0]), np.array([0.0]))
    np.testing.assert_allclose(merged.x, plain.x, rtol=1e-13)
    np.testing.assert_allclose(merged.P, plain.P, rtol=1e-12)
    np.testing.assert_allclose(merged.mu, plain.mu, rtol=1e-13)


def composed(method: str, params):
    return registry.compose(method, Models({"kalman_tuned": tf.untuned_filters(params)}), params.tracker, 4000.0, 0)


def positions(updates: dict[str, np.ndarray]) -> np.ndarray:
    return np.column_stack([updates[f"{axis}_ecef_m"] for axis in "xyz"])


@pytest.mark.parametrize("kind", ["kalman_cv", "imm"])
def test_flights_far_apart_are_tracked_as_gnn_tracks_them(params, kind):
    """Eight flights 20 km apart, without clutter: no track has two plots in its gate, and with the default
    clutter density a plot in the gate outweighs none by about a million, so JPDA gives GNN's tracks,
    plot for plot, within a millimetre."""
    busy = tf.busy_recording(params.radar)
    recording = busy.take(np.flatnonzero(busy.target_id != NO_TARGET))
    gnn, joint = track(recording, composed(kind + "_gnn", params)), track(recording, composed(kind + "_jpda", params))
    np.testing.assert_array_equal(joint["plot_id"], gnn["plot_id"])
    np.testing.assert_array_equal(joint["track_id"], gnn["track_id"])
    assert (joint["association"] == kind + "_jpda").sum() > 250
    np.testing.assert_allclose(positions(joint), positions(gnn), atol=1e-3)


def test_two_plots_in_one_gate_pull_the_track_between_them(params):
    """A straight flight's track, mature, meets a scan with two plots 400 m either side of its true
    position, across its path: GNN follows one of them; JPDA weighs them about evenly and its update lies
    near the midpoint, the true position."""
    flight = tf.straight_features(params.radar, (60e3, 20e3, 9000.0), (0.0, 200.0, 0.0), 8)
    east = np.array([1.0, 0.0, 0.0])
    last = flight[-1]
    twins = []
    for side in (-1.0, 1.0):
        plot = last.copy()
        enu = tf.ecef_to_enu(last[None, 1:4], params.radar)[0] + side * 400.0 * east
        plot[1:4] = tf.enu_to_features(np.array([last[0] + 0.01 * (side > 0)]), enu[None], params.radar)[0, 1:4]
        plot[0] += 0.01 * (side > 0)
        twins.append(plot)
    features = np.vstack([flight[:-1], twins])
    recording = tf.plots_of(features, np.arange(len(features)), params.radar)
    truth = last[1:4]
    gnn, joint = track(recording, composed("kalman_cv_gnn", params)), track(recording, composed("kalman_cv_jpda", params))
    misses = []
    for updates in (gnn, joint):
        flown = updates["track_id"] == updates["track_id"][0]
        assert flown.sum() == len(flight)  # the flight's track took one of the twins
        misses.append(np.linalg.norm(positions(updates)[flown][-1] - truth))
    assert misses[0] > 150.0
    assert misses[1] < 60.0


def test_chunks_give_the_whole_recordings_updates(params):
    """The JPDA tracker over a recording read a part at a time gives the updates of the whole, bit for bit."""
    tf.assert_chunked_as_whole(crossing_flights_among_clutter(params), lambda: composed("imm_jpda", params),
                               (37, 150))


def test_every_tuned_filter_has_a_jpda_method():
    """Each classical filter runs under nearest neighbour, GNN and JPDA, and the JPDA method runs that filter."""
    for kind in ("kalman_cv", "kalman_ca", "imm", "imm_ct", "imm_ca_ct"):
        method = registry.method(kind + registry.JPDA_SUFFIX)
        assert method.family == registry.CLASSICAL and method.filter_kind == registry.method(kind).filter_kind


@pytest.mark.parametrize("probabilities", [(1.0, 0.999, 1e-15), (0.9, 0.0, 1e-15), (0.9, 0.999, 0.0)])
def test_impossible_probabilities_are_refused(probabilities):
    with pytest.raises(ValueError, match="JPDA"):
        jpda.JointProbabilisticPerScan(*probabilities)


def test_network_scaled_filter_with_pinned_scales_is_the_kalman_filter_under_jpda(params):
    """`kalman_net_jpda` with a network whose scales are all 1 (`pinned_network`) and `kalman_cv_jpda` (the
    same CV filter) on eight crossing flights among clutter: the same updates, plot for plot and track for
    track, positions to a micrometre, so the soft assigner's update is the same merge for both estimators."""
    from tests.test_kalman_net_tracker import pinned_network
    plots = crossing_flights_among_clutter(params)
    models = Models({"kalman_tuned": tf.untuned_filters(params), "kalman_net": pinned_network(params)})
    network, classical = (track(plots, registry.compose(name, models, params.tracker, 4000.0, 0))
                          for name in ("kalman_net_jpda", "kalman_cv_jpda"))
    for column in ("track_id", "plot_id"):
        np.testing.assert_array_equal(network[column], classical[column])
    assert (network["association"] == "kalman_net_jpda").sum() > 50
    np.testing.assert_allclose(positions(network), positions(classical), rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(network["position_covariance"], classical["position_covariance"], rtol=1e-9)

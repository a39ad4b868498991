"""The tracker's classical estimator and gate (`pipeline.tracker.kalman` on the one Kalman core,
`pipeline.filters.batch_filters`) against filterpy's objects (`pipeline.filters.classical_filters`), step by step.

A turning flight near the radar with 50 m noise and one missed scan, plots placed in ECEF with their
converted-measurement covariance. No networks are needed.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.filters import classical_filters, motion_models
from pipeline.geometry import geodesy
from pipeline.tracker import registry
from pipeline.tracker.gate import ChiSquareGate
from pipeline.tracker.kalman import KalmanEstimator
from pipeline.tracker.management import ThesisWeights
from pipeline.tracker.models import Models
from pipeline.tracker.run import track
from pipeline.tracker.tracks import LiveTracks
from tests import tracker_fixtures as tf

COAST_AT = 9  # the track is predicted at this plot but does not take it (a coast), then takes the next


@pytest.fixture(scope="module")
def params():
    return tf.make_params()


def noisy_turning_flight(params, rng: np.random.Generator, scans: int = 16) -> np.ndarray:
    """[t, x, y, z, r] plots of a 220 m/s flight turning at 2 deg/s, 50 m noise, scan 7 missed."""
    elapsed = np.delete(np.arange(scans) * tf.SCAN_S, 7)
    heading = np.radians(2.0) * elapsed
    enu = np.column_stack([80e3 + 220.0 / np.radians(2.0) * (1.0 - np.cos(heading)),
                           -30e3 + 220.0 / np.radians(2.0) * np.sin(heading), np.full(len(elapsed), 9000.0)])
    return tf.enu_to_features(tf.T0 + elapsed, enu + rng.normal(0.0, 50.0, enu.shape), params.radar)


def moved_east(features: np.ndarray, params, metres: float) -> np.ndarray:
    """The same plots `metres` east (in the radar's local frame)."""
    moved = features.copy()
    moved[:, 1:4] += metres * geodesy.enu_rotation(params.radar.latitude_deg, params.radar.longitude_deg)[0]
    return moved


@pytest.mark.parametrize("kind", classical_filters.KINDS)
def test_tracker_filter_is_filterpys_step_by_step_started_updated_coasted_and_gated(params, kind):
    """One track of the tracker's estimator beside filterpy's filter, started at the same first plot:
    at every later plot the prediction the gate scores with (combined position and covariance; the
    IMM's own predicted density), the chi-square gate's normalised error (d^2 / quantile, d^2 computed
    from filterpy's prediction with np.linalg.solve), the position and covariance after the update and
    the IMM's predicted mode probabilities all equal filterpy's to rounding, and so do the velocity and its
    covariance the estimator gives after the update (of the IMM's mixed models: mixing keeps the moments). A plot 5 km off is gated
    out (infinite error) and changes nothing; at plot COAST_AT the track coasts (predicted, gated, not
    updated) and its next update spans two scans."""
    settings = tf.untuned_filters(params)[kind]
    measured = np.ix_(settings.measured, settings.measured)
    flight = noisy_turning_flight(params, np.random.default_rng(21))
    far = moved_east(flight, params, 5000.0)
    plots = tf.plots_of(np.concatenate([flight, far]), np.arange(2 * len(flight)), params.radar)
    estimator = KalmanEstimator(settings)
    live = LiveTracks(plots, ThesisWeights.from_params(params.tracker.management), latest_plots=estimator.latest_plots)
    gate = ChiSquareGate(params.tracker.association.kalman_gate_probability)
    slot = live.start(0)
    estimator.start(live, slot)
    slots = np.array([slot])
    reference = classical_filters.start_filter(settings, plots.position[0], plots.covariance[0])
    last = plots.time[0]
    gated_out = 0
    for row in range(1, len(flight)):
        prediction = estimator.predict(live, slots, plots.time[row])
        state, covariance = classical_filters.predicted_gaussian(reference, settings, plots.time[row] - last)
        np.testing.assert_allclose(prediction.positions[0], state[settings.measured], rtol=1e-12, atol=1e-6)
        np.testing.assert_allclose(prediction.covariances[0], covariance[measured], rtol=1e-9, atol=1e-6)
        for plot in (row, row + len(flight)):
            innovation = plots.position[plot] - state[settings.measured]
            distance = innovation @ np.linalg.solve(covariance[measured] + plots.covariance[plot], innovation)
            error = gate(live, slots, plot, prediction).errors[0]
            if distance < gate.threshold:
                assert error == pytest.approx(distance / gate.threshold, rel=1e-9)
            else:
                assert np.isinf(error)
                gated_out += plot >= len(flight)
        if row == COAST_AT:
            continue
        position, position_covariance = estimator.update(live, slot, row, prediction, 0)
        live.associate(slot, row, position)
        classical_filters.advance(reference, settings, plots.time[row] - last)
        classical_filters.update(reference, plots.position[row], plots.covariance[row])
        last = plots.time[row]
        x, P = classical_filters.posterior(reference)
        np.testing.assert_allclose(position, x[settings.measured], rtol=1e-12, atol=1e-6)
        np.testing.assert_allclose(position_covariance, P[measured], rtol=1e-9, atol=1e-6)
        velocity, velocity_covariance = estimator.velocities(live, slots)  # from the stored (IMM: mixed) filters
        at = motion_models.velocity_indices(settings.models[0])
        np.testing.assert_allclose(velocity[0], x[at], rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(velocity_covariance[0], P[np.ix_(at, at)], rtol=1e-7, atol=1e-6)
        if settings.is_imm:
            np.testing.assert_allclose(estimator.mu[slot], reference.cbar, rtol=1e-9, atol=1e-12)
    assert gated_out >= len(flight) - 3  # the 5 km plots, bar the first few while the velocity is unknown


def one_track(params, settings, flight: np.ndarray) -> tuple[LiveTracks, KalmanEstimator, int]:
    """The plots of `flight` tracked by `settings`' filter: one track started at the first, its slot."""
    estimator = KalmanEstimator(settings)
    live = LiveTracks(tf.plots_of(flight, np.arange(len(flight)), params.radar),
                      ThesisWeights.from_params(params.tracker.management), latest_plots=estimator.latest_plots)
    slot = live.start(0)
    estimator.start(live, slot)
    return live, estimator, slot


def test_update_without_a_prediction_predicts_itself(params):
    """A young track's update (the radius gate made no prediction) gives what predicting first gives."""
    settings = tf.untuned_filters(params)["imm"]
    flight = noisy_turning_flight(params, np.random.default_rng(3))[:2]
    results = []
    for given in (False, True):
        live, estimator, slot = one_track(params, settings, flight)
        prediction = estimator.predict(live, np.array([slot]), flight[1, 0]) if given else None
        results.append(estimator.update(live, slot, 1, prediction, 0))
    np.testing.assert_array_equal(results[0][0], results[1][0])
    np.testing.assert_array_equal(results[0][1], results[1][1])


def test_gate_scores_stacked_tracks_as_each_alone(params):
    """All candidate tracks of a plot are predicted and gated in one batch: the same errors and
    predictions as each track alone, for tracks of different ages and times (the youngest, last
    updated a minute before the plot in a turn, rejects it)."""
    settings = tf.untuned_filters(params)["imm"]
    rng = np.random.default_rng(4)
    flights = [noisy_turning_flight(params, rng)[:count] for count in (3, 6, 11)]
    plot = noisy_turning_flight(params, rng)[11]
    features = np.concatenate([*flights, plot[None]])
    estimator = KalmanEstimator(settings)
    live = LiveTracks(tf.plots_of(features, np.arange(len(features)), params.radar),
                      ThesisWeights.from_params(params.tracker.management), latest_plots=estimator.latest_plots)
    gate = ChiSquareGate(params.tracker.association.kalman_gate_probability)
    first = 0
    for flight in flights:
        slot = live.start(first)
        estimator.start(live, slot)
        for row in range(first + 1, first + len(flight)):
            position, _ = estimator.update(live, slot, row, None, 0)
            live.associate(slot, row, position)
        first += len(flight)
    slots = np.flatnonzero(live.alive)
    row = len(features) - 1
    together = gate(live, slots, row, estimator.predict(live, slots, features[row, 0]))
    alone = [gate(live, slots[n:n + 1], row, estimator.predict(live, slots[n:n + 1], features[row, 0]))
             for n in range(len(slots))]
    np.testing.assert_allclose(together.errors, [scores.errors[0] for scores in alone], rtol=1e-12)
    np.testing.assert_allclose(together.prediction.positions,
                               np.vstack([scores.prediction.positions for scores in alone]), rtol=1e-12)
    assert np.isinf(together.errors[0]) and np.isfinite(together.errors[1:]).all()


@pytest.mark.parametrize("method", ["kalman_cv_gnn", "imm_gnn"])
def test_a_scan_scored_and_updated_at_once_gives_the_updates_of_plot_by_plot(params, method):
    """GNN scans of eight crossing flights among clutter: the loop predicts, gates and updates the
    (track, plot) pairs of a whole scan in one call each (the estimator and gates are `pairwise`);
    the update table is the one the same tracker gives scoring and updating one plot at a time,
    to the last bit."""
    plots = crossing_flights_among_clutter(params)
    tables = []
    for pairwise in (True, False):
        tracker = registry.compose(method, Models({"kalman_tuned": tf.untuned_filters(params)}), params.tracker, 4000.0, 0)
        tracker.estimator.pairwise = pairwise
        tables.append(track(plots, tracker))
    assert (tables[0]["association"] == method).sum() > 50
    for column in tables[0]:
        np.testing.assert_array_equal(tables[0][column], tables[1][column], err_msg=column)


def crossing_flights_among_clutter(params):
    """Plots of eight flights crossing each other's paths, 3 km apart, among clutter (12 scans)."""
    rng = np.random.default_rng(16)
    flights = [(tf.straight_features(params.radar, (40e3 + 3e3 * n, -20e3, 9000.0),
                                     (60.0 * (n % 3 - 1), 200.0, 0.0), 12, t_offset=0.7 * n), 100 * n + np.arange(12))
               for n in range(8)]
    clutter = tf.clutter_features(params.radar, 12, 30.0, rng, half_width_m=60e3)
    features, ids = tf.merge(*flights, (clutter, 10_000 + np.arange(len(clutter))))
    return tf.plots_of(features, ids, params.radar)


@pytest.mark.parametrize("method", ["kalman_cv", "imm"])
def test_nearest_neighbour_scored_ahead_gives_the_updates_of_plot_by_plot(params, method, monkeypatch):
    """Nearest neighbour's plots are scored a few at a time ahead (`run._track_ahead`); a plot whose
    candidates changed before its turn is scored again. The update table is the one scoring each
    plot at its turn gives (roles not `pairwise`: no look-ahead), to the last bit, and both kinds of
    plot occur."""
    from pipeline.tracker import run
    plots = crossing_flights_among_clutter(params)
    verdicts = []

    def watched(*args):
        verdicts.append(unchanged_near(*args))
        return verdicts[-1]

    unchanged_near = run._unchanged_near
    monkeypatch.setattr(run, "_unchanged_near", watched)
    tables = []
    for pairwise in (True, False):
        tracker = registry.compose(method, Models({"kalman_tuned": tf.untuned_filters(params)}), params.tracker, 4000.0, 0)
        tracker.estimator.pairwise = pairwise
        assert tracker.looks_ahead == pairwise
        tables.append(track(plots, tracker))
    assert (tables[0]["association"] == method).sum() > 50
    assert True in verdicts and False in verdicts
    for column in tables[0]:
        np.testing.assert_array_equal(tables[0][column], tables[1][column], err_msg=column)


def test_motion_table_starting_afresh_changes_nothing(params, monkeypatch):
    """The estimator's table of F and Q by time step starts afresh when full (`MOTION_CACHE`): a
    table of three steps gives the same update table as the default one."""
    from pipeline.tracker import kalman
    plots = crossing_flights_among_clutter(params)
    tables = []
    for cache in (kalman.MOTION_CACHE, 3):
        monkeypatch.setattr(kalman, "MOTION_CACHE", cache)
        tracker = registry.compose("kalman_cv", Models({"kalman_tuned": tf.untuned_filters(params)}), params.tracker, 4000.0, 0)
        tables.append(track(plots, tracker))
        assert len(tracker.estimator._motion_code) <= max(cache, 12)  # at most a prediction's steps beyond it
    for column in tables[0]:
        np.testing.assert_array_equal(tables[0][column], tables[1][column], err_msg=column)


def test_single_filter_update_from_the_gates_inverse_is_its_own(params):
    """The chi-square gate hands its inverse innovation covariances on with the prediction; a single
    filter's update starting from them gives what inverting again gives, to the bit."""
    settings = tf.untuned_filters(params)["cv"]
    flight = noisy_turning_flight(params, np.random.default_rng(5))[:4]
    results = []
    for handed_on in (True, False):
        live, estimator, slot = one_track(params, settings, flight)
        gate = ChiSquareGate(params.tracker.association.kalman_gate_probability)
        for row in range(1, len(flight)):
            scores = gate(live, np.array([slot]), row, estimator.predict(live, np.array([slot]), flight[row, 0]))
            assert scores.prediction.innovation_inverse.shape == (1, 3, 3)
            prediction = scores.prediction if handed_on else scores.prediction._replace(innovation_inverse=None)
            position, covariance = estimator.update(live, slot, row, prediction, 0)
            live.associate(slot, row, position)
            results.append((position, covariance))
    for (position, covariance), (own_position, own_covariance) in zip(results[:3], results[3:]):
        np.testing.assert_array_equal(position, own_position)
        np.testing.assert_array_equal(covariance, own_covariance)

"""Track-to-track association: the statistical, double-threshold and bias-robust methods pair what they should,
the bias-robust offset is within its stated accuracy, and bad tracks stop with a named error."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from pipeline.association.bias_robust_association import associate_bias_robust
from pipeline.association.track_association import (
    TrackInputError,
    associate_double_threshold,
    associate_statistical,
    statistical_distances,
)
from tests.association_fixtures import straight_aircraft

GATE = 0.999


def test_one_straight_aircraft_without_bias_is_paired_by_every_classical_method():
    x1, p1, x2, p2 = straight_aircraft(np.array([[1000.0, -2000.0]]), np.array([[150.0, 80.0]]), np.zeros(2))
    assert associate_statistical(x1[-1], p1[-1], x2[-1], p2[-1], GATE).tolist() == [[0, 0]]
    assert associate_double_threshold(x1, p1, x2, p2, GATE, hits=3).tolist() == [[0, 0]]
    result = associate_bias_robust(x1[-1], p1[-1], x2[-1], p2[-1], GATE, 600.0, 150.0, 10)
    assert result.pairs.tolist() == [[0, 0]]


def test_statistic_is_the_mahalanobis_distance_of_the_difference():
    """Δᵀ (P1 + P2)⁻¹ Δ by hand for one pair with diagonal covariances."""
    x1, x2 = np.array([[0.0, 0.0, 100.0, 0.0]]), np.array([[30.0, -40.0, 100.0, 10.0]])
    p1, p2 = np.diag([100.0, 100.0, 4.0, 4.0])[None], np.diag([125.0, 300.0, 21.0, 21.0])[None]
    assert statistical_distances(x1, p1, x2, p2)[0, 0] == pytest.approx(30 ** 2 / 225 + 40 ** 2 / 400 + 10 ** 2 / 25)


def test_known_bias_is_estimated_within_its_stated_accuracy_and_the_aircraft_are_paired():
    rng = np.random.default_rng(5)
    starts = rng.uniform(-5000.0, 5000.0, (12, 2))
    heading = rng.uniform(0.0, 2 * np.pi, 12)
    velocities = 200.0 * np.stack([np.sin(heading), np.cos(heading)], axis=1)
    bias = np.array([300.0, -200.0])
    x1, p1, x2, p2 = straight_aircraft(starts, velocities, bias, seed=6)
    result = associate_bias_robust(x1[-1], p1[-1], x2[-1], p2[-1], GATE, 600.0, 150.0, 10)
    error = result.bias_m - bias
    assert error @ np.linalg.solve(result.bias_covariance_m2, error) <= chi2.ppf(0.999, 2)
    assert np.sqrt(np.diag(result.bias_covariance_m2)).max() < 30.0  # 12 pairs of 50 and 70 m tracks
    assert result.pairs.tolist() == [[i, i] for i in range(12)]
    assert len(associate_statistical(x1[-1], p1[-1], x2[-1], p2[-1], GATE)) < 12  # the bias defeats the plain test


def test_double_threshold_needs_the_second_threshold_of_passes():
    """A pair that passes the gate at the last time only is not associated with 3 passes needed, is with 1."""
    x1, p1, x2, p2 = straight_aircraft(np.array([[0.0, 0.0]]), np.array([[200.0, 0.0]]), np.zeros(2))
    x2 = x2.copy()
    x2[:-1, :, 0] += 2000.0
    assert associate_double_threshold(x1, p1, x2, p2, GATE, hits=3).tolist() == []
    assert associate_double_threshold(x1, p1, x2, p2, GATE, hits=1).tolist() == [[0, 0]]


@pytest.mark.parametrize("spoil, message", [
    (lambda p: p.__setitem__((0, 2, 2), np.nan), "radar 2: 1 track.* NaN or infinite covariance"),
    (lambda p: p.__setitem__((0, 0, 0), -1.0), "radar 2: covariance of track 0 is not positive definite"),
    (lambda p: p.__setitem__((0, 0, 1), 5.0), "radar 2: covariance of track 0 is not symmetric"),
])
def test_bad_covariance_is_a_named_error_in_every_method(spoil, message):
    x1, p1, x2, p2 = straight_aircraft(np.array([[0.0, 0.0]]), np.array([[200.0, 0.0]]), np.zeros(2))
    p2 = p2.copy()
    spoil(p2[-1])
    with pytest.raises(TrackInputError, match=message):
        associate_statistical(x1[-1], p1[-1], x2[-1], p2[-1], GATE)
    with pytest.raises(TrackInputError, match=message):
        associate_bias_robust(x1[-1], p1[-1], x2[-1], p2[-1], GATE, 600.0, 150.0, 10)
    with pytest.raises(TrackInputError, match=message):
        associate_double_threshold(x1, p1, x2, p2, GATE, hits=3)


def test_mismatched_shapes_are_named_errors():
    x1, p1, x2, p2 = straight_aircraft(np.array([[0.0, 0.0]]), np.array([[200.0, 0.0]]), np.zeros(2))
    with pytest.raises(TrackInputError, match="radar 1: states must be"):
        associate_statistical(x1[-1, :, :3], p1[-1], x2[-1], p2[-1], GATE)
    with pytest.raises(TrackInputError, match="radar 2: covariances must be"):
        associate_statistical(x1[-1], p1[-1], x2[-1], p2[-1, :, :3, :3], GATE)
    with pytest.raises(TrackInputError, match="hits = 5 must be in"):
        associate_double_threshold(x1, p1, x2, p2, GATE, hits=5)


def test_a_radar_without_tracks_gives_no_pairs():
    """A common time at which one radar has no track (`associate` meets them at a table's edges): no pair."""
    states, covariances = np.zeros((0, 4)), np.zeros((0, 4, 4))
    one, one_covariance = np.zeros((1, 4)), np.eye(4)[None]
    assert associate_statistical(one, one_covariance, states, covariances, 0.999).shape == (0, 2)
    assert associate_statistical(states, covariances, one, one_covariance, 0.999).shape == (0, 2)


def crossing_aircraft(count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Starts (count, 2) m and velocities (count, 2) m/s of aircraft at 200 m/s in uniform directions."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0.0, 2 * np.pi, count)
    return rng.uniform(-5000.0, 5000.0, (count, 2)), 200.0 * np.stack([np.sin(heading), np.cos(heading)], axis=1)


def test_a_clock_offset_is_estimated_beside_the_translation_and_the_aircraft_are_paired():
    """Radar 2's time stamps 3 s late place each of its tracks 600 m back along the aircraft's velocity, and it
    is 300 m off east: no translation fits (the translation-only vote pairs few), the joint estimate pairs all 12
    and finds the offset within its stated accuracy."""
    starts, velocities = crossing_aircraft(12, 5)
    bias = np.array([300.0, 0.0])
    x1, p1, x2, p2 = straight_aircraft(starts, velocities, bias, seed=6, time_offset_s=3.0)
    translation = associate_bias_robust(x1[-1], p1[-1], x2[-1], p2[-1], GATE, 600.0, 150.0, 10)
    assert len(translation.pairs) < 6 and translation.time_offset_s == 0.0
    result = associate_bias_robust(x1[-1], p1[-1], x2[-1], p2[-1], GATE, 600.0, 150.0, 10, max_time_offset_s=5.0)
    assert result.pairs.tolist() == [[i, i] for i in range(12)]
    assert (result.time_offset_s - 3.0) ** 2 <= chi2.ppf(0.999, 1) * result.time_offset_variance_s2
    assert np.sqrt(result.time_offset_variance_s2) < 0.2   # 12 pairs of 50 and 70 m tracks at 200 m/s
    error = result.bias_m - bias
    assert error @ np.linalg.solve(result.bias_covariance_m2, error) <= chi2.ppf(0.999, 2)


def test_without_a_clock_offset_the_translation_alone_is_the_result():
    """Radars that agree in time: the clock offset is not significant, so bias_robust gives what the translation
    alone gives, to the bit, with a time offset of 0 (the default pipeline's results do not change)."""
    starts, velocities = crossing_aircraft(12, 7)
    x1, p1, x2, p2 = straight_aircraft(starts, velocities, np.array([-200.0, 100.0]), seed=8)
    # the first aircraft unseen by radar 2, the last by radar 1: tracks unpaired on both sides, so the joint
    # estimate is tried
    x1, p1, x2, p2 = x1[-1][:-1], p1[-1][:-1], x2[-1][1:], p2[-1][1:]
    plain = associate_bias_robust(x1, p1, x2, p2, GATE, 600.0, 150.0, 10)
    timed = associate_bias_robust(x1, p1, x2, p2, GATE, 600.0, 150.0, 10, max_time_offset_s=5.0)
    assert timed.pairs.tolist() == plain.pairs.tolist() == [[i, i - 1] for i in range(1, 11)]
    assert np.array_equal(timed.bias_m, plain.bias_m) and timed.time_offset_s == 0.0

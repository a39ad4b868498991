"""Track-to-track association: the statistical, double-threshold and bias-robust methods pair what they should,
the bias-robust offset is within its stated accuracy, and bad tracks stop with a named error."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from pipeline.bias_robust_association import associate_bias_robust
from pipeline.track_association import (TrackInputError, associate_double_threshold, associate_statistical,
                                        statistical_distances)
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

"""Covariance intersection of associated pairs."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.association.track_association import TrackInputError
from pipeline.association.track_fusion import fuse_pairs
from tests.association_fixtures import straight_aircraft


@pytest.mark.parametrize("criterion", ["trace", "determinant"])
def test_two_equal_tracks_fuse_to_that_track_with_no_larger_covariance(criterion):
    x, p, _, _ = straight_aircraft(np.array([[0.0, 0.0]]), np.array([[200.0, 50.0]]), np.zeros(2))
    states, covariances, _ = fuse_pairs(x[-1], p[-1], x[-1], p[-1], np.array([[0, 0]]), criterion)
    np.testing.assert_allclose(states[0], x[-1, 0], atol=1e-9)
    assert np.linalg.eigvalsh(p[-1, 0] - covariances[0]).min() >= -1e-9


def test_complementary_tracks_weigh_evenly_and_fuse_tighter_than_either():
    """P1 = diag(1, 4), P2 = diag(4, 1): by symmetry ω = 1/2, P = diag(1.6, 1.6) (Julier & Uhlmann 1997, eq. 6)."""
    p1, p2 = np.diag([1.0, 4.0, 1.0, 4.0])[None], np.diag([4.0, 1.0, 4.0, 1.0])[None]
    x1, x2 = np.array([[0.0, 0.0, 0.0, 0.0]]), np.array([[1.0, 1.0, 0.0, 0.0]])
    states, covariances, weights = fuse_pairs(x1, p1, x2, p2, np.array([[0, 0]]))
    assert weights[0] == pytest.approx(0.5, abs=1e-4)
    np.testing.assert_allclose(np.diag(covariances[0]), [1.6, 1.6, 1.6, 1.6], rtol=1e-4)
    np.testing.assert_allclose(states[0, :2], [0.2, 0.8], rtol=1e-3)


def test_a_registration_offset_is_removed_before_fusing():
    x, p, _, _ = straight_aircraft(np.array([[0.0, 0.0]]), np.array([[200.0, 50.0]]), np.zeros(2))
    shifted = x[-1].copy()
    shifted[:, :2] += [300.0, -100.0]
    states, _, _ = fuse_pairs(x[-1], p[-1], shifted, p[-1], np.array([[0, 0]]), bias_m=np.array([300.0, -100.0]))
    np.testing.assert_allclose(states[0], x[-1, 0], atol=1e-6)


def test_bad_pairs_criterion_or_covariance_are_named_errors():
    x, p, _, _ = straight_aircraft(np.array([[0.0, 0.0]]), np.array([[200.0, 50.0]]), np.zeros(2))
    with pytest.raises(TrackInputError, match="pairs index tracks that do not exist"):
        fuse_pairs(x[-1], p[-1], x[-1], p[-1], np.array([[0, 1]]))
    with pytest.raises(TrackInputError, match="fusion criterion 'volume'"):
        fuse_pairs(x[-1], p[-1], x[-1], p[-1], np.array([[0, 0]]), "volume")
    bad = p[-1].copy()
    bad[0, 1, 1] = np.nan
    with pytest.raises(TrackInputError, match="radar 1: 1 track.* NaN"):
        fuse_pairs(x[-1], bad, x[-1], p[-1], np.array([[0, 0]]))

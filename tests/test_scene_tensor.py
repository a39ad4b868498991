"""The association network's inputs: the scene tensor of a hand-made scene value by value, and the pair features."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.association.scene_tensor import pair_features, scene_tensor
from pipeline.association.track_association import TrackInputError


def test_two_by_two_scene_tensor_value_by_value():
    """Radar 1 at (1, 0) and (0, 0) km, radar 2 at (0, 3) and (4, 0) km; diameter 10 km; padded to 3 x 3.
    Sorted by east: radar 1 (0, 0), (1, 0); radar 2 (0, 3), (4, 0)."""
    tensor = scene_tensor(np.array([[1000.0, 0.0], [0.0, 0.0]]), np.array([[4000.0, 0.0], [0.0, 3000.0]]), 3,
                          10000.0)
    assert tensor.shape == (3, 3, 3) and tensor.dtype == np.float32
    np.testing.assert_allclose(tensor[..., 0], [[0.0, 0.1, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 0.0]], atol=1e-7)
    np.testing.assert_allclose(tensor[..., 1], [[0.0, 0.5, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]], atol=1e-7)
    np.testing.assert_allclose(tensor[..., 2], [[0.3, 0.4, 0.0], [np.hypot(1000.0, 3000.0) / 10000.0, 0.3, 0.0],
                                                [0.0, 0.0, 0.0]], atol=1e-7)


def test_equal_east_sorts_by_north():
    tensor = scene_tensor(np.array([[0.0, 2000.0], [0.0, 0.0]]), np.array([[0.0, 0.0]]), 2, 1000.0)
    np.testing.assert_allclose(tensor[:, 0, 2], [0.0, 2.0])  # (0, 0) first, then (0, 2000)


def test_too_many_tracks_or_a_nan_position_is_a_named_error():
    with pytest.raises(TrackInputError, match="radar 2: 3 tracks, more than the scene tensor's size 2"):
        scene_tensor(np.zeros((1, 2)), np.zeros((3, 2)), 2, 1000.0)
    with pytest.raises(TrackInputError, match="radar 1: a position is NaN"):
        scene_tensor(np.array([[np.nan, 0.0]]), np.zeros((1, 2)), 2, 1000.0)


def test_pair_features_are_position_speed_and_heading_statistics():
    """Same place and speed, heading 90 degrees apart: position 0, speed 0, heading (π/2)² / summed variance."""
    covariance = np.diag([100.0, 100.0, 4.0, 4.0])[None]
    east = np.array([[0.0, 0.0, 100.0, 0.0]])
    north = np.array([[0.0, 0.0, 0.0, 100.0]])
    features = pair_features(east, covariance, north, covariance)
    heading_variance = 4.0 / 100.0 ** 2  # σ_v² / speed² for each track
    np.testing.assert_allclose(features[0, 0], [0.0, 0.0, (np.pi / 2) ** 2 / (2 * heading_variance)])

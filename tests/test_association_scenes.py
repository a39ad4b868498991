"""The seed's synthetic two-radar setting: deterministic per seed, as described, tracks as filterpy filters them."""

from __future__ import annotations

import dataclasses

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from pipeline.association.association_scenes import make_scene, make_tracks
from tests.association_fixtures import SETTING


def test_same_seed_same_scene_and_other_index_other_scene():
    first, again, other = make_scene(SETTING, 3, 7), make_scene(SETTING, 3, 7), make_scene(SETTING, 3, 8)
    for field in dataclasses.fields(first):
        np.testing.assert_array_equal(getattr(first, field.name), getattr(again, field.name))
    assert not np.array_equal(first.states1, other.states1)


def test_scene_follows_the_setting():
    scene = make_scene(dataclasses.replace(SETTING, bias_m=(150.0, 150.0)), 1, 0)
    assert scene.states1.shape[0] == SETTING.track_points - 1 and scene.states1.shape[2] == 4
    assert scene.states1.shape[1] <= 32 and scene.states2.shape[1] <= 32
    assert np.isclose(np.linalg.norm(scene.bias_m), 150.0)
    np.testing.assert_array_equal(scene.targets1[scene.true_pairs[:, 0]], scene.targets2[scene.true_pairs[:, 1]])
    assert len(scene.true_pairs) == len(np.intersect1d(scene.targets1, scene.targets2))


def test_kalman_tracks_match_filterpy():
    """The per-radar filter is filterpy's KalmanFilter with the discrete white-noise acceleration Q, started
    from two-point differencing."""
    rng = np.random.default_rng(2)
    plots = np.cumsum(rng.normal(0.0, 800.0, (5, 1, 2)), axis=0)
    states, covariances = make_tracks(plots, SETTING, 50.0)
    t, r = SETTING.scan_period_s, 50.0 ** 2
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.x = np.array([plots[1, 0, 0], (plots[1, 0, 0] - plots[0, 0, 0]) / t,
                     plots[1, 0, 1], (plots[1, 0, 1] - plots[0, 0, 1]) / t])   # filterpy order [e, ve, n, vn]
    block = np.array([[r, r / t], [r / t, 2 * r / t ** 2]])
    kf.P = np.kron(np.eye(2), block)
    kf.F = np.kron(np.eye(2), np.array([[1.0, t], [0.0, 1.0]]))
    kf.Q = np.kron(np.eye(2), Q_discrete_white_noise(2, dt=t, var=SETTING.acceleration_std_mps2 ** 2))
    kf.H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    kf.R = np.eye(2) * r
    order = [0, 2, 1, 3]  # ours [e, n, ve, vn] from filterpy's [e, ve, n, vn]
    for time in range(2, 5):
        kf.predict()
        kf.update(plots[time, 0])
        np.testing.assert_allclose(states[time - 1, 0], kf.x[order], rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(covariances[time - 1, 0], kf.P[np.ix_(order, order)], rtol=1e-9, atol=1e-9)

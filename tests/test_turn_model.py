"""The coordinated-turn model with a known turn rate (`pipeline.filters.turn_model`, issue 33) against Stone
Soup's `KnownTurnRate`, step by step, and in ECEF, where the turn is about each track's own vertical."""

from __future__ import annotations

import datetime

import numpy as np
import pytest

from pipeline.filters import motion_models
from pipeline.filters.turn_model import POSITION, VELOCITY, turn_process_noise, turn_transition
from pipeline.geometry import geodesy

stonesoup_linear = pytest.importorskip("stonesoup.models.transition.linear",
                                       reason="Stone Soup, the reference, is not installed")

XY_Z = [0, 1, 3, 4, 6, 7]  # (x, vx, y, vy, z, vz) in the CA layout


@pytest.mark.parametrize("turn_rate, dt", [(0.1, 4.0), (-0.15, 6.0), (np.radians(3.0), 4.8), (1e-9, 5.0)])
def test_about_the_z_axis_it_is_stone_soups_known_turn_rate_and_a_constant_velocity_on_z(turn_rate, dt):
    """With up the z axis, F on (x, vx, y, vy) is Stone Soup's `KnownTurnRate` matrix, z moves at constant
    velocity, the accelerations are reset; at a turn rate of 1e-9 rad/s it is the constant-velocity model
    (there the reference's (1 - cos(omega T)) / omega cancels to 0, ours keeps omega T^2 / 2 = 1.25e-8)."""
    F = turn_transition(dt, turn_rate, np.array([0.0, 0.0, 1.0]))
    reference = stonesoup_linear.KnownTurnRate(turn_noise_diff_coeffs=[1.0, 1.0], turn_rate=turn_rate)
    np.testing.assert_allclose(F[np.ix_(XY_Z[:4], XY_Z[:4])],
                               reference.matrix(time_interval=datetime.timedelta(seconds=dt)), rtol=1e-12,
                               atol=1e-7 if abs(turn_rate) < 1e-6 else 1e-12)
    np.testing.assert_allclose(F[np.ix_(XY_Z[4:], XY_Z[4:])], [[1.0, dt], [0.0, 1.0]])
    assert not F[[2, 5, 8]].any() and not F[:, [2, 5, 8]].any()
    if abs(turn_rate) < 1e-6:
        np.testing.assert_allclose(F, motion_models.transition("cv9", dt), atol=1e-7)


def test_a_track_in_ecef_turns_about_its_own_vertical_step_by_step():
    """A target at 10 km over 52 N 4 E flying 200 m/s east and climbing 5 m/s, turning left at 3 deg/s:
    stepped 30 times by 4 s in ECEF it is where the same steps of Stone Soup's model in the local east,
    north, up frame put it (positions to a micrometre, velocities to 1e-9 m/s); its ground speed and climb
    rate are kept."""
    rotation = geodesy.enu_rotation(52.0, 4.0)   # rows: east, north, up in ECEF
    origin = geodesy.site_ecef(52.0, 4.0, 10_000.0)
    turn_rate, dt = np.radians(3.0), 4.0
    reference = stonesoup_linear.KnownTurnRate(turn_noise_diff_coeffs=[1.0, 1.0], turn_rate=turn_rate)
    local_F = reference.matrix(time_interval=datetime.timedelta(seconds=dt))
    local = np.array([0.0, 200.0, 0.0, 0.0, 0.0, 5.0])  # east, v_east, north, v_north, up, v_up
    state = np.zeros(9)
    state[POSITION], state[VELOCITY] = origin, rotation.T @ local[[1, 3, 5]]
    F = turn_transition(dt, turn_rate, rotation[2])
    for _ in range(30):
        local[:4] = local_F @ local[:4]
        local[4] += dt * local[5]
        state = F @ state
        np.testing.assert_allclose(rotation @ (state[POSITION] - origin), local[[0, 2, 4]], atol=1e-6)
        np.testing.assert_allclose(rotation @ state[VELOCITY], local[[1, 3, 5]], atol=1e-9)
    ground = rotation @ state[VELOCITY]
    np.testing.assert_allclose([np.hypot(*ground[:2]), ground[2]], [200.0, 5.0], rtol=1e-12)


def test_per_track_verticals_and_steps_broadcast_and_bad_verticals_are_refused():
    """F for several tracks at once, each its own step and vertical, equals each track's alone; an up that
    is not a unit vector is refused (ValueError)."""
    ups = geodesy.enu_rotations(np.array([10.0, -60.0, 45.0]), np.array([0.0, 179.9, -120.0]))[:, 2]
    dts = np.array([4.0, 5.0, 6.0])
    together = turn_transition(dts, 0.05, ups)
    assert together.shape == (3, 9, 9)
    for k in range(3):
        np.testing.assert_array_equal(together[k], turn_transition(dts[k], 0.05, ups[k]))
    with pytest.raises(ValueError, match="unit vectors"):
        turn_transition(4.0, 0.05, np.array([0.0, 0.0, 2.0]))


def test_its_process_noise_is_the_same_in_every_frame():
    """Q is `cv9`'s white-noise acceleration: rotating it into another frame leaves it unchanged."""
    Q = turn_process_noise(4.0, 3.0)
    rotation = np.kron(np.eye(3), geodesy.enu_rotation(52.0, 4.0))  # the same rotation on p, v and a
    layout = np.arange(9).reshape(3, 3).T.ravel()   # (p_x, p_y, p_z, v_x, ...) -> the CA layout's order
    per_quantity = Q[np.ix_(layout, layout)]
    np.testing.assert_allclose(rotation @ per_quantity @ rotation.T, per_quantity, atol=1e-9)

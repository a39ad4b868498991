"""The coordinated-turn model with a known turn rate (issue 33, deliverable 3), in the trackers' ECEF frame.

A target in a coordinated turn keeps its speed while its velocity turns at a rate omega (rad/s,
positive counter-clockwise seen from above) about the local vertical `up`: dv/dt = omega up x v
(Li & Jilkov 2003, "Survey of maneuvering target tracking. Part I: dynamic models", IEEE Trans.
AES-39(4), section V.A, the known-turn-rate model; Stone Soup's `KnownTurnRate` in the plane of its two
axes). Over a step T, with theta = omega T and K the cross-product matrix of the unit vector up
(K v = up x v), Rodrigues' formula gives

    v(T) = R v(0),  R = I + sin(theta) K + (1 - cos(theta)) K^2
    p(T) = p(0) + G v(0),  G = T I + (1 - cos(theta)) / omega K + (T - sin(theta) / omega) K^2,

so the vertical component of the velocity is kept and the horizontal one turns. With up the z axis
this is Stone Soup's `KnownTurnRate` matrix on (x, vx, y, vy) and a constant velocity on z
(`tests/test_turn_model.py` checks it step by step). The coefficients are written with `np.sinc`, so a
turn rate of 0 gives the constant-velocity transition with no 0 / 0.

Why a frame-free formula: the classical filters run in ECEF (`pipeline.filters.motion_models`: their
noise is the same on every axis, so ECEF and a local frame give the same result); a turn is about the
local vertical, which in ECEF differs from track to track, so F is built per track from its `up` (the third
row of `geodesy.enu_rotations` at the track's geodetic position; `local_vertical` gives it from the ECEF position
in closed form). The state is the CA layout [x, vx, ax, y, vy,
ay, z, vz, az] with the acceleration reset at each step (as `cv9`), so an IMM can mix the model with
`cv9` and `ca`; its process noise is `cv9`'s white-noise acceleration, the same on every axis and so the
same in any frame.
"""

from __future__ import annotations

import numpy as np

from pipeline.filters import motion_models
from pipeline.geometry import geodesy

POSITION, VELOCITY = np.array([0, 3, 6]), np.array([1, 4, 7])  # the CA layout's entries per axis
_INVERSE_AXES_SQUARED = 1.0 / np.array([geodesy.SEMIMAJOR_M, geodesy.SEMIMAJOR_M, geodesy.SEMIMINOR_M]) ** 2


def cross_matrix(up: np.ndarray) -> np.ndarray:
    """K (..., 3, 3) with K v = up x v, for unit vectors `up` (..., 3)."""
    x, y, z = np.moveaxis(np.asarray(up, dtype=float), -1, 0)
    zero = np.zeros_like(x)
    return motion_models.stacked_matrix([[zero, -z, y], [z, zero, -x], [-y, x, zero]])


def turn_transition(dt: float | np.ndarray, turn_rate: float | np.ndarray, up: np.ndarray) -> np.ndarray:
    """F (..., 9, 9) of the known-turn-rate model over steps `dt` (s) at `turn_rate` (rad/s, positive
    counter-clockwise about `up`) for the unit vertical `up` (..., 3), all broadcast together; the CA
    layout with the acceleration reset (module docstring). Raises ValueError for an `up` not of unit
    length (within 1e-6)."""
    up = np.asarray(up, dtype=float)
    if not np.all(np.abs(np.linalg.norm(up, axis=-1) - 1.0) < 1e-6):
        raise ValueError("turn_transition: up must be unit vectors (the local vertical at each track)")
    dt, turn_rate = np.asarray(dt, dtype=float), np.asarray(turn_rate, dtype=float)
    theta = turn_rate * dt
    shape = np.broadcast_shapes(theta.shape, up.shape[:-1])
    theta, dt = np.broadcast_to(theta, shape)[..., None, None], np.broadcast_to(dt, shape)[..., None, None]
    K = np.broadcast_to(cross_matrix(up), (*shape, 3, 3))
    K2 = K @ K
    eye = np.eye(3)
    sin_over = dt * np.sinc(theta / np.pi)                                 # sin(theta) / omega
    one_minus_cos_over = dt * np.sin(theta / 2.0) * np.sinc(theta / (2.0 * np.pi))  # (1 - cos(theta)) / omega
    R = eye + np.sin(theta) * K + (1.0 - np.cos(theta)) * K2
    G = dt * eye + one_minus_cos_over * K + (dt - sin_over) * K2
    F = np.zeros((*shape, 9, 9))
    F[..., POSITION, POSITION] = 1.0
    F[..., POSITION[:, None], VELOCITY] = G
    F[..., VELOCITY[:, None], VELOCITY] = R
    return F


def turn_process_noise(dt: float | np.ndarray, noise_std: float) -> np.ndarray:
    """Q (..., 9, 9) over steps `dt` (s): `cv9`'s white-noise acceleration of standard deviation
    `noise_std` (m/s^2), the same on every axis (module docstring)."""
    return motion_models.process_noise("cv9", dt, noise_std)


def local_vertical(position_ecef: np.ndarray) -> np.ndarray:
    """The unit local vertical `up` (..., 3) at ECEF positions (..., 3) metres: the normal (x / a^2, y / a^2,
    z / b^2) of the WGS84-shaped ellipsoid through the point (a, b the semi-axes).

    Why this and not the geodetic latitude's normal (`geodesy.enu_rotations` after `geodesy.ecef_to_geodetic`):
    it is one closed-form step instead of an iteration, for the Kalman core's every prediction; at an
    aircraft's height h the two differ by about e^2 (h / a) sin(2 latitude), below 2e-5 rad at 15 km, which
    turns a 250 m/s velocity by 5 mm/s. The Earth's centre, where the padding of a batch may sit, gets
    the z axis rather than 0 / 0."""
    normal = np.asarray(position_ecef, dtype=float) * _INVERSE_AXES_SQUARED
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    return np.where(length > 0.0, normal / np.where(length > 0.0, length, 1.0), [0.0, 0.0, 1.0])


def turning_transitions(dt: np.ndarray, turn_rates: np.ndarray, up: np.ndarray) -> np.ndarray:
    """F (B, R, 9, 9) of R turning models (turn rates (R,) rad/s) for B tracks over their steps dt (B,) s, each
    about its track's vertical up (B, 3) (`turn_transition` broadcast over tracks and models)."""
    return turn_transition(np.asarray(dt, dtype=float)[:, None], np.asarray(turn_rates, dtype=float)[None, :],
                           np.asarray(up, dtype=float)[:, None, :])

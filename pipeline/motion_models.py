"""Motion models of the classical trackers: transition F and process noise Q over a time step.

Three models, each defined once here and used both by the filterpy reference filters
(`pipeline.classical_filters`) and by the one Kalman core that the tracker, the tuner and the
comparison run (`pipeline.batch_filters`):

- `cv`: constant velocity, state [x, vx, y, vy, z, vz], white-noise acceleration of standard
  deviation q (filterpy's `Q_discrete_white_noise(dim=2)`).
- `ca`: constant acceleration, state [x, vx, ax, y, vy, ay, z, vz, az], white-noise
  acceleration increments of standard deviation q per second (filterpy's
  `Q_discrete_white_noise(dim=3)`, the discrete Wiener-process acceleration model).
- `cv9`: constant velocity in the CA state, acceleration reset to zero at each step, so an
  IMM can mix it with `ca` (filterpy's IMMEstimator needs one state layout for all models).

The noise is the same on the three axes, so the filters give the same result in ECEF as in
a local east-north-up frame (Q and the transition commute with a rotation of the axes):
the tracker stays in ECEF and takes the measurement covariance rotated there.

Every function takes `dt` as a scalar or an array (then the result has dt's shape in front),
so the tuner can step hundreds of tracks at once.
"""

from __future__ import annotations

import numpy as np

DIMENSIONS = {"cv": 2, "ca": 3, "cv9": 3}  # state entries per axis


def state_size(model: str) -> int:
    return 3 * DIMENSIONS[model]


def measured_indices(model: str) -> list[int]:
    """Where x, y, z sit in the model's state."""
    return [axis * DIMENSIONS[model] for axis in range(3)]


def velocity_indices(model: str) -> list[int]:
    return [axis * DIMENSIONS[model] + 1 for axis in range(3)]


def measurement_matrix(model: str) -> np.ndarray:
    """H: picks the position out of the state."""
    matrix = np.zeros((3, state_size(model)))
    matrix[[0, 1, 2], measured_indices(model)] = 1.0
    return matrix


def _per_axis(block: np.ndarray) -> np.ndarray:
    """The same (..., d, d) block on each of the three axes: (..., 3d, 3d)."""
    d = block.shape[-1]
    out = np.zeros((*block.shape[:-2], 3 * d, 3 * d))
    for axis in range(3):
        out[..., axis * d:(axis + 1) * d, axis * d:(axis + 1) * d] = block
    return out


def transition(model: str, dt: float | np.ndarray) -> np.ndarray:
    """F over dt."""
    dt = np.asarray(dt, dtype=float)
    one, zero = np.ones_like(dt), np.zeros_like(dt)
    if model == "cv":
        rows = [[one, dt], [zero, one]]
    elif model == "ca":
        rows = [[one, dt, dt ** 2 / 2], [zero, one, dt], [zero, zero, one]]
    elif model == "cv9":
        rows = [[one, dt, zero], [zero, one, zero], [zero, zero, zero]]
    else:
        raise ValueError(f"motion model {model!r}: must be cv, ca or cv9")
    return _per_axis(np.moveaxis(np.array(rows), (0, 1), (-2, -1)))


def process_noise(model: str, dt: float | np.ndarray, noise_std: float) -> np.ndarray:
    """Q over dt for process noise of standard deviation `noise_std` (m/s^2 for cv/cv9, m/s^3 for ca)."""
    dt = np.asarray(dt, dtype=float)
    variance = noise_std ** 2
    if model in ("cv", "cv9"):
        rows = [[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]]
        if model == "cv9":
            zero = np.zeros_like(dt)
            rows = [rows[0] + [zero], rows[1] + [zero], [zero, zero, zero]]
    elif model == "ca":
        rows = [[dt ** 4 / 4, dt ** 3 / 2, dt ** 2 / 2], [dt ** 3 / 2, dt ** 2, dt], [dt ** 2 / 2, dt, np.ones_like(dt)]]
    else:
        raise ValueError(f"motion model {model!r}: must be cv, ca or cv9")
    return variance * _per_axis(np.moveaxis(np.array(rows), (0, 1), (-2, -1)))


def initial_state(model: str, position: np.ndarray, covariance: np.ndarray, velocity_std: float,
                  acceleration_std: float) -> tuple[np.ndarray, np.ndarray]:
    """State and covariance of a track started at one measurement: position measured, velocity
    and acceleration unknown (zero, with the given spreads). Batched over leading axes of `position`."""
    position = np.asarray(position, dtype=float)
    size = state_size(model)
    state = np.zeros((*position.shape[:-1], size))
    state[..., measured_indices(model)] = position
    spread = np.zeros((*position.shape[:-1], size, size))
    measured = measured_indices(model)
    for row, i in enumerate(measured):
        for column, j in enumerate(measured):
            spread[..., i, j] = covariance[..., row, column]
    for index in velocity_indices(model):
        spread[..., index, index] = velocity_std ** 2
    if DIMENSIONS[model] == 3:
        for index in (2, 5, 8):
            spread[..., index, index] = acceleration_std ** 2 if model == "ca" else 0.0
    return state, spread

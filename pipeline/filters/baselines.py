"""Classical references for the networks: linear extrapolation and a constant-velocity Kalman filter.

The Kalman filter is filterpy's, in ECEF with state [x, vx, y, vy, z, vz]. Its
measurement covariance is the converted-measurement covariance of a radar plot: the range
error along the line of sight, the azimuth error across it (range * sigma_azimuth), and
the altitude error vertically, rotated into ECEF at the radar. These references are
deliberately untuned here; tuned Kalman and IMM trackers are a later stage.
"""

from __future__ import annotations

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

MEASURED = [0, 2, 4]  # positions in the [x, vx, y, vy, z, vz] state


def constant_velocity_filter(position: np.ndarray, covariance: np.ndarray, max_speed_mps: float) -> KalmanFilter:
    """A CV Kalman filter started at a measurement, velocity unknown up to max_speed."""
    kf = KalmanFilter(dim_x=6, dim_z=3)
    kf.x = np.zeros(6)
    kf.x[MEASURED] = position
    kf.P = np.zeros((6, 6))
    kf.P[np.ix_(MEASURED, MEASURED)] = covariance
    kf.P[[1, 3, 5], [1, 3, 5]] = max_speed_mps ** 2
    kf.H = np.zeros((3, 6))
    kf.H[[0, 1, 2], MEASURED] = 1.0
    return kf


def constant_velocity_model(dt: float, acceleration_std: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition F and white-acceleration process noise Q of [x, vx, y, vy, z, vz] over dt."""
    transition = np.kron(np.eye(3), np.array([[1.0, dt], [0.0, 1.0]]))
    noise = Q_discrete_white_noise(dim=2, dt=dt, var=acceleration_std ** 2, block_size=3, order_by_dim=True)
    return transition, noise


def _predict(kf: KalmanFilter, dt: float, acceleration_std: float) -> None:
    kf.F, kf.Q = constant_velocity_model(dt, acceleration_std)
    kf.predict()


def _filtered(times: np.ndarray, positions: np.ndarray, covariances: np.ndarray, acceleration_std: float,
              max_speed_mps: float) -> KalmanFilter:
    """Run a CV filter through one window's measurements."""
    kf = constant_velocity_filter(positions[0], covariances[0], max_speed_mps)
    for k in range(1, len(times)):
        _predict(kf, times[k] - times[k - 1], acceleration_std)
        kf.update(positions[k], R=covariances[k])
    return kf


def kalman_filtered_last(times: np.ndarray, positions: np.ndarray, covariances: np.ndarray,
                         acceleration_std: float, max_speed_mps: float) -> np.ndarray:
    """Filtered position at the last measurement of each window (N x L -> N x 3)."""
    return np.array([_filtered(times[n], positions[n], covariances[n], acceleration_std, max_speed_mps).x[MEASURED]
                     for n in range(len(times))]).reshape(-1, 3)


def kalman_predicted(times: np.ndarray, positions: np.ndarray, covariances: np.ndarray, target_times: np.ndarray,
                     acceleration_std: float, max_speed_mps: float) -> np.ndarray:
    """Filter each window, then predict its position at `target_times` (N)."""
    out = np.empty((len(times), 3))
    for n in range(len(times)):
        kf = _filtered(times[n], positions[n], covariances[n], acceleration_std, max_speed_mps)
        _predict(kf, target_times[n] - times[n, -1], acceleration_std)
        out[n] = kf.x[MEASURED]
    return out


def linear_extrapolation(times: np.ndarray, positions: np.ndarray, target_times: np.ndarray) -> np.ndarray:
    """Extrapolate the last two positions of each window to `target_times`."""
    velocity = (positions[:, -1] - positions[:, -2]) / (times[:, -1] - times[:, -2])[:, None]
    return positions[:, -1] + velocity * (target_times - times[:, -1])[:, None]

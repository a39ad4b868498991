"""The limit: the posterior Cramér-Rao bound (PCRB) of a radar track's position, under a classical motion model.

The PCRB bounds the mean square error of any unbiased estimator of the state given the plots (Tichavsky,
Muravchik & Nehorai 1998, "Posterior Cramér-Rao bounds for discrete-time nonlinear filtering", IEEE Trans.
Signal Processing 46(5), eq. 21): for a linear Gaussian motion model the information matrix obeys the
Riccati recursion

    J_k = (F_k J_{k-1}^-1 F_k^T + Q_k)^-1 + q_k H^T R_k^-1 H,

F_k and Q_k the model's transition and process noise over the step, H the position's selection, R_k the
plot's measurement covariance at the true position (`geodesy.measurement_covariance`: the radar's range,
azimuth and altitude errors converted to ECEF, as the tracker takes each plot), and q_k the information
reduction factor of the scan (Hernandez, Ristic & Farina 2005; Stone Soup's `PCRBMetric`, which this
recursion matches in `tests/test_pcrb.py`). With detections of probability P_d and no clutter the factor
is P_d exactly (a scan's information is the plot's with probability P_d); clutter lowers it further
(Niu, Willett & Bar-Shalom 2001), which is not included here: with q_k = P_d the bound is a lower, still
valid, bound of the true one with clutter. The prior J_0 is the inverse of the covariance a filter starts
with at the first plot (`motion_models.initial_state`: the plot's covariance, the velocity and
acceleration spreads).

The bound depends on the motion model the truth is taken to follow: under the tuned CV or CA model's
process noise it is the limit for trackers that assume that model, not for the route model the
simulator flies; it is reported per model. Measured on the test split of the 2026-12-06 run (`route_bounds`
over every in-coverage scan of its 80 routes): sqrt(PCRB) under the tuned CV model is 281 m RMS horizontally
(median 257 m), under the tuned CA 293 m, while the tuned IMM with global nearest neighbour reaches 203 m RMS on
its confirmed updates (`python -m pipeline score`): the tuned models' process noise (20-24 m/s^2 and m/s^3,
set by the manoeuvres) makes the routes look far more random than they are, so under those models the bound
is no limit for these routes. A bound that is one needs the route model's own statistics.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from pipeline.filters import motion_models

MODELS = ("cv", "ca")  # the tuned filters whose models the bench gives the bound under


def information_recursion(times_s: np.ndarray, measurement_covariance: np.ndarray, reduction: np.ndarray,
                          model: str, noise_std: float, velocity_std_mps: float, acceleration_std_mps2: float
                          ) -> np.ndarray:
    """The PCRB J_k^-1 (N, n, n) of the state of `model` ("cv" or "ca", n = 6 or 9) at each of N scan times (s,
    increasing), given each scan's measurement covariance (N, 3, 3) m^2, its information reduction factor q_k
    (N,) in [0, 1] (the detection probability; module docstring), and the model's process noise and start
    spreads. Raises ValueError for times not increasing or a factor outside [0, 1]."""
    times_s = np.asarray(times_s, dtype=float)
    if len(times_s) and np.any(np.diff(times_s) <= 0.0):
        raise ValueError("PCRB: the scan times must increase")
    reduction = np.asarray(reduction, dtype=float)
    if np.any((reduction < 0.0) | (reduction > 1.0)):
        raise ValueError("PCRB: an information reduction factor outside [0, 1]")
    h = motion_models.measurement_matrix(model)
    _, start = motion_models.initial_state(model, np.zeros(3), measurement_covariance[0], velocity_std_mps,
                                           acceleration_std_mps2)
    bounds = np.empty((len(times_s), *start.shape))
    information = np.linalg.inv(start)
    bounds[0] = start
    for k in range(1, len(times_s)):
        dt = times_s[k] - times_s[k - 1]
        f, q = motion_models.transition(model, dt), motion_models.process_noise(model, dt, noise_std)
        information = (np.linalg.inv(f @ bounds[k - 1] @ f.T + q)
                       + reduction[k] * h.T @ np.linalg.inv(measurement_covariance[k]) @ h)
        bounds[k] = np.linalg.inv(information)
    return bounds


def position_bounds(bounds: np.ndarray, model: str, enu_rotations: np.ndarray | None = None) -> np.ndarray:
    """sqrt of the position block's trace of each PCRB (N,) m: the bound on the position RMSE; with the local
    east-north-up rotations (N, 3, 3) at the true positions, of its horizontal (east, north) part only."""
    index = motion_models.measured_indices(model)
    block = bounds[:, index][:, :, index]
    if enu_rotations is not None:
        block = (enu_rotations @ block @ enu_rotations.transpose(0, 2, 1))[:, :2, :2]
    return np.sqrt(np.trace(block, axis1=1, axis2=2))


def route_bounds(times_s: np.ndarray, positions: np.ndarray, detection: np.ndarray, radar: object,
                 settings: object) -> tuple[np.ndarray, np.ndarray]:
    """The position-RMSE bounds (3-D and horizontal, each (N,) m) along one aircraft's truth in coverage: scans
    at `times_s` (N,) s, true ECEF `positions` (N, 3) m, detection probabilities (N,) (the simulator's, per
    scan), the radar (`pipeline.params.Radar`) whose plots they would be, under a tuned CV or CA filter's
    `settings` (`classical_filters.FilterSettings`: its model, process noise and start spreads). The recursion
    starts again after a gap of more than 1.5 scans (a new track)."""
    from pipeline.geometry import geodesy

    model = settings.models[0]
    covariance = geodesy.measurement_covariance(positions, radar)
    latitude, longitude, _ = geodesy.ecef_to_geodetic(positions)
    rotations = geodesy.enu_rotations(np.atleast_1d(latitude), np.atleast_1d(longitude))
    scan = 60.0 / radar.rotation_rpm
    starts = np.flatnonzero(np.concatenate([[True], np.diff(times_s) > 1.5 * scan]))
    full, horizontal = np.empty(len(times_s)), np.empty(len(times_s))
    for begin, end in zip(starts, np.append(starts[1:], len(times_s))):
        bounds = information_recursion(times_s[begin:end], covariance[begin:end], detection[begin:end], model,
                                       settings.noise_std[0], settings.velocity_std_mps, settings.acceleration_std_mps2)
        full[begin:end] = position_bounds(bounds, model)
        horizontal[begin:end] = position_bounds(bounds, model, rotations[begin:end])
    return full, horizontal


def horizontal_rms(truths: Sequence[tuple[object, np.ndarray, object]], settings: object) -> float:
    """The limit beside a bench's position RMS: the RMS (m), over every in-coverage truth sample of every target
    of every material item, of the horizontal position bound (`route_bounds`) under a tuned filter's `settings`.
    Each item is (truth, detection probability (T,) of each truth row, radar): `scorecard.Truth` (target id,
    time s, ECEF position m, in coverage), the simulator's detection probabilities and the radar
    (`pipeline.params.Radar`) that saw it. NaN where no target is in coverage. A run's RMS is over its confirmed
    updates alone, so a run that holds the hard scans less often may come nearer the bound than it is."""
    squares = []
    for truth, detection, radar in truths:
        for target in np.unique(truth.target_id[truth.in_coverage]).tolist():
            rows = np.flatnonzero((truth.target_id == target) & truth.in_coverage)
            rows = rows[np.argsort(truth.time_s[rows], kind="stable")]
            _, horizontal = route_bounds(truth.time_s[rows], truth.position[rows], detection[rows], radar, settings)
            squares.append(horizontal ** 2)
    return float(np.sqrt(np.concatenate(squares).mean())) if squares else float("nan")

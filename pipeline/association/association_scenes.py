"""The seed's synthetic two-radar setting (seed 002, section 4.1; related-work.md section B), for training and
scoring track-to-track association.

A scene: 16-32 targets (uniform) start uniformly in a square of side `area_m` centred on the origin, with a
uniform speed and heading, and fly a discrete white-noise acceleration model (Bar-Shalom, Li & Kirubarajan
(2001), "Estimation with Applications to Tracking and Navigation", section 6.3.2: the acceleration,
N(0, σ_a²) per axis, is constant over each period). Both radars see them at the same `track_points` times,
`scan_period_s` apart (the seed aligns the radars' times by interpolation; here they are aligned), with
white position noise of their own sigma; radar 2's plots are all shifted by its registration bias, a
vector of uniform length in `bias_m` and uniform direction (the seed gives the length only).

What the seed leaves open, chosen here (each a field of `SceneSetting`):
- Pd 0.9: the seed's segments always have 5 points, so it is read per target: a radar tracks a target with
  probability `detection_probability`, else has no track of it (true pairs: the targets both radars track).
- Its track points: `tracks = "kalman"` (default) filters each radar's plots with the constant-velocity
  Kalman filter of the same motion model, started from the first two plots (two-point differencing,
  ibid. section 5.5.3), one state and covariance per point from the second on; `tracks = "two_point"` takes
  every point as it is measured, the velocity from the last two plots (no filtering).
- The acceleration sigma and the speed interval were lost from the scraped text: `acceleration_std_mps2`
  and `speed_mps` (defaults: 1 m/s², 100-300 m/s, airliners and fighters at cruise).

A track's history is (L, 4) with L = track_points - 1 ([east, north, v_east, v_north], m and m/s, the
last point last: the common time). Tracks are listed in a random order per radar. Deterministic: scene k
of `seed` is drawn from its own stream (seed, k), whatever the count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SceneSetting:
    """The seed's setting (module docstring); lengths in metres, times in seconds."""

    targets: tuple[int, int]              # inclusive bounds of the target count
    area_m: float                         # side of the square the targets start in
    scan_period_s: float
    track_points: int                     # plots per track segment (>= 2)
    noise_m: tuple[float, float]          # position sigma per axis of radar 1 and radar 2
    detection_probability: float          # a radar tracks a target with this probability
    speed_mps: tuple[float, float]
    acceleration_std_mps2: float
    bias_m: tuple[float, float]           # length of radar 2's registration bias, uniform in this interval
    tracks: str                           # one of params.TRACK_MODELS


@dataclass(frozen=True)
class Scene:
    """Both radars' tracks: states (L, N_s, 4), covariances (L, N_s, 4, 4); `targets1` (N_1,) and `targets2`
    (N_2,) the target behind each track; `bias_m` (2,) radar 2's true offset; `true_pairs` (K, 2) sorted by
    radar 1's track."""

    states1: np.ndarray
    covariances1: np.ndarray
    states2: np.ndarray
    covariances2: np.ndarray
    targets1: np.ndarray
    targets2: np.ndarray
    bias_m: np.ndarray
    true_pairs: np.ndarray


def _transition(period_s: float) -> np.ndarray:
    """F of the constant-velocity model for [e, n, ve, vn]."""
    f = np.eye(4)
    f[0, 2] = f[1, 3] = period_s
    return f


def _process_noise(period_s: float, acceleration_std_mps2: float) -> np.ndarray:
    """Q of the discrete white-noise acceleration model (Bar-Shalom et al. 2001, eq. 6.3.2-4) for [e, n, ve, vn]."""
    t = period_s
    block = np.array([[t ** 4 / 4, t ** 3 / 2], [t ** 3 / 2, t ** 2]]) * acceleration_std_mps2 ** 2
    q = np.zeros((4, 4))
    q[np.ix_([0, 2], [0, 2])] = q[np.ix_([1, 3], [1, 3])] = block
    return q


def _two_point(previous: np.ndarray, last: np.ndarray, period_s: float,
               sigma_m: float) -> tuple[np.ndarray, np.ndarray]:
    """State (N, 4) and covariance (4, 4) from two plots (N, 2) one period apart (Bar-Shalom et al. 2001,
    section 5.5.3): position the last plot, velocity their difference over the period."""
    r = sigma_m ** 2
    block = np.array([[r, r / period_s], [r / period_s, 2 * r / period_s ** 2]])
    covariance = np.zeros((4, 4))
    covariance[np.ix_([0, 2], [0, 2])] = covariance[np.ix_([1, 3], [1, 3])] = block
    return np.concatenate([last, (last - previous) / period_s], axis=1), covariance


def make_tracks(plots: np.ndarray, setting: SceneSetting, sigma_m: float) -> tuple[np.ndarray, np.ndarray]:
    """One radar's track histories from its plots (T, N, 2), T = track_points: states (T - 1, N, 4) and
    covariances (T - 1, N, 4, 4), by `setting.tracks` (module docstring). Every track of a radar sees the same
    plot times and noise, so the covariance and the Kalman gain are the same for all its tracks."""
    period = setting.scan_period_s
    state, covariance = _two_point(plots[0], plots[1], period, sigma_m)
    states, covariances = [state], [covariance]
    f, q = _transition(period), _process_noise(period, setting.acceleration_std_mps2)
    h, r = np.eye(2, 4), np.eye(2) * sigma_m ** 2
    for time in range(2, len(plots)):
        if setting.tracks == "two_point":
            state, covariance = _two_point(plots[time - 1], plots[time], period, sigma_m)
        else:
            state, predicted = state @ f.T, f @ covariance @ f.T + q
            gain = predicted @ h.T @ np.linalg.inv(h @ predicted @ h.T + r)
            state = state + (plots[time] - state @ h.T) @ gain.T
            joseph = np.eye(4) - gain @ h
            covariance = joseph @ predicted @ joseph.T + gain @ r @ gain.T
        states.append(state)
        covariances.append(covariance)
    count = plots.shape[1]
    return np.stack(states), np.broadcast_to(np.stack(covariances)[:, None], (len(states), count, 4, 4)).copy()


def _trajectories(rng: np.random.Generator, count: int, setting: SceneSetting) -> np.ndarray:
    """True positions (T, count, 2) of the white-noise acceleration model at the plot times."""
    half = setting.area_m / 2
    position = rng.uniform(-half, half, size=(count, 2))
    speed = rng.uniform(*setting.speed_mps, size=count)
    heading = rng.uniform(0.0, 2 * np.pi, size=count)
    state = np.concatenate([position, np.stack([np.sin(heading), np.cos(heading)], axis=1) * speed[:, None]], axis=1)
    f = _transition(setting.scan_period_s)
    t = setting.scan_period_s
    positions = [state[:, :2]]
    for _ in range(setting.track_points - 1):
        acceleration = rng.normal(0.0, setting.acceleration_std_mps2, size=(count, 2))
        state = state @ f.T + np.concatenate([acceleration * t ** 2 / 2, acceleration * t], axis=1)
        positions.append(state[:, :2])
    return np.stack(positions)


def make_scene(setting: SceneSetting, seed: int, index: int) -> Scene:
    """Scene `index` of `seed` (module docstring); the same arrays for the same arguments."""
    rng = np.random.default_rng([seed, index])
    count = int(rng.integers(setting.targets[0], setting.targets[1] + 1))
    truth = _trajectories(rng, count, setting)
    length = rng.uniform(*setting.bias_m)
    direction = rng.uniform(0.0, 2 * np.pi)
    bias = length * np.array([np.sin(direction), np.cos(direction)])
    tracked = [np.flatnonzero(rng.random(count) < setting.detection_probability) for _ in range(2)]
    targets = [rng.permutation(ids) for ids in tracked]
    radars = []
    for radar, (ids, sigma) in enumerate(zip(targets, setting.noise_m)):
        plots = truth[:, ids] + rng.normal(0.0, sigma, size=(setting.track_points, len(ids), 2))
        radars.append(make_tracks(plots + bias if radar == 1 else plots, setting, sigma))
    position2 = {target: j for j, target in enumerate(targets[1])}
    true_pairs = np.array([[i, position2[target]] for i, target in enumerate(targets[0]) if target in position2],
                          dtype=np.int64).reshape(-1, 2)
    return Scene(radars[0][0], radars[0][1], radars[1][0], radars[1][1], targets[0], targets[1], bias, true_pairs)

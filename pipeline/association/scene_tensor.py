"""What the association network reads (seed 002, section 2.2): the scene tensor and each pair's statistical distances.

Scene tensor (section 2.2 (1) and section 3 step 1): each radar's tracks sorted by position (by east, then
north: the seed's order I_s, "if x_i > x_j then I(i) > I(j); equal x, by y"); three distance matrices at
the common time, radar 1 with itself (n x n), radar 2 with itself (m x m) and radar 1 rows against radar 2
columns (n x m), each divided by the scene diameter L_C, zero-padded to size x size and stacked as
(size, size, 3) (channel order as the seed's e = 1, 2, 3). Distances are horizontal (east, north).

Pair features (section 2.2 (2)): for radar 1's track i and radar 2's track j, the statistical distances in
position, speed and heading: squared differences over the summed variances, the variances of speed
and heading linearised from the velocity covariance (their Jacobians; Bar-Shalom, Li & Kirubarajan (2001),
section 1.4.15). The heading difference is wrapped to [-π, π]. (n, m, 3) in [position, speed, heading] order.
The seed computes them over the two track segments (its formula was lost in the scraped text); here at the
common time, whose filtered state and covariance summarise the segment.
"""

from __future__ import annotations

import numpy as np

from pipeline.association.track_association import TrackInputError, check_pair_of_radars, statistical_distances

MIN_SPEED_MPS = 1.0  # the heading's variance is linearised at no less than this speed (a hovering track has none)
MIN_VARIANCE = 1e-12  # floor of a summed variance: two motionless tracks have no heading variance


def sort_order(positions: np.ndarray) -> np.ndarray:
    """Indices (n,) that sort positions (n, >=2) by east, then north: the seed's I_s⁻¹."""
    return np.lexsort((positions[:, 1], positions[:, 0]))


def scene_tensor(positions1: np.ndarray, positions2: np.ndarray, size: int, diameter_m: float) -> np.ndarray:
    """(size, size, 3) float32 (module docstring) from horizontal positions (n, 2) and (m, 2) in metres.
    TrackInputError when n or m exceeds `size` or a position is not finite."""
    positions1, positions2 = np.asarray(positions1, dtype=float), np.asarray(positions2, dtype=float)
    for label, positions in (("radar 1", positions1), ("radar 2", positions2)):
        if positions.ndim != 2 or positions.shape[1] < 2:
            raise TrackInputError(f"{label}: positions must be (n, 2), got shape {positions.shape}")
        if len(positions) > size:
            raise TrackInputError(f"{label}: {len(positions)} tracks, more than the scene tensor's size {size}")
        if not np.isfinite(positions).all():
            raise TrackInputError(f"{label}: a position is NaN or infinite")
    first = positions1[sort_order(positions1), :2]
    second = positions2[sort_order(positions2), :2]
    tensor = np.zeros((size, size, 3), dtype=np.float32)
    for channel, (rows, columns) in enumerate(((first, first), (second, second), (first, second))):
        distances = np.linalg.norm(rows[:, None] - columns[None], axis=-1) / diameter_m
        tensor[:len(rows), :len(columns), channel] = distances
    return tensor


def _speed_heading(states: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, ...]:
    """Speed (n,), heading from north (n,), and their linearised variances, from the horizontal velocity."""
    p = states.shape[1] // 2
    ve, vn = states[:, p], states[:, p + 1]
    velocity_covariance = covariances[:, p:p + 2, p:p + 2]
    speed = np.hypot(ve, vn)
    safe = np.maximum(speed, MIN_SPEED_MPS)
    speed_jacobian = np.stack([ve, vn], axis=1) / safe[:, None]
    heading_jacobian = np.stack([vn, -ve], axis=1) / safe[:, None] ** 2
    variance = [np.einsum("ni,nij,nj->n", jacobian, velocity_covariance, jacobian)
                for jacobian in (speed_jacobian, heading_jacobian)]
    return speed, np.arctan2(ve, vn), variance[0], variance[1]


def pair_features(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                  covariances2: np.ndarray) -> np.ndarray:
    """(n, m, 3) statistical distances in position, speed and heading (module docstring) of tracks at a common
    time: states (n, d) / (m, d), covariances (n, d, d) / (m, d, d). TrackInputError on bad tracks."""
    states1, covariances1, states2, covariances2 = check_pair_of_radars(states1, covariances1, states2, covariances2)
    p = states1.shape[1] // 2
    position = statistical_distances(states1[:, :p], covariances1[:, :p, :p], states2[:, :p], covariances2[:, :p, :p])
    speed1, heading1, speed_var1, heading_var1 = _speed_heading(states1, covariances1)
    speed2, heading2, speed_var2, heading_var2 = _speed_heading(states2, covariances2)
    speed = (speed1[:, None] - speed2[None]) ** 2 / (speed_var1[:, None] + speed_var2[None])
    turn = np.angle(np.exp(1j * (heading1[:, None] - heading2[None])))
    heading = turn ** 2 / np.maximum(heading_var1[:, None] + heading_var2[None], MIN_VARIANCE)
    return np.stack([position, speed, heading], axis=-1)

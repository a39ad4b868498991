"""Bias-robust track-to-track association: estimate radar 2's registration offset and associate with it removed.

Method (joint association and bias estimation, in the line of Levedahl (2002), "An explicit pattern
matching assignment algorithm", Proc. SPIE 4728, and Danford, Kragel & Poore (2007), "Joint MAP bias
estimation and data association", Proc. SPIE 6699): the two radars' pictures differ by an unknown
translation b (radar 2 sees every target at x + b); find the b under which the most tracks agree,
then alternate assignment and estimation until the pairs stop changing:

1. Votes (ours, a Hough-style start that needs no prior pairs): every position difference
   p2_j - p1_i no longer than `max_bias_m` whose velocities pass the chi-square test (a bias moves
   positions, not velocities) is a candidate offset; the candidate with the most candidates within
   `vote_radius_m` of it wins (ties: the shortest), and their mean is the first estimate.
2. Assignment: the gated chi-square assignment of `track_association` on x1 + H b - x2, with the
   estimate's covariance added to every pair's (its error is common to all pairs).
3. Estimate: the generalised least-squares offset over the assigned pairs (Gauss-Markov),
   b = (Σ Hᵀ S_k⁻¹ H)⁻¹ Σ Hᵀ S_k⁻¹ (x2_j - x1_i), S_k = P1_i + P2_j, H = [I; 0] (position rows);
   Cov(b) = (Σ Hᵀ S_k⁻¹ H)⁻¹. Back to 2 until the pairs repeat or `max_iterations`.

Stated accuracy: when the final pairs are right and the covariances consistent, b's error is zero-mean
Gaussian with covariance `bias_covariance_m2` (the GLS estimate's, which reaches the Cramér-Rao bound
for a common offset; Bar-Shalom, Willett & Tian (2011), "Tracking and Data Fusion", section on
sensor registration): its squared Mahalanobis error is chi-square with p = d/2 degrees of freedom.

Why this and not a reference-topology method (He You et al.'s anti-bias association, the seed's
reference [3]): it returns the offset and its accuracy, which the fusion needs to register radar 2's
tracks before fusing them; it works with few targets (topology features need neighbours) and its
cost is a few assignments. It models a translation only: a rotation (azimuth bias) or range-scale
bias appears as a position-dependent offset, which the gate then has to absorb.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from pipeline.track_association import assign, check_pair_of_radars, gate, statistical_distances


@dataclass(frozen=True)
class BiasRobustResult:
    """Pairs (K, 2) [radar 1 track, radar 2 track]; radar 2's estimated offset `bias_m` (p,) in metres (radar 2
    sees a target at its position + bias) and its covariance (p, p) in m² (the stated accuracy); the iterations run."""

    pairs: np.ndarray
    bias_m: np.ndarray
    bias_covariance_m2: np.ndarray
    iterations: int


def _candidate_offsets(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                       covariances2: np.ndarray, max_bias_m: float, gate_probability: float) -> np.ndarray:
    """(K, p) position differences p2_j - p1_i no longer than `max_bias_m` whose velocity blocks pass the
    chi-square gate (p = d / 2 velocity components)."""
    p = states1.shape[1] // 2
    if not len(states1) or not len(states2):
        return np.zeros((0, p))
    near = cKDTree(states1[:, :p]).query_ball_tree(cKDTree(states2[:, :p]), max_bias_m)
    rows = np.repeat(np.arange(len(near)), [len(columns) for columns in near])
    columns = np.fromiter((j for columns in near for j in sorted(columns)), dtype=np.int64, count=len(rows))
    velocity = (slice(None), slice(p, None))
    dv = states1[rows][velocity] - states2[columns][velocity]
    summed = covariances1[rows][:, p:, p:] + covariances2[columns][:, p:, p:]
    statistic = np.einsum("ki,ki->k", dv, np.linalg.solve(summed, dv[..., None])[..., 0])
    keep = statistic <= gate(gate_probability, p)
    return states2[columns[keep], :p] - states1[rows[keep], :p]


def _vote(offsets: np.ndarray, vote_radius_m: float) -> np.ndarray:
    """The mean of the offsets around the offset with the most neighbours within `vote_radius_m`
    (ties: the shortest); zero when there is no offset."""
    if not len(offsets):
        return np.zeros(offsets.shape[1])
    tree = cKDTree(offsets)
    counts = tree.query_ball_point(offsets, vote_radius_m, return_length=True)
    best = np.lexsort((np.linalg.norm(offsets, axis=1), -counts))[0]
    return offsets[tree.query_ball_point(offsets[best], vote_radius_m)].mean(axis=0)


def _least_squares_offset(difference: np.ndarray, summed: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """GLS offset of the position rows over pairs: differences (K, d) = x2 - x1, covariances (K, d, d);
    the estimate (p,) and its covariance (p, p)."""
    information = np.linalg.inv(summed)[:, :p, :]             # Hᵀ S⁻¹, (K, p, d)
    normal = information[:, :, :p].sum(axis=0)                  # Σ Hᵀ S⁻¹ H
    covariance = np.linalg.inv(normal)
    return covariance @ np.einsum("kpd,kd->p", information, difference), covariance


def associate_bias_robust(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                          covariances2: np.ndarray, gate_probability: float, max_bias_m: float,
                          vote_radius_m: float, max_iterations: int) -> BiasRobustResult:
    """Pairs and radar 2's offset (module docstring). States (N, d) / (M, d), covariances (N, d, d) /
    (M, d, d), ENU metres; offsets longer than `max_bias_m` are not found. With no pair the offset is 0
    with an infinite variance. TrackInputError on bad tracks."""
    states1, covariances1, states2, covariances2 = check_pair_of_radars(states1, covariances1, states2, covariances2)
    d = states1.shape[1]
    p = d // 2
    bias = _vote(_candidate_offsets(states1, covariances1, states2, covariances2, max_bias_m, gate_probability),
                 vote_radius_m)
    bias_covariance = np.zeros((p, p))
    threshold = gate(gate_probability, d)
    pairs = np.zeros((0, 2), dtype=np.int64)
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        shifted = states2.copy()
        shifted[:, :p] -= bias
        widened = covariances2.copy()
        widened[:, :p, :p] += bias_covariance
        distances = statistical_distances(states1, covariances1, shifted, widened)
        found = assign(distances, distances <= threshold)
        if not len(found):
            return BiasRobustResult(found, np.zeros(p), np.diag(np.full(p, np.inf)), iterations)
        rows, columns = found[:, 0], found[:, 1]
        bias, bias_covariance = _least_squares_offset(states2[columns] - states1[rows],
                                                      covariances1[rows] + covariances2[columns], p)
        if np.array_equal(found, pairs):
            break
        pairs = found
    return BiasRobustResult(pairs, bias, bias_covariance, iterations)

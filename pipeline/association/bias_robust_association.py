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
cost is a few assignments. It models a translation and, optionally, a clock offset; a rotation (azimuth
bias) or range-scale bias appears as a position-dependent offset, which the gate then has to absorb.

Clock offset (issue 27; `max_time_offset_s` > 0): radar 2's time stamps late by δ seconds place its track of
a target moving at v at x - δ v at every stamped time, an offset along each track's velocity, different for
each aircraft, which no single translation fits. The displacement model of the registration literature with
a time bias (Stone Soup PR #1217, "time bias feeders": sensor bias estimation in time and translation; the
same linearisation as Bar-Shalom, Willett & Tian (2011), ibid.) makes it linear in θ = [b, δ]:
x2_j - x1_i = H_j θ + noise, H_j = [[I, -v2_j]; [0, 0]] (position rows; v2_j radar 2's track velocity), and
the same steps estimate it: the vote (1) over a grid of δ in [-max_time_offset_s, max_time_offset_s] (each
candidate displacement o gives b = o + δ v; grid step vote_radius_m / the fastest candidate's speed), the
assignment (2) on x2 - H θ with H Cov(θ) Hᵀ added, and the GLS estimate (3) with H_j in place of H and a
zero-mean Gaussian prior of standard deviation max_time_offset_s on δ (a MAP estimate in the sense of Danford
et al.; it keeps the normal equations regular when all tracks fly parallel, where δ and b are confounded).
Translation alone is tried first; the joint result replaces it only when it pairs more tracks and its δ is
significant (δ² / Var(δ) beyond the chi-square quantile of 1 degree of freedom at the gate probability), so that
radars without a clock offset are associated as by the translation alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from pipeline.association.associator import Decision, TrackSet
from pipeline.association.track_association import assign, check_pair_of_radars, gate, statistical_distances


@dataclass(frozen=True)
class BiasRobustResult:
    """Pairs (K, 2) [radar 1 track, radar 2 track]; radar 2's estimated offset `bias_m` (p,) in metres (radar 2
    sees a target at its position + bias) and its covariance (p, p) in m² (the stated accuracy); the iterations run;
    radar 2's clock offset `time_offset_s` (its time stamps that much late; 0 when not estimated) and its
    variance `time_offset_variance_s2` (0 when not estimated)."""

    pairs: np.ndarray
    bias_m: np.ndarray
    bias_covariance_m2: np.ndarray
    iterations: int
    time_offset_s: float = 0.0
    time_offset_variance_s2: float = 0.0


def registered(states: np.ndarray, bias_m: np.ndarray | None, time_offset_s: float | None) -> np.ndarray:
    """Radar 2's states (N, d) in radar 1's registration: positions less `bias_m` (its first components; None:
    none) and moved by `time_offset_s` times the track's velocity (None: none) (module docstring), a copy."""
    out = np.array(states, dtype=float)
    p = out.shape[1] // 2
    if bias_m is not None:
        out[:, :len(bias_m)] -= bias_m
    if time_offset_s:
        out[:, :p] += time_offset_s * out[:, p:]
    return out


def _candidates(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray, covariances2: np.ndarray,
                radius_m: float, gate_probability: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows (K,) and columns (K,) of the pairs whose positions are within `radius_m` and whose velocity blocks
    pass the chi-square gate (p = d / 2 velocity components)."""
    p = states1.shape[1] // 2
    if not len(states1) or not len(states2):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    near = cKDTree(states1[:, :p]).query_ball_tree(cKDTree(states2[:, :p]), radius_m)
    rows = np.repeat(np.arange(len(near)), [len(columns) for columns in near])
    columns = np.fromiter((j for columns in near for j in sorted(columns)), dtype=np.int64, count=len(rows))
    velocity = (slice(None), slice(p, None))
    dv = states1[rows][velocity] - states2[columns][velocity]
    summed = covariances1[rows][:, p:, p:] + covariances2[columns][:, p:, p:]
    statistic = np.einsum("ki,ki->k", dv, np.linalg.solve(summed, dv[..., None])[..., 0])
    keep = statistic <= gate(gate_probability, p)
    return rows[keep], columns[keep]


def _vote(offsets: np.ndarray, vote_radius_m: float) -> tuple[np.ndarray, int]:
    """The mean of the offsets around the offset with the most neighbours within `vote_radius_m`
    (ties: the shortest), and that count; zero when there is no offset."""
    if not len(offsets):
        return np.zeros(offsets.shape[1]), 0
    tree = cKDTree(offsets)
    counts = tree.query_ball_point(offsets, vote_radius_m, return_length=True)
    best = np.lexsort((np.linalg.norm(offsets, axis=1), -counts))[0]
    return offsets[tree.query_ball_point(offsets[best], vote_radius_m)].mean(axis=0), int(counts[best])


def _vote_with_time(offsets: np.ndarray, velocities: np.ndarray, max_bias_m: float, vote_radius_m: float,
                    max_time_offset_s: float) -> np.ndarray:
    """θ = [b, δ] (p + 1,) of the vote over a grid of δ (module docstring): at each δ the candidates'
    translations b = o + δ v no longer than `max_bias_m` vote (`_vote`); most votes win, ties the smallest |δ|."""
    speed = np.linalg.norm(velocities, axis=1).max(initial=0.0)
    steps = int(np.ceil(max_time_offset_s * speed / vote_radius_m))
    best = (-1, 0.0, np.zeros(offsets.shape[1]))
    for delta in sorted(np.linspace(-max_time_offset_s, max_time_offset_s, 2 * steps + 1), key=abs):
        translations = offsets + delta * velocities
        translation, count = _vote(translations[np.linalg.norm(translations, axis=1) <= max_bias_m], vote_radius_m)
        if count > best[0]:
            best = (count, delta, translation)
    return np.append(best[2], best[1])


def _least_squares(difference: np.ndarray, summed: np.ndarray, design: np.ndarray,
                   prior_information: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GLS (MAP with a zero-mean prior of information `prior_information` (q, q)) θ of differences (K, d) = x2 - x1
    with covariances (K, d, d) and design matrices H (K, d, q): the estimate (q,) and its covariance (q, q)."""
    information = design.transpose(0, 2, 1) @ np.linalg.inv(summed)          # Hᵀ S⁻¹, (K, q, d)
    normal = (information @ design).sum(axis=0) + prior_information          # Σ Hᵀ S⁻¹ H + Λ0
    covariance = np.linalg.inv(normal)
    return covariance @ np.einsum("kqd,kd->q", information, difference), covariance


def _translation_design(count: int, d: int) -> np.ndarray:
    """H = [I; 0] (count, d, p): a translation of the positions."""
    return np.broadcast_to(np.eye(d, d // 2), (count, d, d // 2)).copy()


def _time_design(states2: np.ndarray) -> np.ndarray:
    """H_j = [[I, -v2_j]; [0, 0]] (M, d, p + 1): a translation and a clock offset (module docstring)."""
    m, d = states2.shape
    p = d // 2
    design = np.zeros((m, d, p + 1))
    design[:, :p, :p] = np.eye(p)
    design[:, :p, p] = -states2[:, p:]
    return design


def _iterate(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray, covariances2: np.ndarray,
             theta: np.ndarray, design: np.ndarray, prior_information: np.ndarray, threshold: float,
             max_iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Steps 2 and 3 (module docstring) from θ: pairs (K, 2), θ (q,), Cov(θ) (q, q) (θ = 0 with infinite
    variances when nothing pairs) and the iterations run."""
    q = len(theta)
    theta_covariance = np.zeros((q, q))
    pairs = np.zeros((0, 2), dtype=np.int64)
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        shifted = states2 - design @ theta
        widened = covariances2 + design @ theta_covariance @ design.transpose(0, 2, 1)
        distances = statistical_distances(states1, covariances1, shifted, widened)
        found = assign(distances, distances <= threshold)
        if not len(found):
            return found, np.zeros(q), np.diag(np.full(q, np.inf)), iterations
        rows, columns = found[:, 0], found[:, 1]
        theta, theta_covariance = _least_squares(states2[columns] - states1[rows],
                                                 covariances1[rows] + covariances2[columns], design[columns],
                                                 prior_information)
        if np.array_equal(found, pairs):
            break
        pairs = found
    return pairs, theta, theta_covariance, iterations


def _with_time_offset(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray, covariances2: np.ndarray,
                      gate_probability: float, max_bias_m: float, vote_radius_m: float, max_iterations: int,
                      max_time_offset_s: float) -> BiasRobustResult:
    """The joint translation and clock offset estimate and its pairs (module docstring)."""
    p = states1.shape[1] // 2
    speed = np.linalg.norm(states2[:, p:], axis=1).max(initial=0.0)
    rows, columns = _candidates(states1, covariances1, states2, covariances2,
                                max_bias_m + max_time_offset_s * speed, gate_probability)
    theta = _vote_with_time(states2[columns, :p] - states1[rows, :p], states2[columns, p:], max_bias_m,
                            vote_radius_m, max_time_offset_s)
    prior = np.zeros((p + 1, p + 1))
    prior[p, p] = max_time_offset_s ** -2
    pairs, theta, covariance, iterations = _iterate(states1, covariances1, states2, covariances2, theta,
                                                    _time_design(states2), prior, gate(gate_probability, 2 * p),
                                                    max_iterations)
    return BiasRobustResult(pairs, theta[:p], covariance[:p, :p], iterations, float(theta[p]),
                            float(covariance[p, p]))


def associate_bias_robust(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                          covariances2: np.ndarray, gate_probability: float, max_bias_m: float,
                          vote_radius_m: float, max_iterations: int, max_time_offset_s: float = 0.0
                          ) -> BiasRobustResult:
    """Pairs and radar 2's offset (module docstring). States (N, d) / (M, d), covariances (N, d, d) /
    (M, d, d), ENU metres; offsets longer than `max_bias_m` are not found. With no pair the offset is 0
    with an infinite variance. With `max_time_offset_s` > 0 a clock offset up to it is estimated too, and used
    where it pairs more tracks and is significant. TrackInputError on bad tracks."""
    states1, covariances1, states2, covariances2 = check_pair_of_radars(states1, covariances1, states2, covariances2)
    d = states1.shape[1]
    p = d // 2
    rows, columns = _candidates(states1, covariances1, states2, covariances2, max_bias_m, gate_probability)
    bias, _ = _vote(states2[columns, :p] - states1[rows, :p], vote_radius_m)
    pairs, bias, bias_covariance, iterations = _iterate(states1, covariances1, states2, covariances2, bias,
                                                        _translation_design(len(states2), d), np.zeros((p, p)),
                                                        gate(gate_probability, d), max_iterations)
    result = BiasRobustResult(pairs, bias, bias_covariance, iterations)
    if max_time_offset_s <= 0.0 or len(pairs) == min(len(states1), len(states2)):
        return result
    joint = _with_time_offset(states1, covariances1, states2, covariances2, gate_probability, max_bias_m,
                              vote_radius_m, max_iterations, max_time_offset_s)
    significant = joint.time_offset_s ** 2 > gate(gate_probability, 1) * joint.time_offset_variance_s2
    return joint if significant and len(joint.pairs) > len(pairs) else result


@dataclass(frozen=True)
class BiasRobustAssociator:
    """`associate_bias_robust` at the current common time, with its offset, clock offset and the offset's
    covariance in the decision."""

    gate_probability: float
    max_bias_m: float
    vote_radius_m: float
    max_iterations: int
    max_time_offset_s: float
    common_times = 1

    def associate_tracks(self, tracks1: TrackSet, tracks2: TrackSet) -> Decision:
        result = associate_bias_robust(*tracks1.current, *tracks2.current, self.gate_probability, self.max_bias_m,
                                       self.vote_radius_m, self.max_iterations, self.max_time_offset_s)
        return Decision(result.pairs, result.bias_m, result.time_offset_s, result.bias_covariance_m2)

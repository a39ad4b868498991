"""Statistical track-to-track association between two radars (seed 002's classical baselines).

Tracks are given per radar at a common time as states (N, d) in ENU metres and m/s, d = 4
([east, north, v_east, v_north]) or 6 ([east, north, up, v_east, v_north, v_up]), with their
covariances (N, d, d). A pair is a row [i, j]: radar 1's track i with radar 2's track j.

- `statistical_distances`: the track-to-track test statistic of Bar-Shalom (1981), "On the
  track-to-track correlation problem", IEEE Trans. Automatic Control 26(2), and Bar-Shalom & Li
  (1995), "Multitarget-Multisensor Tracking: Principles and Techniques", section 8.4: the
  difference of two estimates of one target, Δ = x1 - x2, is zero-mean with covariance
  S = P1 + P2 - P12 - P21. The cross-covariance P12 (common process noise) is neglected here, as
  the seed does: for tracks of few updates it is small, and neglecting it makes S larger, so the
  test is conservative. Δᵀ S⁻¹ Δ is then chi-square with d degrees of freedom.
- `associate_statistical`: the test as a gate (chi-square quantile at `gate_probability`) and the
  one-to-one choice of pairs as a 2-D assignment minimising the summed statistic over gated pairs
  (scipy's `linear_sum_assignment`, the Jonker-Volgenant algorithm).
- `associate_double_threshold`: the statistical double-threshold method the seed compares with
  (He You et al., "Radar Data Processing with Applications", Wiley 2016, chapter 13, and the seed's
  reference [1]): over the last L common times, a first threshold (the chi-square gate) marks each
  time a pair passes; a second threshold M declares the pair associated when it passed at least M
  of the L times; conflicts are settled by an assignment on the pass counts (most passes, then the
  smallest summed statistic).

`StatisticalAssociator` and `DoubleThresholdAssociator` are the two as associators (`associator.Associator`,
entries of `pipeline.association.registry`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

from pipeline.association.associator import Decision, TrackSet
from pipeline.io import InputError

STATE_SIZES = (4, 6)   # [e, n, ve, vn] or [e, n, u, ve, vn, vu]
FORBIDDEN = 1e12       # assignment cost of a gated-out pair (never chosen while a gated pair is left)


class TrackInputError(InputError):
    """Tracks or covariances unusable for association: the message names the radar and what is wrong."""


def correlation_eigenvalues(covariances: np.ndarray) -> np.ndarray:
    """Ascending eigenvalues (N, d) of the correlation matrices D^-1/2 P D^-1/2 of covariances (N, d, d) with
    positive diagonals D. P is positive definite exactly when they are all positive (a congruence keeps the signs
    of the eigenvalues: Sylvester's law of inertia), and they are computed to about d·ε absolute, whatever P's
    scale: the diagonal scaling is within a factor d of the best (van der Sluis (1969), "Condition numbers and
    equilibration of matrices", Numer. Math. 14; Higham (2002), "Accuracy and Stability of Numerical
    Algorithms", chapters 7 and 10 on scaling and the Cholesky factorisation), where P's own eigenvalues are only good to ε·max(P), so that a variance of
    1e20 m² beside 1 m² would be judged indefinite."""
    if not len(covariances):
        return np.zeros((0, covariances.shape[-1]))
    scale = 1.0 / np.sqrt(np.diagonal(covariances, axis1=1, axis2=2))
    return np.linalg.eigvalsh(covariances * scale[:, :, None] * scale[:, None, :])


def positive_definite(covariances: np.ndarray) -> np.ndarray:
    """Which covariances (N, d, d) are positive definite (N,) bool: positive diagonal and positive
    `correlation_eigenvalues` (scale-free)."""
    diagonal = np.diagonal(covariances, axis1=1, axis2=2)
    good = (diagonal > 0.0).all(axis=1) & np.isfinite(covariances).all(axis=(1, 2))
    good[good] = correlation_eigenvalues(covariances[good])[:, 0] > 0.0
    return good


def check_tracks(states: np.ndarray, covariances: np.ndarray, label: str) -> tuple[np.ndarray, np.ndarray]:
    """`states` (N, d) and `covariances` (N, d, d) as float64, checked: d in STATE_SIZES, finite, covariances
    symmetric and positive definite (`positive_definite`, whatever their scale). TrackInputError naming `label`
    (e.g. "radar 2") and the first bad track."""
    states, covariances = np.asarray(states, dtype=float), np.asarray(covariances, dtype=float)
    if states.ndim != 2 or states.shape[1] not in STATE_SIZES:
        raise TrackInputError(f"{label}: states must be (N, d) with d in {STATE_SIZES}, got shape {states.shape}")
    n, d = states.shape
    if covariances.shape != (n, d, d):
        raise TrackInputError(f"{label}: covariances must be {(n, d, d)} for states {states.shape}, "
                              f"got {covariances.shape}")
    for name, values in (("state", states), ("covariance", covariances)):
        bad = ~np.isfinite(values).all(axis=tuple(range(1, values.ndim)))
        if bad.any():
            raise TrackInputError(f"{label}: {int(bad.sum())} track(s) with a NaN or infinite {name} "
                                  f"(first: track {int(np.argmax(bad))})")
    asymmetric = ~np.isclose(covariances, covariances.transpose(0, 2, 1), rtol=1e-6, atol=1e-9).all(axis=(1, 2))
    if asymmetric.any():
        raise TrackInputError(f"{label}: covariance of track {int(np.argmax(asymmetric))} is not symmetric")
    definite = positive_definite(covariances)
    if not definite.all():
        raise TrackInputError(f"{label}: covariance of track {int(np.argmin(definite))} is not positive definite")
    return states, covariances


def check_pair_of_radars(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                         covariances2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Both radars' tracks checked (`check_tracks`) and of the same state size (TrackInputError if not)."""
    states1, covariances1 = check_tracks(states1, covariances1, "radar 1")
    states2, covariances2 = check_tracks(states2, covariances2, "radar 2")
    if states1.shape[1] != states2.shape[1]:
        raise TrackInputError(f"radar 1 states have {states1.shape[1]} components, radar 2 states "
                              f"{states2.shape[1]}: both must use the same state layout")
    return states1, covariances1, states2, covariances2


def statistical_distances(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                          covariances2: np.ndarray) -> np.ndarray:
    """(N, M) test statistics Δᵀ (P1 + P2)⁻¹ Δ, Δ = x1_i - x2_j (Bar-Shalom 1981; module docstring).
    Inputs unchecked (see `check_pair_of_radars`); shapes (N, d), (N, d, d), (M, d), (M, d, d)."""
    difference = states1[:, None, :] - states2[None, :, :]
    summed = covariances1[:, None] + covariances2[None, :]
    return np.einsum("nmi,nmi->nm", difference, np.linalg.solve(summed, difference[..., None])[..., 0])


def gate(probability: float, state_size: int) -> float:
    """The chi-square quantile of `state_size` degrees of freedom at `probability`: a true pair's statistic
    stays below it with that probability."""
    return float(chi2.ppf(probability, state_size))


def assign(cost: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """One-to-one pairs (K, 2) minimising the summed `cost` (N, M) over `allowed` entries, sorted by row;
    pairs not allowed are never returned."""
    if not allowed.any():
        return np.zeros((0, 2), dtype=np.int64)
    rows, columns = linear_sum_assignment(np.where(allowed, cost, FORBIDDEN))
    keep = allowed[rows, columns]
    return np.stack([rows[keep], columns[keep]], axis=1).astype(np.int64)


def associate_statistical(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                          covariances2: np.ndarray, gate_probability: float) -> np.ndarray:
    """Pairs (K, 2) of the gated chi-square assignment (module docstring). TrackInputError on bad tracks."""
    states1, covariances1, states2, covariances2 = check_pair_of_radars(states1, covariances1, states2, covariances2)
    distances = statistical_distances(states1, covariances1, states2, covariances2)
    return assign(distances, distances <= gate(gate_probability, states1.shape[1]))


def associate_double_threshold(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                               covariances2: np.ndarray, gate_probability: float, hits: int) -> np.ndarray:
    """Pairs (K, 2) of the double-threshold method (module docstring) over a history of L common times:
    states (L, N, d), covariances (L, N, d, d) per radar, the last time last. A pair passes a time when its
    statistic is under the chi-square gate, and is associated when it passed at least `hits` of the L times.
    TrackInputError on bad tracks or `hits` outside [1, L]."""
    states1, states2 = np.asarray(states1, dtype=float), np.asarray(states2, dtype=float)
    if states1.ndim != 3 or states2.ndim != 3 or len(states1) != len(states2):
        raise TrackInputError(f"double threshold: states must be (L, N, d) for both radars with the same L, got "
                              f"{states1.shape} and {states2.shape}")
    if not 1 <= hits <= len(states1):
        raise TrackInputError(f"double threshold: hits = {hits} must be in [1, {len(states1)}] (the history length)")
    passes = np.zeros((states1.shape[1], states2.shape[1]), dtype=np.int64)
    summed = np.zeros(passes.shape)
    for time in range(len(states1)):
        x1, p1, x2, p2 = check_pair_of_radars(states1[time], covariances1[time], states2[time], covariances2[time])
        distances = statistical_distances(x1, p1, x2, p2)
        passes += distances <= gate(gate_probability, x1.shape[1])
        summed += np.minimum(distances, FORBIDDEN / 1e3)
    # most passes first; among equal counts the smallest summed statistic (scaled below one pass)
    cost = -passes + summed / (summed.max() + 1.0) if summed.size else summed
    return assign(cost, passes >= hits)


@dataclass(frozen=True)
class StatisticalAssociator:
    """`associate_statistical` at the current common time."""

    gate_probability: float
    common_times = 1

    def associate_tracks(self, tracks1: TrackSet, tracks2: TrackSet) -> Decision:
        return Decision(associate_statistical(*tracks1.current, *tracks2.current, self.gate_probability), None)


@dataclass(frozen=True)
class DoubleThresholdAssociator:
    """`associate_double_threshold` over the latest `common_times` common times, among the tracks present at all
    of them (by id); no pair while fewer common times are given (a scenario's first common_times - 1)."""

    gate_probability: float
    hits: int
    common_times: int

    def associate_tracks(self, tracks1: TrackSet, tracks2: TrackSet) -> Decision:
        if len(tracks1.ids) < self.common_times:
            return Decision(np.zeros((0, 2), dtype=np.int64), None)
        rows = [_rows_throughout(tracks.ids) for tracks in (tracks1, tracks2)]
        stacked = [np.stack([values[r] for values, r in zip(part, rows[user])])
                   for user, tracks in enumerate((tracks1, tracks2)) for part in (tracks.states, tracks.covariances)]
        found = associate_double_threshold(*stacked, self.gate_probability, self.hits)
        last = [rows[0][-1], rows[1][-1]]
        return Decision(np.stack([last[0][found[:, 0]], last[1][found[:, 1]]], axis=1).reshape(-1, 2), None)


def _rows_throughout(ids: tuple[np.ndarray, ...]) -> list[np.ndarray]:
    """Per common time, the rows of the tracks present at every one of them (ids ascending at each)."""
    common = ids[0]
    for later in ids[1:]:
        common = np.intersect1d(common, later)
    return [np.searchsorted(at, common) for at in ids]

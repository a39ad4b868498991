"""Fusion of associated track pairs by covariance intersection (Julier & Uhlmann (1997), "A non-divergent
estimation algorithm in the presence of unknown correlations", Proc. American Control Conference, eq. 6-7).

Two radars' tracks of one target share process noise (and, when both radars' plots were ever fused, their
errors), and that correlation is unknown; the optimal (Bar-Shalom-Campo) fusion needs it. Covariance
intersection is consistent for any correlation:
    P⁻¹ = ω P1⁻¹ + (1 - ω) P2⁻¹,   x = P (ω P1⁻¹ x1 + (1 - ω) P2⁻¹ x2),   ω in [0, 1],
with ω chosen to minimise the trace or the determinant of P (scipy's bounded scalar minimiser; the
determinant is minimised through its logarithm, the same minimiser). Two equal tracks give that track and
its covariance for every ω. Radar 2's registration offset, if estimated (`bias_robust_association`), is
removed from its positions before fusing.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from pipeline.association.track_association import TrackInputError, check_pair_of_radars
from pipeline.params import ParamError, Params

CRITERIA = ("trace", "determinant")


def check_params(params: Params) -> None:
    """`associate.fusion_criterion`: one of CRITERIA (ParamError)."""
    if params.associate.fusion_criterion not in CRITERIA:
        raise ParamError(f"associate.fusion_criterion = {params.associate.fusion_criterion!r}: must be one of "
                         f"{CRITERIA}")


def _size(covariance: np.ndarray, criterion: str) -> float:
    return float(np.trace(covariance)) if criterion == "trace" else float(np.linalg.slogdet(covariance)[1])


def intersect(state1: np.ndarray, covariance1: np.ndarray, state2: np.ndarray, covariance2: np.ndarray,
              criterion: str) -> tuple[np.ndarray, np.ndarray, float]:
    """One pair's fused state (d,), covariance (d, d) and weight ω of track 1 (module docstring)."""
    information1, information2 = np.linalg.inv(covariance1), np.linalg.inv(covariance2)

    def fused_covariance(omega: float) -> np.ndarray:
        return np.linalg.inv(omega * information1 + (1.0 - omega) * information2)

    omega = float(minimize_scalar(lambda w: _size(fused_covariance(w), criterion), bounds=(0.0, 1.0),
                                  method="bounded", options={"xatol": 1e-6}).x)
    covariance = fused_covariance(omega)
    state = covariance @ (omega * information1 @ state1 + (1.0 - omega) * information2 @ state2)
    return state, (covariance + covariance.T) / 2, omega


def fuse_pairs(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray, covariances2: np.ndarray,
               pairs: np.ndarray, criterion: str = "trace",
               bias_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fused states (K, d), covariances (K, d, d) and weights (K,) of the `pairs` (K, 2) [radar 1 track, radar 2
    track]; radar 2's positions less `bias_m` (p,) if given. TrackInputError on bad tracks, pairs out of range
    or an unknown criterion."""
    states1, covariances1, states2, covariances2 = check_pair_of_radars(states1, covariances1, states2, covariances2)
    if criterion not in CRITERIA:
        raise TrackInputError(f"fusion criterion {criterion!r}: must be one of {CRITERIA}")
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) and (pairs.min() < 0 or pairs[:, 0].max() >= len(states1) or pairs[:, 1].max() >= len(states2)):
        raise TrackInputError(f"pairs index tracks that do not exist (radar 1 has {len(states1)}, radar 2 "
                              f"{len(states2)})")
    if bias_m is not None:
        states2 = states2.copy()
        states2[:, :len(bias_m)] -= bias_m
    d = states1.shape[1]
    fused_states, fused_covariances = np.zeros((len(pairs), d)), np.zeros((len(pairs), d, d))
    weights = np.zeros(len(pairs))
    for k, (i, j) in enumerate(pairs):
        fused_states[k], fused_covariances[k], weights[k] = intersect(states1[i], covariances1[i], states2[j],
                                                                      covariances2[j], criterion)
    return fused_states, fused_covariances, weights

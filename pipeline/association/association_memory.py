"""Track-to-track association with memory: one common time's pairs continued from the last time's, and the
tracks a method left unpaired that are one aircraft seen by both radars paired after all.

Why: our local tracks' chi-square statistics have heavy tails (manoeuvres the two-point velocity lags, an azimuth
bias that moves positions by range): about 4 % of true pairs exceed the gate at `association.gate_probability`
(0.999, where 0.1 % would for consistent covariances). A pair missed at one common time leaves both tracks in
the fused picture: one aircraft reported twice, GOSPA's false part. Multi-sensor trackers do not decide each
time anew: they keep the last association as long as it stays plausible and test new pairs only among the
tracks left over (track-to-track association over a sliding window of past times, Tian & Bar-Shalom (2009),
"Track-to-track fusion configurations and association in a sliding window", J. Advances in Information Fusion
4(2); Blackman & Popoli (1999), "Design and Analysis of Modern Tracking Systems", chapter 9, multiple-sensor
tracking, on using the previous track-to-track decisions). The rule here (ours, in that spirit), the same for
every method, applied after the method's own decision at each common time:

1. Held pairs: the last common time's pairs of this scenario (by track ids) whose tracks are both still there and
   whose statistic Δᵀ (P1 + P2)⁻¹ Δ (d = 4, after the method's offset and clock offset removal, as the method
   compares) is under the keep gate, the chi-square quantile at `keep_probability` (looser than the forming gate:
   a pair once formed needs more evidence to break than to form, a hysteresis).
2. The method's pairs whose two tracks are both still free.
3. The tracks still unpaired on both sides, assigned among themselves (`track_association.assign`, minimum summed
   statistic) under the keep gate: two unpaired tracks that pass it are one aircraft, reported once.
"""

from __future__ import annotations

import numpy as np

from pipeline.association.bias_robust_association import registered
from pipeline.association.common_time_states import Snapshot
from pipeline.association.track_association import assign, gate, statistical_distances

HORIZONTAL = np.array([0, 1, 3, 4])  # [e, n, ve, vn] of [e, n, u, ve, vn, vu]: what every method compares
STATE_SIZE = len(HORIZONTAL)


def horizontal(states: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[e, n, ve, vn] states (N, 4) and covariances (N, 4, 4) of full ones (N, 6), (N, 6, 6)."""
    return states[:, HORIZONTAL], covariances[:, HORIZONTAL[:, None], HORIZONTAL[None, :]]


def pair_statistics(snapshot: Snapshot, bias_m: np.ndarray | None, time_offset_s: float | None = None) -> np.ndarray:
    """(N1, N2) chi-square statistics of every pair of the snapshot's horizontal states, the second user's
    registered (`bias_robust_association.registered`: positions less `bias_m` (2,) east, north m and moved by
    `time_offset_s` times its velocity, each if given)."""
    (x1, p1), (x2, p2) = (horizontal(x, p) for x, p in zip(snapshot.states, snapshot.covariances))
    if not len(x1) or not len(x2):
        return np.zeros((len(x1), len(x2)))
    return statistical_distances(x1, p1, registered(x2, bias_m, time_offset_s), p2)


def continue_pairs(snapshot: Snapshot, pairs: np.ndarray, bias_m: np.ndarray | None, held: set[tuple[int, int]],
                   keep_probability: float, time_offset_s: float | None = None) -> np.ndarray:
    """One common time's pairs (K, 2) (rows of the snapshot, sorted) from the method's `pairs` (M, 2), its
    offset `bias_m` and clock offset `time_offset_s` (each or None) and the last time's pairs `held` as (first
    user's id, second user's id), by the module docstring's three steps."""
    statistics = pair_statistics(snapshot, bias_m, time_offset_s)
    keep = gate(keep_probability, STATE_SIZE)
    row = {int(track): i for i, track in enumerate(snapshot.ids[0])}
    column = {int(track): j for j, track in enumerate(snapshot.ids[1])}
    chosen = [(row[a], column[b]) for a, b in sorted(held)
              if a in row and b in column and statistics[row[a], column[b]] <= keep]
    used = [{i for i, _ in chosen}, {j for _, j in chosen}]
    for i, j in np.asarray(pairs, dtype=np.int64).reshape(-1, 2).tolist():
        if i not in used[0] and j not in used[1]:
            chosen.append((i, j))
            used[0].add(i)
            used[1].add(j)
    rows = np.setdiff1d(np.arange(statistics.shape[0]), list(used[0]))
    columns = np.setdiff1d(np.arange(statistics.shape[1]), list(used[1]))
    leftover = statistics[np.ix_(rows, columns)]
    chosen += [(rows[i], columns[j]) for i, j in assign(leftover, leftover <= keep).tolist()]
    return np.array(sorted(chosen), dtype=np.int64).reshape(-1, 2)


def with_memory(snapshots: list[Snapshot], pairs: list[np.ndarray], biases: list[np.ndarray | None],
                keep_probability: float, time_offsets: list[float | None] | None = None) -> list[np.ndarray]:
    """Every common time's pairs continued (`continue_pairs`) in order, with each time's offset and clock offset
    (None: all None); the memory is emptied at each new scenario (its track ids are another recording's)."""
    out: list[np.ndarray] = []
    held: set[tuple[int, int]] = set()
    offsets = time_offsets if time_offsets is not None else [None] * len(snapshots)
    for index, (snapshot, found, bias, offset) in enumerate(zip(snapshots, pairs, biases, offsets)):
        if index and snapshots[index - 1].scenario_id != snapshot.scenario_id:
            held = set()
        continued = continue_pairs(snapshot, found, bias, held, keep_probability, offset)
        held = {(int(snapshot.ids[0][i]), int(snapshot.ids[1][j])) for i, j in continued.tolist()}
        out.append(continued)
    return out

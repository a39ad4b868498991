"""GOSPA with its parts, and the identity metrics read off its assignment: track switches,
tracks per truth and track purity. For many truths and many tracks per scan.

**GOSPA** (Rahmathullah, García-Fernández and Svensson, "Generalized optimal sub-pattern
assignment metric", FUSION 2017, Proposition 1, for α = 2): between the set of truths X and the
set of track estimates Y of one scan, with d the Euclidean distance, cutoff c and order p,

    GOSPA(X, Y) = ( min over assignments γ of  Σ_{(i, j) in γ} d(x_i, y_j)^p + c^p/2 (|X| + |Y| - 2 |γ|) )^(1/p),

γ a one-to-one pairing of some truths with some tracks. Only pairs closer than c are worth
pairing (a pair at d >= c costs d^p >= c^p, no less than leaving both unpaired), so the same
minimum is the linear assignment of all min(|X|, |Y|) pairs with cost min(d, c)^p
plus c^p/2 per unpaired element (solved with scipy's `linear_sum_assignment`), after which pairs
at d >= c are taken apart. The sum splits into three parts (m^p, before the root):
- localisation: Σ d^p over the assigned pairs (d < c);
- missed: c^p/2 per truth left without a track;
- false: c^p/2 per track left without a truth;
GOSPA = (localisation + missed + false)^(1/p), in metres; 0 for two empty sets. Unlike OSPA
(`pipeline.bench.ospa`) it is not normalised by the larger set, so it grows with the number of
mistakes, and a missed truth costs c/2^(1/p), not c.

**Parts in metres** (`shares_in_metres`): the parts are additive only before the root. For
tables each scan's GOSPA is split in proportion to its parts, part × GOSPA / (localisation +
missed + false), so the three shares add up to the scan's GOSPA and their means over scans to
the mean GOSPA. For p = 1 the shares are the parts themselves.

**Track switches** (`track_switches`): for each truth, per scan, its best-matching confirmed
track is the track the GOSPA assignment of that scan pairs it with (within the cutoff). A switch
is counted each time that track id changes to another track id. Scans where the truth has no
assigned track are skipped, not a reset: A, none, B is one switch and A, none, A none, as CLEAR
MOT's identity switches (Bernardin and Stiefelhagen, "Evaluating multiple object tracking
performance: the CLEAR MOT metrics", EURASIP J. Image Video Process. 2008), which compare a
truth's match with its last known one. So a track lost and taken up again by the same track is
missed scans, not a switch, and a new track taking over after a gap is one switch; a crossing
where two tracks swap their truths is two switches, one per truth. (Trajectory GOSPA,
García-Fernández, Rahmathullah and Svensson, IEEE Trans. Signal Process. 2020, also charges half
a switch for going to or from no track; we leave that to the missed part.)

**Kept pairs** (`scan_gospa(..., keep_pairs=True)`, for scenes of many aircraft): where two
truths come closer than the estimates' errors (two aircraft crossing), GOSPA's assignment of a
single scan may pair each with the other's track, and back the next scan: two switches for each
truth, though no track changed aircraft. CLEAR MOT (above) keeps a correspondence while it stays
valid, and so do kept pairs: a truth keeps the track it was last paired with while that track's
estimate is within the cutoff of it (and not taken by a truth that kept it first, in truth id
order); the truths and tracks left are paired as GOSPA pairs them (the linear assignment, pairs at
d >= c taken apart). A track that really swaps aircraft is switched when it leaves the cutoff of
its old one. The GOSPA parts are always those of GOSPA's own assignment; only the pairs the
identity metrics read change.

**Tracks per truth** (`tracks_per_truth`): the distinct confirmed tracks ever assigned to a
truth; 1 is one track all along, 0 a truth never tracked.

**Track purity** (`track_purity`): per confirmed track ever assigned to a truth, the share of
its assigned scans spent on the truth it was assigned to most often; 1 for a track that kept to
one truth. Tracks never assigned (false tracks only) have no purity.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import linear_sum_assignment

PARTS = ("localisation", "missed", "false")


def gospa_parts(distances: np.ndarray, cutoff: float, order: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One scan: the GOSPA parts (3,) localisation, missed, false (m^p) and the assigned pairs,
    as rows (A,) of `distances` (the truths) and columns (A,) (the tracks), from the distances
    (T, K) m between T truths and K track estimates."""
    truths, tracks = distances.shape
    rows = columns = np.empty(0, dtype=np.intp)
    if truths and tracks:
        rows, columns = linear_sum_assignment(np.minimum(distances, cutoff) ** order)
        within = distances[rows, columns] < cutoff
        rows, columns = rows[within], columns[within]
    half = cutoff ** order / 2.0
    return (np.array([float((distances[rows, columns] ** order).sum()), half * (truths - len(rows)),
                      half * (tracks - len(rows))]), rows, columns)


def gospa(distances: np.ndarray, cutoff: float, order: float) -> float:
    """One scan's GOSPA (m) from the distances (T, K) m between its truths and track estimates."""
    return float(gospa_parts(distances, cutoff, order)[0].sum() ** (1.0 / order))


@dataclass(frozen=True)
class ScanGospa:
    """GOSPA over S scans: each scan's parts and the pairs its assignment made (A in all)."""

    parts: np.ndarray  # (S, 3) m^p: localisation, missed, false of each scan (`PARTS`)
    scan: np.ndarray   # (A,) the scan of each assigned pair
    truth: np.ndarray  # (A,) its truth's id
    track: np.ndarray  # (A,) its track's id


def kept_pairs(distances: np.ndarray, truths: np.ndarray, tracks: np.ndarray, last: dict[int, int], cutoff: float,
               order: float) -> tuple[np.ndarray, np.ndarray]:
    """One scan's kept pairs (see the module docstring), as rows (A,) of `distances` (T, K) m and
    columns (A,), from the scan's truth ids (T,) and track ids (K,) and `last`, each truth's last
    paired track by id, which is updated."""
    column_of = {int(track): column for column, track in enumerate(tracks.tolist())}
    rows, columns = [], []
    for row in np.argsort(truths, kind="stable"):
        column = column_of.get(last.get(int(truths[row]), -1))
        if column is not None and column not in columns and distances[row, column] < cutoff:
            rows.append(int(row))
            columns.append(column)
    free_rows, free_columns = _unused(len(truths), rows), _unused(len(tracks), columns)
    _, paired_rows, paired_columns = gospa_parts(distances[np.ix_(free_rows, free_columns)], cutoff, order)
    rows = np.concatenate([rows, free_rows[paired_rows]]).astype(np.intp)
    columns = np.concatenate([columns, free_columns[paired_columns]]).astype(np.intp)
    last.update(zip(truths[rows].tolist(), tracks[columns].tolist()))
    return rows, columns


def _unused(count: int, used: list[int]) -> np.ndarray:
    """The indices (sorted) below `count` that are not in `used`: `np.setdiff1d(np.arange(count), used)` without
    its sort, which at a scan's handful of truths and tracks cost more than the scan's assignment."""
    free = np.ones(count, dtype=bool)
    free[used] = False
    return np.flatnonzero(free)


def scan_gospa(scans: np.ndarray, truth_scan: np.ndarray, truth_id: np.ndarray, track_scan: np.ndarray,
               track_id: np.ndarray, distances: Callable[[np.ndarray, np.ndarray], np.ndarray], cutoff: float,
               order: float, keep_pairs: bool = False) -> ScanGospa:
    """GOSPA at each of `scans` (S,, sorted): N truth rows (`truth_scan`, `truth_id`) and M track
    estimate rows (`track_scan`, `track_id`), each sorted by scan; `distances(truth_rows, track_rows)`
    gives the distances (T, K) m between the truths and estimates of one scan, by row index. Scans
    with no truth or no track cost c^p/2 per element without solving an assignment. The pairs are
    GOSPA's assignment's, or with `keep_pairs` the kept pairs (module docstring)."""
    truth_begin, truth_end = np.searchsorted(truth_scan, scans, "left"), np.searchsorted(truth_scan, scans, "right")
    track_begin, track_end = np.searchsorted(track_scan, scans, "left"), np.searchsorted(track_scan, scans, "right")
    half = cutoff ** order / 2.0
    parts = np.column_stack([np.zeros(len(scans)), half * (truth_end - truth_begin), half * (track_end - track_begin)])
    pairs = [np.empty((0, 3), dtype=np.int64)]
    last: dict[int, int] = {}
    for k in np.flatnonzero((truth_end > truth_begin) & (track_end > track_begin)):
        truths, tracks = np.arange(truth_begin[k], truth_end[k]), np.arange(track_begin[k], track_end[k])
        matrix = distances(truths, tracks)
        parts[k], rows, columns = gospa_parts(matrix, cutoff, order)
        if keep_pairs:
            rows, columns = kept_pairs(matrix, truth_id[truths], track_id[tracks], last, cutoff, order)
        pairs.append(np.column_stack([np.full(len(rows), scans[k]), truth_id[truths[rows]], track_id[tracks[columns]]]))
    scan, truth, track = np.concatenate(pairs).astype(np.int64).T
    return ScanGospa(parts, scan, truth, track)


def shares_in_metres(parts: np.ndarray, order: float) -> np.ndarray:
    """Each scan's GOSPA (m) split in proportion to its parts (S, 3) m^p: (S, 3) m, summing per scan
    to the scan's GOSPA (0 where it is 0)."""
    total = parts.sum(axis=1, keepdims=True)
    return np.divide(parts * total ** (1.0 / order), total, out=np.zeros_like(parts), where=total > 0)


def track_switches(truth: np.ndarray, scan: np.ndarray, track: np.ndarray, truths: np.ndarray) -> np.ndarray:
    """Switches (len(truths),) of each of `truths` (sorted ids, every truth of the pairs among
    them): how often its assigned track id changes to another, over the assigned pairs (A,)
    `truth`, `scan`, `track` in any order (a scan without a pair is skipped)."""
    in_order = np.lexsort((scan, truth))
    truth, track = truth[in_order], track[in_order]
    changed = (truth[1:] == truth[:-1]) & (track[1:] != track[:-1])
    return np.bincount(np.searchsorted(truths, truth[1:][changed]), minlength=len(truths))


def tracks_per_truth(truth: np.ndarray, track: np.ndarray, truths: np.ndarray) -> np.ndarray:
    """Distinct tracks (len(truths),) ever assigned to each of `truths` (sorted ids, every truth of
    the pairs among them), over the assigned pairs (A,) `truth`, `track`."""
    pairs = np.unique(np.column_stack([truth, track]), axis=0)
    return np.bincount(np.searchsorted(truths, pairs[:, 0]), minlength=len(truths))


def track_purity(truth: np.ndarray, track: np.ndarray) -> np.ndarray:
    """Purity (P,) of each of the P tracks among the assigned pairs (A,) `truth`, `track`, in
    track id order: the share of its assigned scans on its most frequent truth."""
    pairs, counts = np.unique(np.column_stack([track, truth]), axis=0, return_counts=True)
    if not len(pairs):
        return np.empty(0)
    starts = np.flatnonzero(np.r_[True, pairs[1:, 0] != pairs[:-1, 0]])
    return np.maximum.reduceat(counts, starts) / np.add.reduceat(counts, starts)

"""OSPA: the optimal sub-pattern assignment distance between estimated and true target sets
(Schuhmacher, Vo and Vo, 2008), per scan and averaged.

d_c(x, y) = min(c, |x - y|); for m estimates and n truths (m <= n after swapping),
OSPA = ( (min over assignments of sum d_c^p + c^p (n - m)) / n )^(1/p), 0 when both sets are
empty. So a missed or a false track costs the cutoff c, and a matched one its distance.
Written here (a dozen lines over scipy's assignment solver) because Stone Soup's metric needs
its own state and track types around every number.

Scans of a tracker run: the truth set of scan k holds the target when the simulator had it in
radar coverage at that scan; the estimate set holds each confirmed track updated during the
scan, at its last update in it, and is compared with the true position at that update's time.
A missed detection therefore costs c for every tracker alike (the raw-plot reference shows
that floor); tracks are not coasted, so no tracker is judged on extrapolation it never made.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from pipeline.tracker.management import TrackManagement
from pipeline.tracker.updates import confirmed_associations, positions


def ospa(distances: np.ndarray, cutoff: float, order: float) -> float:
    """OSPA from the matrix of distances between m estimates (rows) and n truths (columns)."""
    m, n = distances.shape
    if m == 0 and n == 0:
        return 0.0
    if m == 0 or n == 0:
        return float(cutoff)
    cut = np.minimum(distances, cutoff) ** order
    rows, columns = linear_sum_assignment(cut)
    total = cut[rows, columns].sum() + cutoff ** order * abs(m - n)
    return float((total / max(m, n)) ** (1.0 / order))


@dataclass(frozen=True)
class ScanEstimates:
    """The estimate sets of a tracker run's scans: each confirmed track updated during a scan, at its
    last update in it; E estimates, sorted by scan, then track."""

    scan: np.ndarray      # (E,) int64, the scan
    track: np.ndarray     # (E,) int64, the track's id
    time: np.ndarray      # (E,) s, the update's time
    position: np.ndarray  # (E, 3) m ECEF, the track's position after the update


def scan_estimates(updates: dict[str, np.ndarray], update_scans: np.ndarray, management: TrackManagement
                   ) -> ScanEstimates:
    """The estimate set of every scan from an update table (`pipeline.tracker.updates`), confirmed by
    `management`'s rule; `update_scans` is the scan of each update's plot."""
    return marked_estimates(updates, update_scans, confirmed_associations(updates, management))


def marked_estimates(updates: dict[str, np.ndarray], update_scans: np.ndarray, confirmed: np.ndarray) -> ScanEstimates:
    """The estimate set of every scan from the updates (U rows of track id, time, ECEF position) marked
    `confirmed` (U,) bool: each confirmed track's last update in each scan, `update_scans` (U,) the scans."""
    times = updates["time_unix_s"][confirmed]
    scans = update_scans[confirmed]
    tracks = updates["track_id"][confirmed]
    order_in_time = np.lexsort((times, tracks, scans))
    scans, tracks, times = scans[order_in_time], tracks[order_in_time], times[order_in_time]
    estimates = positions(updates)[confirmed][order_in_time]
    last = np.ones(len(scans), dtype=bool)  # each track's last update in each scan
    last[:-1] = (scans[1:] != scans[:-1]) | (tracks[1:] != tracks[:-1])
    return ScanEstimates(scans[last], tracks[last], times[last], estimates[last])


def scan_ospa(updates: dict[str, np.ndarray], update_scans: np.ndarray, management: TrackManagement,
              scans_in_coverage: np.ndarray, all_scans: np.ndarray, truth_at: callable, cutoff: float,
              order: float) -> np.ndarray:
    """OSPA of one single-target scenario at each of `all_scans` (sorted).

    `updates` is an update table (`pipeline.tracker.updates`), confirmed by `management`'s rule;
    `update_scans` is the scan of each update's plot; `scans_in_coverage` the scans in which
    the target exists for the radar; `truth_at(times)` the target's true ECEF positions."""
    estimates = scan_estimates(updates, update_scans, management)
    scans = estimates.scan
    errors = (np.linalg.norm(estimates.position - truth_at(estimates.time), axis=1) if len(scans)
              else np.empty(0))
    present = np.isin(all_scans, scans_in_coverage)
    result = np.empty(len(all_scans))
    starts = np.searchsorted(scans, all_scans, side="left")
    ends = np.searchsorted(scans, all_scans, side="right")
    for k, (begin, end) in enumerate(zip(starts, ends)):
        distances = errors[begin:end, None] if present[k] else np.empty((end - begin, 0))
        result[k] = ospa(distances, cutoff, order)
    return result

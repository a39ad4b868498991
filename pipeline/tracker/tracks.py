"""Tracks and their management: weights, confirmation, deletion (thesis 4.4).

Weights: a new track starts at `weight_start` (0.4), is a candidate at `weight_candidate`
(0.8) and confirmed at `weight_confirmed` (1.0). Each association adds `weight_step`
(0.2, capped at the confirmed weight). A track with no association and no weight change for
`silence_s` (12 s) loses `weight_step`; a track lowered while at the candidate weight is
deleted. The thesis does not say what happens to a track lowered at or below the start
weight: here it is deleted too, so clutter tracks die after one silence period.

The live tracks are kept as NumPy arrays (last position, weight, plot count) so management and the pre-filter are vector operations over all tracks; each
track's history is a short Python list, touched only when the track is a candidate.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np

from pipeline.params import TrackerParams

EPSILON = 1e-9


@dataclass
class Track:
    """History of one track: states and plots as [t, x, y, z, r] rows (ECEF metres, seconds).
    `estimate` is whatever a classical estimator keeps per track (its filter, `kalman.TrackFilter`)."""

    track_id: int
    states: list[np.ndarray] = field(default_factory=list)
    plots: list[np.ndarray] = field(default_factory=list)
    plot_ids: list[int] = field(default_factory=list)
    estimate: object = None


class LiveTracks:
    """The tracks alive now, in fixed slots with array views for vectorised management and gating.

    Most plots are clutter that starts a track which dies one silence period later, so slots
    are reused rather than arrays grown and shrunk, and the times at which tracks fall due
    for lowering sit in a heap: management costs nothing until a track is due. A heap entry
    carries the slot's generation, which changes whenever the slot's weight changes or the
    slot is reused, so stale entries are skipped. A free slot's position is infinite, so it
    is never within the pre-filter distance.
    """

    def __init__(self, capacity: int = 64) -> None:
        self.tracks: list[Track | None] = [None] * capacity
        self.last_state = np.full((capacity, 3), np.inf)
        self.last_plot = np.full((capacity, 3), np.inf)
        self.weight = np.zeros(capacity)
        self.plot_count = np.zeros(capacity, dtype=np.int64)
        self.alive = np.zeros(capacity, dtype=bool)
        self._generation = [0] * capacity
        self._due: list[tuple[float, int, int]] = []  # (time the slot falls due, slot, generation)
        self._free = list(range(capacity - 1, -1, -1))
        self._next_id = 0

    def __len__(self) -> int:
        return len(self.tracks) - len(self._free)

    def _grow(self) -> None:
        capacity = len(self.tracks)
        self.tracks.extend([None] * capacity)
        self.last_state = np.vstack([self.last_state, np.full((capacity, 3), np.inf)])
        self.last_plot = np.vstack([self.last_plot, np.full((capacity, 3), np.inf)])
        self.weight = np.concatenate([self.weight, np.zeros(capacity)])
        self.plot_count = np.concatenate([self.plot_count, np.zeros(capacity, dtype=np.int64)])
        self.alive = np.concatenate([self.alive, np.zeros(capacity, dtype=bool)])
        self._generation.extend([0] * capacity)
        self._free = list(range(2 * capacity - 1, capacity - 1, -1))

    def start(self, plot: np.ndarray, plot_id: int, weight: float, silence_s: float) -> int:
        """A new track from one plot; its state is the plot. Returns its slot."""
        if not self._free:
            self._grow()
        slot = self._free.pop()
        self.tracks[slot] = Track(self._next_id, [plot.copy()], [plot.copy()], [plot_id])
        self._next_id += 1
        self.last_state[slot] = plot[1:4]
        self.last_plot[slot] = plot[1:4]
        self.weight[slot] = weight
        self.plot_count[slot] = 1
        self.alive[slot] = True
        self._schedule(slot, plot[0] + silence_s)
        return slot

    def _schedule(self, slot: int, due: float) -> None:
        self._generation[slot] += 1
        heapq.heappush(self._due, (due, slot, self._generation[slot]))

    def associate(self, slot: int, plot: np.ndarray, plot_id: int, state: np.ndarray, params: TrackerParams) -> None:
        """Add a plot and the updated state to a track, raising its weight."""
        track = self.tracks[slot]
        track.plots.append(plot.copy())
        track.plot_ids.append(plot_id)
        track.states.append(state)
        self.last_state[slot] = state[1:4]
        self.last_plot[slot] = plot[1:4]
        self.weight[slot] = min(self.weight[slot] + params.weight_step, params.weight_confirmed)
        self.plot_count[slot] += 1
        self._schedule(slot, plot[0] + params.silence_s)

    def manage(self, now: float, params: TrackerParams) -> list[Track]:
        """Lower the weight of silent tracks and delete those lowered at or below the candidate
        weight (see the module docstring). Returns the deleted tracks."""
        removed = []
        while self._due and self._due[0][0] <= now:
            due, slot, generation = heapq.heappop(self._due)
            if generation != self._generation[slot]:
                continue
            lowered_from = self.weight[slot]
            if abs(lowered_from - params.weight_candidate) < EPSILON or lowered_from <= params.weight_start + EPSILON:
                removed.append(self._remove(slot))
                continue
            self.weight[slot] = lowered_from - params.weight_step
            self._schedule(slot, due + params.silence_s)
        return removed

    def _remove(self, slot: int) -> Track:
        track = self.tracks[slot]
        self.tracks[slot] = None
        self._free.append(slot)
        self._generation[slot] += 1
        self.alive[slot] = False
        self.last_state[slot] = np.inf
        self.last_plot[slot] = np.inf
        return track


def status(weight: float, params: TrackerParams) -> str:
    if weight >= params.weight_confirmed - EPSILON:
        return "confirmed"
    if weight >= params.weight_candidate - EPSILON:
        return "candidate"
    return "tentative"

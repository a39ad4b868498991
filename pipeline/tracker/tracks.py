"""Tracks and their management: weights, confirmation, deletion (thesis 4.4).

Weights: a new track starts at `weight_start` (0.4), is a candidate at `weight_candidate`
(0.8) and confirmed at `weight_confirmed` (1.0). Each association adds `weight_step`
(0.2, capped at the confirmed weight). A track with no association and no weight change for
`silence_s` (12 s) loses `weight_step`; a track lowered while at the candidate weight is
deleted. The thesis does not say what happens to a track lowered at or below the start
weight: here it is deleted too, so clutter tracks die after one silence period.

The live tracks are kept as NumPy arrays (last position, weight, time of the last weight
change) so management and the pre-filter are vector operations over all tracks; each
track's history is a short Python list, touched only when the track is a candidate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.params import TrackerParams

EPSILON = 1e-9


@dataclass
class Track:
    """History of one track: states and plots as [t, x, y, z, r] rows (ECEF metres, seconds)."""

    track_id: int
    states: list[np.ndarray] = field(default_factory=list)
    plots: list[np.ndarray] = field(default_factory=list)
    plot_ids: list[int] = field(default_factory=list)


class LiveTracks:
    """The tracks alive now, in fixed slots with array views for vectorised management and gating.

    Most plots are clutter that starts a track which dies one silence period later, so slots
    are reused rather than arrays grown and shrunk, and management is skipped until the
    earliest time any track can be lowered (`next_due`). A free slot's position is
    infinite, so it is never within the pre-filter distance.
    """

    def __init__(self, capacity: int = 64) -> None:
        self.tracks: list[Track | None] = [None] * capacity
        self.last_state = np.full((capacity, 3), np.inf)
        self.last_plot = np.full((capacity, 3), np.inf)
        self.weight = np.zeros(capacity)
        self.last_change = np.full(capacity, np.inf)
        self.plot_count = np.zeros(capacity, dtype=np.int64)
        self.alive = np.zeros(capacity, dtype=bool)
        self._free = list(range(capacity - 1, -1, -1))
        self._next_id = 0
        self.next_due = np.inf

    def __len__(self) -> int:
        return len(self.tracks) - len(self._free)

    def _grow(self) -> None:
        capacity = len(self.tracks)
        self.tracks.extend([None] * capacity)
        self.last_state = np.vstack([self.last_state, np.full((capacity, 3), np.inf)])
        self.last_plot = np.vstack([self.last_plot, np.full((capacity, 3), np.inf)])
        self.weight = np.concatenate([self.weight, np.zeros(capacity)])
        self.last_change = np.concatenate([self.last_change, np.full(capacity, np.inf)])
        self.plot_count = np.concatenate([self.plot_count, np.zeros(capacity, dtype=np.int64)])
        self.alive = np.concatenate([self.alive, np.zeros(capacity, dtype=bool)])
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
        self.last_change[slot] = plot[0]
        self.plot_count[slot] = 1
        self.alive[slot] = True
        self.next_due = min(self.next_due, plot[0] + silence_s)
        return slot

    def associate(self, slot: int, plot: np.ndarray, plot_id: int, state: np.ndarray, params: TrackerParams) -> None:
        """Add a plot and the updated state to a track, raising its weight."""
        track = self.tracks[slot]
        track.plots.append(plot.copy())
        track.plot_ids.append(plot_id)
        track.states.append(state)
        self.last_state[slot] = state[1:4]
        self.last_plot[slot] = plot[1:4]
        self.weight[slot] = min(self.weight[slot] + params.weight_step, params.weight_confirmed)
        self.last_change[slot] = plot[0]
        self.plot_count[slot] += 1

    def manage(self, now: float, params: TrackerParams) -> list[Track]:
        """Lower the weight of silent tracks and delete those lowered at or below the candidate
        weight (see the module docstring). Returns the deleted tracks."""
        if now < self.next_due:
            return []
        due = self.alive & (now - self.last_change >= params.silence_s)
        delete = np.zeros(len(self.tracks), dtype=bool)
        while due.any():
            lowered_from = self.weight[due]
            dies = (np.abs(lowered_from - params.weight_candidate) < EPSILON) | (
                lowered_from <= params.weight_start + EPSILON)
            delete[np.flatnonzero(due)[dies]] = True
            self.weight[due] -= params.weight_step
            self.last_change[due] += params.silence_s
            due = self.alive & ~delete & (now - self.last_change >= params.silence_s)
        removed = self._remove(delete) if delete.any() else []
        self.next_due = float(self.last_change[self.alive].min()) + params.silence_s if self.alive.any() else np.inf
        return removed

    def _remove(self, mask: np.ndarray) -> list[Track]:
        slots = np.flatnonzero(mask)
        removed = [self.tracks[slot] for slot in slots]
        for slot in slots:
            self.tracks[slot] = None
        self._free.extend(slots.tolist())
        self.alive[slots] = False
        self.last_state[slots] = np.inf
        self.last_plot[slots] = np.inf
        self.last_change[slots] = np.inf
        return removed


def status(weight: float, params: TrackerParams) -> str:
    if weight >= params.weight_confirmed - EPSILON:
        return "confirmed"
    if weight >= params.weight_candidate - EPSILON:
        return "candidate"
    return "tentative"

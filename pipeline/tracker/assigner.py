"""Role: the assigner (Stone Soup's data associator): which plot joins which candidate track.

The loop cuts the plots into batches that are associated together (`batches`), scores each
plot's candidate tracks (pre-filter and gates: `Candidates`) against the tracks alive at the
batch's first plot, and asks the assigner for a choice per plot (`assign`): the position of
the chosen candidate in the plot's `Candidates`, or None when the plot starts a track. Plots
are then updated in time order; a plot whose chosen track was deleted (by management, before
the plot's time) in the meantime starts a track too. Of a track's plots an assigner may read its
first (`rows[0]`), which every track keeps (`pipeline.tracker.tracks`).

- `NearestPerPlot`: each plot alone; the candidate with the lowest normalised error wins.
- `GlobalNearestPerScan`: each antenna scan of each radar at once (the rotation periods counted
  from the radar's first plot, within which each target is seen once); the assignment of plots
  to tracks with the least summed normalised error (global nearest neighbour, scipy's
  `linear_sum_assignment`), each track taking at most one plot. A run of plots from one radar
  within one of its scans is one batch, so with several radars interleaved the batches are the
  runs between radar changes.
- `TrueAssociation` (the oracle): each plot joins the candidate track started by a plot of the
  same target (the plot table's `target_id`); a false plot joins none. The errors play no part.
- `JointProbabilisticPerScan` (`pipeline.tracker.jpda`): global nearest neighbour's batches and
  choices, and besides them the joint association probabilities of each scan's mature tracks and
  the plots in their gates (`hypotheses`), with which the loop updates those tracks (a soft
  assigner).

`hypotheses(tracks, rows, candidates, choices)` gives a soft assigner's `Hypotheses` for a batch,
after its choices; the hard assigners give None, and their tracks take the one plot chosen.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np
from scipy.optimize import linear_sum_assignment

from pipeline import io
from pipeline.recordings.plot_table import NO_TARGET, Plots
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.tracks import LiveTracks

UNASSIGNABLE = 1e9  # stands for an infinite cost in the assignment; such pairs are dropped after it


class Candidates(NamedTuple):
    """The K tracks one plot may join: their slots (K,) in increasing order, normalised errors
    (K,) (inf outside the gate), whether each was scored by the method's gate rather than the
    young-track radius (K,), and the method's gate's prediction of those (None if it made none),
    in their order from row `first` of it (a prediction made for the whole batch of plots holds
    the other plots' candidates too)."""

    slots: np.ndarray
    errors: np.ndarray
    mature: np.ndarray
    prediction: Prediction | None
    first: int


class Hypotheses(NamedTuple):
    """The association hypotheses of a batch's T mature tracks that have a plot in their gate, and
    their probabilities (joint probabilistic data association): the tracks' slots (T,); each
    track's probability that none of the batch's plots is its own (T,), `missed`; and the H
    (track, plot) hypotheses, each with its track's place in `slots` (H,), its plot row (H,) and
    its probability (H,), `weights` (a track's `missed` and weights sum to 1). Each track is
    updated at the time of its `reference` plot (T,), from row `reference_index` (T,) of
    `prediction`, the batch's prediction: the plot its track was chosen for, else its most probable
    one."""

    slots: np.ndarray
    missed: np.ndarray
    track: np.ndarray
    rows: np.ndarray
    weights: np.ndarray
    reference: np.ndarray
    reference_index: np.ndarray
    prediction: Prediction


class Assigner(Protocol):
    def batches(self, plots: Plots) -> np.ndarray:
        """Boundaries (B + 1,) of the B runs of plot rows that are associated together."""

    def assign(self, tracks: LiveTracks, rows: range, candidates: list[Candidates]) -> list[int | None]:
        """For each plot of `rows` (with its `candidates`), the chosen candidate or None."""

    def hypotheses(self, tracks: LiveTracks, rows: range, candidates: list[Candidates],
                   choices: list[int | None]) -> Hypotheses | None:
        """A soft assigner's hypotheses for the batch after its `choices`; None for a hard assigner."""


def _nearest(candidates: Candidates) -> int | None:
    if not len(candidates.slots):
        return None
    best = int(np.argmin(candidates.errors))
    return best if np.isfinite(candidates.errors[best]) else None


def _hard(self, tracks: LiveTracks, rows: range, candidates: list[Candidates],
          choices: list[int | None]) -> None:
    """A hard assigner's `hypotheses`: none, each chosen track takes its plot."""
    return None


class NearestPerPlot:
    """Each plot alone, lowest normalised error wins (the thesis's rule)."""

    def batches(self, plots: Plots) -> np.ndarray:
        return np.arange(len(plots) + 1)

    def assign(self, tracks: LiveTracks, rows: range, candidates: list[Candidates]) -> list[int | None]:
        return [_nearest(c) for c in candidates]

    hypotheses = _hard


class GlobalNearestPerScan:
    """Global nearest neighbour over each antenna scan of each radar. One per run: it remembers
    each radar's first plot time, so that the scans of a recording read a part at a time are
    counted from the same origin in every part."""

    def __init__(self) -> None:
        self._first: dict[int, float] = {}

    def batches(self, plots: Plots) -> np.ndarray:
        if not len(plots):
            return np.zeros(1, dtype=np.int64)
        for radar_id in np.unique(plots.radar_id).tolist():
            self._first.setdefault(radar_id, float(plots.time[np.argmax(plots.radar_id == radar_id)]))
        origin = np.array([self._first[r] for r in plots.radar_id.tolist()])
        period = np.array([plots.radars[r].scan_period_s for r in plots.radar_id.tolist()])
        scans = np.floor((plots.time - origin) / period).astype(np.int64)
        change = (np.diff(scans) != 0) | (np.diff(plots.radar_id) != 0)
        return np.concatenate([[0], np.flatnonzero(change) + 1, [len(plots)]])

    def assign(self, tracks: LiveTracks, rows: range, candidates: list[Candidates]) -> list[int | None]:
        choices: list[int | None] = [None] * len(candidates)
        paired = np.concatenate([c.slots for c in candidates])  # every (plot, track) pair's track, plot by plot
        slots = np.unique(paired)
        if not len(slots):
            return choices
        counts = [len(c.slots) for c in candidates]
        plots, columns = np.repeat(np.arange(len(candidates)), counts), np.searchsorted(slots, paired)
        errors = np.concatenate([c.errors for c in candidates])
        gated = np.isfinite(errors)
        # The cost matrix (plots x tracks) is filled from the pairs alone: at a thousand aircraft it has
        # millions of cells, and every pass over it costs more than the pairs.
        cost = np.full((len(candidates), len(slots)), UNASSIGNABLE)
        cost[plots[gated], columns[gated]] = errors[gated]
        chosen_plots, chosen_columns = linear_sum_assignment(cost)
        kept = cost[chosen_plots, chosen_columns] < UNASSIGNABLE  # a gated pair's error is at most 1
        chosen_plots, chosen_columns = chosen_plots[kept], chosen_columns[kept]
        # A pair's place in the list of pairs (plot by plot, tracks in order: its key plot * tracks + column
        # increases along it), less its plot's first, is the track's place among the plot's candidates.
        keys = plots * len(slots) + columns
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        at = np.searchsorted(keys, chosen_plots * len(slots) + chosen_columns) - first[chosen_plots]
        for plot, place in zip(chosen_plots.tolist(), at.tolist()):
            choices[plot] = place
        return choices

    hypotheses = _hard


class TrueAssociation:
    """The oracle: each plot joins the candidate track of its own target."""

    def batches(self, plots: Plots) -> np.ndarray:
        if not plots.has_truth:
            raise io.InputError("true association needs each plot's target_id, which these plots lack")
        return np.arange(len(plots) + 1)

    def assign(self, tracks: LiveTracks, rows: range, candidates: list[Candidates]) -> list[int | None]:
        target = tracks.plots.target_id
        choices = []
        for row, c in zip(rows, candidates):
            own = [n for n, slot in enumerate(c.slots.tolist()) if target[tracks.tracks[slot].rows[0]] == target[row]]
            choices.append(own[0] if own and target[row] != NO_TARGET else None)
        return choices

    hypotheses = _hard

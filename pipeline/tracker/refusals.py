"""Plots a learned gate refused that the window would have taken (issue 27), counted over a run.

A learned gate (the LSTM update's MC-dropout chi-square gate, the network-scaled filter's
`PlotScaledGate`, MIA's Monte-Carlo window, the autoencoder's threshold) sizes itself from a
network's output; on input unlike the network's training (a target faster than any it saw) it
may refuse the very plots of the track it follows, and then every plot starts a track of its own:
nothing is confirmed and nothing fails. The plain window (`RadiusGate(window_m)`, the young-track
radius every method uses) is the yardstick: a plot is

- *in the window* when some candidate track that a learned gate scores (by the composition's
  `RefusalWatch`: its young tracks, its mature ones or both) had its last plot within `window_m`
  of it, and
- *refused* when, besides, no gate of any candidate accepted it (every error infinite), so that
  it starts a track.

A healthy learned gate refuses only the clutter that falls near a track and the odd target plot;
a gate that cannot follow its target refuses almost every plot in the window (case 29's 600 m/s
target: all of them). Measured on the tiny pipeline's test split (8 routes, its barely trained
models, window 4 km): kalman_net 2.6 %, ae 2.9 %, lstm_update 18.6 %, mia 48.5 % (those two
split the routes into 41 and 59 confirmed tracks, kalman_net 15). The loop counts (`RefusalWatch.count`);
`warn_refusals` turns the run's counts into the `pipeline` logger's warning, naming the method,
when the refused share reaches `tracker.refusal_warning_share`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from pipeline.tracker.assigner import Candidates
from pipeline.tracker.tracks import LiveTracks

log = logging.getLogger("pipeline")


@dataclass
class RefusalCounts:
    """Plots in the window of a learned-gated track, and those of them that every gate refused."""

    in_window: int = 0
    refused: int = 0

    def add(self, other: "RefusalCounts") -> None:
        self.in_window += other.in_window
        self.refused += other.refused

    @property
    def share(self) -> float:
        """refused / in_window (0 with none in the window)."""
        return self.refused / self.in_window if self.in_window else 0.0


class RefusalWatch:
    """One run's counts for a composition whose `young` and/or `mature` gate is learned, against the
    window `window_m` (m) around each candidate track's last plot (module docstring)."""

    def __init__(self, window_m: float, young: bool, mature: bool) -> None:
        self.window_m, self.young, self.mature = window_m, young, mature
        self.counts = RefusalCounts()

    def count(self, live: LiveTracks, rows: range, candidates: list[Candidates]) -> None:
        """Count the plots of `rows` of `live.plots`, each with its scored `candidates` (the tracks as they
        were scored), in one pass over their (track, plot) pairs: a scan's plots cost one set of NumPy calls."""
        counts = [len(c.slots) for c in candidates]
        if not any(counts):
            return
        slots = np.concatenate([c.slots for c in candidates])
        mature = np.concatenate([c.mature for c in candidates])
        accepted = np.isfinite(np.concatenate([c.errors for c in candidates]))
        plot = np.repeat(np.arange(len(candidates)), counts)
        learned = np.where(mature, self.mature, self.young)
        near = np.linalg.norm(live.last_plot[slots] - live.plots.position[np.asarray(rows)[plot]], axis=1) < self.window_m
        in_window = np.bincount(plot[learned & near], minlength=len(candidates)) > 0
        refused = in_window & (np.bincount(plot[accepted], minlength=len(candidates)) == 0)
        self.counts.in_window += int(np.count_nonzero(in_window))
        self.counts.refused += int(np.count_nonzero(refused))


YOUNG_FALLBACK_METHODS = ("lstm_update", "lstm_update_gnn")  # whose young-track gate `young_window_fallback` widens


def remedy(method: str, young_fallback: bool) -> str:
    """What a user can do about a learned gate that keeps refusing plots: widen the LSTM update's young-track
    gate where that is still off, else track such targets with a method whose gate is not learned."""
    if method in YOUNG_FALLBACK_METHODS and not young_fallback:
        return "tracker.lstm_update.young_window_fallback widens its young tracks' gate to the window"
    told = " even with tracker.lstm_update.young_window_fallback on" if method in YOUNG_FALLBACK_METHODS else ""
    return f"its gate cannot follow such targets{told}: a classical method (imm, imm_gnn) or kalman_net tracks them"


def warn_refusals(method: str, window_m: float, counts: RefusalCounts, share: float,
                  young_fallback: bool = False) -> None:
    """Warn (logger `pipeline`) when `method`'s learned gate refused at least `share` of the plots in
    the window (`window_m`, m) of a track it scored, with the `remedy` that applies (`young_fallback`:
    params' tracker.lstm_update.young_window_fallback)."""
    if counts.refused and counts.share >= share:
        log.warning("track: method %s: its learned gate refused %d of the %d plots (%.1f %%) that lay within "
                    "window_m = %g m of a track it scored, and each started a track of its own: plots unlike "
                    "its training (a target faster than any it saw?); %s", method, counts.refused,
                    counts.in_window, 100.0 * counts.share, window_m, remedy(method, young_fallback))

"""Role: the state estimator (Stone Soup's predictor and updater in one).

An estimator keeps what it needs per live track, by slot of `LiveTracks`, and offers three
calls. Units: seconds (Unix), ECEF metres, m^2 for covariances. It declares in `latest_plots` how
many of a track's latest plots it reads (`tracks.tracks[slot].rows[-n:]`, n at most that; 0 for
one that keeps its own state): a track keeps only those and its first plot (`rows[0]`), so
memory does not grow with a track's age (`pipeline.tracker.tracks`). A track's plot count is
`tracks.plot_count[slot]`, not the length of its rows.

- `start(tracks, slot)`: a track has just started at its first plot (`tracks.tracks[slot].rows[0]`).
- `predict(tracks, slots, time)`: where the tracks at `slots` (K,) are expected at `time`, all
  in one batch, as a `Prediction`. The tracks are left unchanged. The loop calls it once per
  plot for the candidate tracks the gate scores, and hands the same prediction to the gate and
  to the update. An estimator with `pairwise` set also takes `time` as an array (K,), a time
  per track (its plot's): the loop then predicts the (track, plot) pairs of a whole antenna
  scan at once.
- `update(tracks, slot, row, prediction, index)`: the track at `slot` takes plot `row` of
  `tracks.plots`; `prediction` is the one made for it at the plot's time (row `index` of it) or
  None when none was made (the young-track radius gate predicts nothing), then the estimator
  predicts itself if it needs to. Returns the track's new position (3,) and, if the estimator
  gives one (`gives_covariance`), its covariance (3, 3), else None. The plot is not yet in the
  track's rows.
- `velocities(tracks, slots)` (estimators with `gives_velocity` only): the velocities (K, 3) m/s, ECEF, of
  the tracks at `slots` (K,) after their latest update, and their covariances (K, 3, 3) m^2/s^2 or
  None. The loop asks it after an update when the run records velocities (`track` does; the bench's
  metrics need none).
- `update_pairs(tracks, slots, rows, prediction, indices)` (`pairwise` estimators only): the
  updates of several different tracks (P,), each with its plot, from rows `indices` of one
  prediction, in one call: positions (P, 3) and covariances (P, 3, 3) or None. The loop makes a
  scan's updates so; a track updated by it and then deleted may see its slot `start`ed again. With
  `prediction` None (a scan's young tracks, which the young-track gate predicts nothing for) the
  estimator predicts the pairs itself, each at its plot, as `update` does without one, and ignores
  `indices`.

- `update_mixtures(tracks, hypotheses)` (estimators composed with a soft assigner, `pipeline.tracker.jpda`):
  the T tracks of a batch's `Hypotheses` (`pipeline.tracker.assigner`) each updated with all its plots,
  weighted by their probabilities, in one call: positions (T, 3) and covariances (T, 3, 3).

A new estimator is one module with a class offering these, and one registry entry
(`pipeline.tracker.registry`); docs/architecture.md has the worked example.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

import numpy as np

from pipeline.tracker.tracks import LiveTracks


class Prediction(NamedTuple):
    """K tracks at one time: `positions` (K, 3) ECEF m, their covariances (K, 3, 3) m^2 or None
    when the estimator gives none, and `state`, the estimator's own predicted state, whatever it
    is, indexable by track (row k is track k's): its update resumes from it.
    `innovation_inverse` (K, 3, 3) 1/m^2: the inverse of each row's innovation covariance (its
    covariance plus its plot's measurement covariance) when a gate computed it (the chi-square
    gate), else None; an update of that row with that plot may start from it rather than invert
    again."""

    positions: np.ndarray
    covariances: np.ndarray | None
    state: Any = None
    innovation_inverse: np.ndarray | None = None


class Estimator(Protocol):
    gives_covariance: bool
    gives_velocity: bool
    pairwise: bool
    latest_plots: int

    def start(self, tracks: LiveTracks, slot: int) -> None: ...

    def predict(self, tracks: LiveTracks, slots: np.ndarray, time: float | np.ndarray) -> Prediction: ...

    def update(self, tracks: LiveTracks, slot: int, row: int, prediction: Prediction | None, index: int
               ) -> tuple[np.ndarray, np.ndarray | None]: ...

    def update_pairs(self, tracks: LiveTracks, slots: np.ndarray, rows: np.ndarray, prediction: Prediction | None,
                     indices: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]: ...

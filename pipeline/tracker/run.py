"""The tracking loop (thesis 4.4-4.6): one loop for every method, its parts given as roles.

A tracker is a `Composition` of roles (`pipeline.tracker.estimator`, `.gate`, `.assigner`,
`.management`); `pipeline.tracker.registry` composes one per method name. The loop takes the
plots in time order, in the assigner's batches (one plot, or one antenna scan). For a batch:
track management first (silent tracks lose weight, some are deleted); then each plot's
candidates, the tracks within the pre-filter distance of the plot, scored by the young-track
gate (tracks with fewer than `mature_from` plots) or the method's gate, which gets the
estimator's prediction of its candidates at the plot's time, made once here; then the
assigner's choice. Plot by plot in time order, management again, then the chosen track's
update (from the same prediction) or, for a plot without one, a new track.

The loop knows no method: no name, no type test. It works in ECEF; each plot brings its
radar's measurement covariance in the plot table, so plots of several radars mix. A long
recording can be given a part at a time (`track_chunks`), with the same updates as whole.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from pipeline import plot_table
from pipeline.plot_table import Plots
from pipeline.tracker.assigner import Assigner, Candidates
from pipeline.tracker.estimator import Estimator, Prediction
from pipeline.tracker.gate import Gate
from pipeline.tracker.management import TrackManagement
from pipeline.tracker.tracks import LiveTracks
from pipeline.tracker.updates import START, Updates

NO_CANDIDATES = Candidates(np.empty(0, dtype=np.int64), np.empty(0), np.empty(0, dtype=bool), None)


@dataclass(frozen=True)
class Composition:
    """A tracker's parts. `gate` scores tracks with at least `mature_from` plots, `young_gate` the
    others; candidates lie within `prefilter_m` metres of the plot (by their last position).
    `label` and `young_label` name, in the updates' `association` column, which gate won.
    `mature_first`: a plot inside a mature track's gate is not offered to young tracks (see
    `_candidates`)."""

    label: str
    estimator: Estimator
    gate: Gate
    young_gate: Gate
    young_label: str
    mature_from: int
    prefilter_m: float
    assigner: Assigner
    management: TrackManagement
    mature_first: bool


def track(plots: Plots, tracker: Composition) -> dict[str, np.ndarray]:
    """Track `plots` (time order, one scenario) with `tracker`: one row per track update, a track's
    start counting as its first (`pipeline.tracker.updates`)."""
    tables = list(track_chunks([plots], tracker))
    return tables[0] if len(tables) == 1 else {key: np.concatenate([t[key] for t in tables]) for key in tables[0]}


def track_chunks(chunks: Iterable[Plots], tracker: Composition) -> Iterator[dict[str, np.ndarray]]:
    """Track plots given as consecutive chunks of one scenario in time order (as a recording is read
    a part at a time), with `tracker`: the update table of each chunk in turn, as `track` would give
    for all the chunks joined, row for row. Memory follows the chunk and the live tracks, not the
    recording: a chunk's plot table is the plots of the live tracks (renumbered,
    `LiveTracks.carry`) followed by the chunk's, and the assigner's last batch of a chunk, which
    the chunk's end may cut, waits for the next chunk (its updates come in the next table)."""
    chunks = iter(chunks)
    chunk, live, waiting = next(chunks, None), None, None
    while chunk is not None:
        following = next(chunks, None)
        todo = chunk if waiting is None else plot_table.joined([waiting, chunk])
        if live is None:
            live, first = LiveTracks(todo, tracker.management, cell_m=tracker.prefilter_m), 0
        else:
            first = live.carry(todo)
        bounds = tracker.assigner.batches(todo)
        last = len(bounds) - 1 if following is None else max(len(bounds) - 2, 0)
        updates = Updates(tracker.estimator.gives_covariance)
        for begin, end in zip(bounds[:last].tolist(), bounds[1:last + 1].tolist()):
            _track_batch(live, range(first + begin, first + end), tracker, updates)
        waiting = None if following is None else todo.take(np.arange(bounds[last], len(todo)))
        yield updates.table(live.plots)
        chunk = following


def _track_batch(live: LiveTracks, rows: range, tracker: Composition, updates: Updates) -> None:
    """One batch of plots: candidates, the assigner's choices, then plot by plot in time order
    management and the chosen track's update or a new track (module docstring)."""
    estimator, plots = tracker.estimator, live.plots
    live.manage(plots.time[rows.start])
    candidates = [_candidates(live, row, tracker) for row in rows]
    choices = tracker.assigner.assign(live, rows, candidates)
    chosen = [None if choice is None else (int(c.slots[choice]), live.tracks[c.slots[choice]].track_id, choice)
              for c, choice in zip(candidates, choices)]
    for row, c, choice in zip(rows, candidates, chosen):
        live.manage(plots.time[row])
        if choice is None or not live.holds(*choice[:2]):
            slot = live.start(row)
            estimator.start(live, slot)
            updates.add(live.tracks[slot].track_id, row, plots.position[row], live.weight[slot], START, np.nan,
                        plots.covariance[row])
            continue
        slot, track_id, at = choice
        mature = bool(c.mature[at])
        prediction, index = (c.prediction, int(c.mature[:at].sum())) if mature else (None, 0)
        position, covariance = estimator.update(live, slot, row, prediction, index)
        live.associate(slot, row, position)
        updates.add(track_id, row, position, live.weight[slot], tracker.label if mature else tracker.young_label,
                    float(c.errors[at]), covariance)


def _scores(gate: Gate, live: LiveTracks, slots: np.ndarray, row: int, estimator: Estimator
            ) -> tuple[np.ndarray, Prediction | None]:
    """A gate's errors for the tracks at `slots`, and the prediction the update resumes from; the
    estimator predicts here, once, if the gate uses a prediction."""
    shared = estimator.predict(live, slots, live.plots.time[row]) if gate.uses_prediction else None
    scores = gate(live, slots, row, shared)
    return scores.errors, scores.prediction


def _candidates(live: LiveTracks, row: int, tracker: Composition) -> Candidates:
    """The tracks within the pre-filter distance of plot `row`, scored.

    With `mature_first`, young tracks are out of the running (error inf) for a plot that some
    mature track's gate accepts: the track-file priority of Blackman & Popoli (1999),
    established tracks before tentative ones. Without it one plot outside an established track's
    gate (a manoeuvre, a plot with a large error) starts a track that is nearer to the next plot
    by the young-track radius's measure, takes it, and the established track starves: one aircraft
    becomes two tracks."""
    near = live.near(row, tracker.prefilter_m)
    if not len(near):  # most plots: clutter far from every track
        return NO_CANDIDATES
    mature = live.plot_count[near] >= tracker.mature_from
    errors = np.empty(len(near))
    prediction = None
    if not mature.all():
        errors[~mature], _ = _scores(tracker.young_gate, live, near[~mature], row, tracker.estimator)
    if mature.any():
        errors[mature], prediction = _scores(tracker.gate, live, near[mature], row, tracker.estimator)
        if tracker.mature_first and np.isfinite(errors[mature]).any():
            errors[~mature] = np.inf
    return Candidates(near, errors, mature, prediction)

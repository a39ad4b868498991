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

When the estimator and both gates are `pairwise` (they take an array of plot rows and times,
one per candidate track), a batch of several plots is scored in one call per gate: one
prediction for every (plot, candidate track) pair of an antenna scan instead of one per plot.
The numbers are the same, pair by pair; what it saves is the NumPy calls per plot, which at a
thousand aircraft in the air cost more than the arithmetic (issue 16, item 4). Nearest neighbour
takes each plot after the previous plot's update, so its batches are single plots; with pairwise
roles the loop still scores a few of them at once, ahead (`_track_ahead`), and scores a plot
again, alone, when a track that changed in between (`LiveTracks.changed`) was or now is among its
candidates: the same updates to the bit, with one prediction and gate call for most plots.

A soft assigner (joint probabilistic data association, `pipeline.tracker.jpda`) gives, beside its
choices, the probabilities of each mature track's plots (`Assigner.hypotheses`): the loop then updates
every such track with all of them in one call (`Estimator.update_mixtures`) before the plots are taken,
and a chosen plot records its track's update; a track that was chosen by no plot is updated all the same.

A composition may carry a `RefusalWatch` (`pipeline.tracker.refusals`): the loop hands it each
plot with its final candidates, and it counts the plots a learned gate refused that the plain
window would have taken (issue 27); the caller reads and reports its counts.

The loop knows no method: no name, no type test. It works in ECEF; each plot brings its
radar's measurement covariance in the plot table, so plots of several radars mix. A long
recording can be given a part at a time (`track_chunks`), with the same updates as whole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from pipeline.recordings import plot_table
from pipeline.recordings.plot_table import Plots
from pipeline.tracker.assigner import Assigner, Candidates, Hypotheses
from pipeline.tracker.estimator import Estimator, Prediction
from pipeline.tracker.gate import Gate
from pipeline.tracker.management import TrackManagement
from pipeline.tracker.refusals import RefusalWatch
from pipeline.tracker.tracks import LiveTracks
from pipeline.tracker.updates import START, Updates

LOOKAHEAD_PLOTS = 4   # one-plot batches scored together by `_track_ahead`: at 1000 aircraft at once about 4 in 5
                      # plots keep these scores (2: 9 in 10, 8: 2 in 3), and each rescored plot costs a second scoring
NEAR_MARGIN = 1.001   # `_unchanged_near` looks this much beyond the pre-filter distance
NO_CANDIDATES = Candidates(np.empty(0, dtype=np.int64), np.empty(0), np.empty(0, dtype=bool), None, 0)


@dataclass(frozen=True)
class Composition:
    """A tracker's parts. `gate` scores tracks with at least `mature_from` plots, `young_gate` the
    others; candidates lie within `prefilter_m` metres of the plot (by their last position).
    `label` and `young_label` name, in the updates' `association` column, which gate won.
    `mature_first`: a plot inside a mature track's gate is not offered to young tracks (see
    `_candidates`). `refusals`: counts, for a composition with a learned gate, the plots it refused
    that the window would have taken (None: none counted). `revisit_scans`: a track that took a plot
    of a radar is not offered another plot of that radar within this many of its scans (0: it is;
    see `_candidates`). `records_velocity`: the updates carry the estimator's velocity where it gives one
    (`Estimator.velocities`; `track` records them, the bench does not)."""

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
    refusals: RefusalWatch | None = None
    revisit_scans: float = 0.0
    records_velocity: bool = False

    @property
    def pairwise(self) -> bool:
        """Whether the plots of a batch can be scored together (module docstring)."""
        return self.estimator.pairwise and self.gate.pairwise and self.young_gate.pairwise

    @property
    def looks_ahead(self) -> bool:
        """Whether one-plot batches are scored a few at a time (`_track_ahead`): pairwise roles, and
        candidates near the plot (with every track a candidate, every plot would be scored again)."""
        return self.pairwise and math.isfinite(self.prefilter_m)

    @property
    def latest_plots(self) -> int:
        """How many of a track's latest plots its rows keep beside its first: the most any role
        reads (the assigners read only the first, the oracle its target)."""
        return max(self.estimator.latest_plots, self.gate.latest_plots, self.young_gate.latest_plots)


def track(plots: Plots, tracker: Composition) -> dict[str, np.ndarray]:
    """Track `plots` (time order, one scenario) with `tracker`: one row per track update, a track's
    start counting as its first (`pipeline.tracker.updates`)."""
    tables = list(track_chunks([plots], tracker))
    return tables[0] if len(tables) == 1 else {key: np.concatenate([t[key] for t in tables]) for key in tables[0]}


def track_chunks(chunks: Iterable[Plots], tracker: Composition) -> Iterator[dict[str, np.ndarray]]:
    """Track plots given as consecutive chunks of one scenario in time order (as a recording is read
    a part at a time), with `tracker`: the update table of each chunk in turn, as `track` would give
    for all the chunks joined, row for row. Memory follows the chunk and the live tracks, not the
    recording: a chunk's plot table is the plots the live tracks keep (each its first and its
    `latest_plots` latest, renumbered: `LiveTracks.carry`) followed by the chunk's, the updates are
    handed on chunk by chunk, and the assigner's last batch of a chunk, which the chunk's end may
    cut, waits for the next chunk (its updates come in the next table)."""
    chunks = iter(chunks)
    chunk, live, waiting = next(chunks, None), None, None
    while chunk is not None:
        following = next(chunks, None)
        todo = chunk if waiting is None else plot_table.joined([waiting, chunk])
        if live is None:
            live, first = LiveTracks(todo, tracker.management, latest_plots=tracker.latest_plots,
                                     cell_m=tracker.prefilter_m), 0
        else:
            first = live.carry(todo)
        bounds = tracker.assigner.batches(todo)
        last = len(bounds) - 1 if following is None else max(len(bounds) - 2, 0)
        updates = Updates(tracker.estimator.gives_covariance,
                          tracker.records_velocity and tracker.estimator.gives_velocity)
        for begin, end, ahead in _runs(bounds[:last + 1].tolist(), tracker.looks_ahead):
            (_track_ahead if ahead else _track_batch)(live, range(first + begin, first + end), tracker, updates)
        waiting = None if following is None else todo.take(np.arange(bounds[last], len(todo)))
        yield updates.table(live.plots)
        chunk = following


def _track_batch(live: LiveTracks, rows: range, tracker: Composition, updates: Updates) -> None:
    """One batch of plots: candidates, the assigner's choices, then plot by plot in time order
    management and the chosen track's update or a new track (module docstring)."""
    plots = live.plots
    live.manage(plots.time[rows.start])
    if len(rows) > 1 and tracker.pairwise:
        candidates = _candidates(live, rows, tracker)
    else:
        candidates = [c for row in rows for c in _candidates(live, range(row, row + 1), tracker)]
    _count_refusals(live, rows, candidates, tracker)
    choices = tracker.assigner.assign(live, rows, candidates)
    chosen = [None if choice is None else _chosen(live, c, choice) for c, choice in zip(candidates, choices)]
    ahead = _updated_before(live, rows, candidates, choices, chosen, tracker)
    for row, c, choice in zip(rows, candidates, chosen):
        live.manage(plots.time[row])
        _take(live, row, c, choice, tracker, updates, ahead)


def _runs(bounds: list[int], ahead: bool) -> Iterator[tuple[int, int, bool]]:
    """The assigner's batches, given by their bounds, as (begin, end, scored ahead): with `ahead`,
    runs of up to LOOKAHEAD_PLOTS batches of one plot each go together to `_track_ahead`."""
    k, last = 0, len(bounds) - 1
    while k < last:
        n = 1
        if ahead and bounds[k + 1] - bounds[k] == 1:
            while n < LOOKAHEAD_PLOTS and k + n < last and bounds[k + n + 1] - bounds[k + n] == 1:
                n += 1
        yield bounds[k], bounds[k + n], n > 1
        k += n


def _track_ahead(live: LiveTracks, rows: range, tracker: Composition, updates: Updates) -> None:
    """Plots that are each a batch of their own (nearest neighbour), scored together at the first
    one's turn, then taken one at a time as `_track_batch` takes them. A plot's scores hold unless
    a track changed before its turn (`LiveTracks.changed`: started, updated or deleted) was one of
    its candidates or now lies within the pre-filter distance of it; then it is scored again,
    alone. So the updates are those of scoring one plot at a time, to the bit (the scores of a
    (track, plot) pair do not depend on the pairs scored with it), and most plots share one
    prediction and one gate call (module docstring)."""
    plots = live.plots
    live.manage(plots.time[rows.start])
    scored = _candidates(live, rows, tracker)
    live.changed.clear()
    for row, c in zip(rows, scored):
        live.manage(plots.time[row])
        if live.changed and not _unchanged_near(live, row, c.slots, tracker.prefilter_m):
            c = _candidates(live, range(row, row + 1), tracker)[0]
        _count_refusals(live, range(row, row + 1), [c], tracker)
        choice = tracker.assigner.assign(live, range(row, row + 1), [c])[0]
        chosen = None if choice is None else _chosen(live, c, choice)
        ahead = _updated_before(live, range(row, row + 1), [c], [choice], [chosen], tracker)
        _take(live, row, c, chosen, tracker, updates, ahead)


def _count_refusals(live: LiveTracks, rows: range, candidates: list[Candidates], tracker: Composition) -> None:
    """Hand the plots of `rows` with their final candidates, scored against the tracks as they are
    now, to the composition's `RefusalWatch`, if it has one: each plot once."""
    if tracker.refusals is not None:
        tracker.refusals.count(live, rows, candidates)


def _chosen(live: LiveTracks, c: Candidates, choice: int) -> tuple[int, int, int]:
    """The chosen candidate as (slot, track id, its place in `c`): the track id tells whether the
    slot still holds the track at the plot's turn."""
    slot = int(c.slots[choice])
    return slot, live.tracks[slot].track_id, choice


def _unchanged_near(live: LiveTracks, row: int, slots: np.ndarray, distance_m: float) -> bool:
    """Whether no track changed since plot `row` was scored is among `slots`, its candidates then,
    or lies within `distance_m` of it now (within a little more: no rounding may let one through),
    so that scoring it now would give the same candidates and scores."""
    changed = live.changed
    if not changed.isdisjoint(slots.tolist()):
        return False
    x, y, z = live.plots.position[row].tolist()
    reach = (distance_m * NEAR_MARGIN) ** 2
    for slot in changed:
        px, py, pz = live.position[slot].tolist()
        if (px - x) ** 2 + (py - y) ** 2 + (pz - z) ** 2 < reach:
            return False
    return True


def _take(live: LiveTracks, row: int, c: Candidates, choice: tuple[int, int, int] | None, tracker: Composition,
          updates: Updates, ahead: dict[int, tuple[np.ndarray, np.ndarray | None]]) -> None:
    """Plot `row` joins its chosen candidate, `choice` = (slot, track id, position in `c`), updated
    (or with its update made `ahead`), or starts a track when it has none or the track is gone."""
    estimator, plots = tracker.estimator, live.plots
    if choice is None or not live.holds(*choice[:2]):
        slot = live.start(row)
        estimator.start(live, slot)
        updates.add(live.tracks[slot].track_id, row, plots.position[row], live.weight[slot], START, np.nan,
                    plots.covariance[row])
        return
    slot, track_id, at = choice
    mature = bool(c.mature[at])
    if row in ahead:
        position, covariance = ahead[row]
    else:
        prediction, index = (c.prediction, _prediction_row(c, at)) if mature else (None, 0)
        position, covariance = estimator.update(live, slot, row, prediction, index)
    live.associate(slot, row, position, float(c.errors[at]))
    velocity = None
    if updates.with_velocity:
        values, spreads = estimator.velocities(live, np.array([slot]))
        velocity = (values[0], None if spreads is None else spreads[0])
    updates.add(track_id, row, position, live.weight[slot], tracker.label if mature else tracker.young_label,
                float(c.errors[at]), covariance, velocity)


def _prediction_row(c: Candidates, at: int) -> int:
    """The row of `c.prediction` that holds candidate `at` (a mature one: only those are predicted)."""
    return c.first + int(np.count_nonzero(c.mature[:at]))


def _updated_before(live: LiveTracks, rows: range, candidates: list[Candidates], choices: list[int | None],
                    chosen: list[tuple | None], tracker: Composition) -> dict[int, tuple[np.ndarray, np.ndarray | None]]:
    """The updates made for the batch's plots before they are taken in time order, by plot row: a soft
    assigner's (`_updated_jointly`), or a pairwise batch's (`_updated_ahead`), else none."""
    hypotheses = tracker.assigner.hypotheses(live, rows, candidates, choices)
    if hypotheses is not None:
        return _updated_jointly(live, rows, candidates, chosen, hypotheses, tracker.estimator)
    if len(rows) > 1 and tracker.pairwise:
        return _updated_ahead(live, rows, candidates, chosen, tracker.estimator)
    return {}


def _updated_jointly(live: LiveTracks, rows: range, candidates: list[Candidates], chosen: list[tuple | None],
                     hypotheses: Hypotheses, estimator: Estimator) -> dict[int, tuple[np.ndarray, np.ndarray | None]]:
    """Every track of a soft assigner's `hypotheses` updated with all its plots (`update_mixtures`), in
    one call; the update recorded at each plot chosen for a mature track. A chosen track deleted before its
    plot's turn was updated for nothing, as in `_updated_ahead`."""
    positions, covariances = estimator.update_mixtures(live, hypotheses)
    place = {slot: k for k, slot in enumerate(hypotheses.slots.tolist())}
    return {row: (positions[place[choice[0]]], covariances[place[choice[0]]])
            for row, c, choice in zip(rows, candidates, chosen) if choice is not None and c.mature[choice[2]]}


def _updated_ahead(live: LiveTracks, rows: range, candidates: list[Candidates], chosen: list[tuple | None],
                   estimator: Estimator) -> dict[int, tuple[np.ndarray, np.ndarray | None]]:
    """The updates of the batch's plots that chose a track, by plot row, made before the plots are taken
    in time order, in two calls of a pairwise estimator's `update_pairs`: the mature tracks' from the
    batch's prediction, then the young tracks' (which have none: the estimator predicts them itself, as
    its `update` would one at a time). Each resumes from the batch's state with its own plot only, so the
    order changes nothing; the calls are in the order the plot-by-plot updates would come (mature ones
    first, young ones in time order), so an estimator that draws per update (the LSTM's dropout masks)
    draws in the same order. A chosen mature track that management deletes before its plot's turn got
    its filter updated for nothing: the plot starts a track instead, and `start` resets the slot's
    filter. A chosen young track that will not live to its plot's turn (`LiveTracks.survives`) is left
    out, as its plot-by-plot update never comes. A track chosen by two plots (an assigner that allows
    it) leaves updates to the plot-by-plot path: all of them for a mature track (the young tracks' would
    then come between them there), the young tracks' for a young one. Updating a scan's young tracks together saves
    a prediction and a step call per young track (two or three network calls each for the learned
    estimators: most of their time on a busy recording, issue 29)."""
    mature, young, prediction = [], [], None
    for row, c, choice in zip(rows, candidates, chosen):
        if choice is None:
            continue
        if c.mature[choice[2]]:
            mature.append((row, choice[0], _prediction_row(c, choice[2])))
            prediction = c.prediction
        else:
            young.append((row, choice[0], 0))
    if _twice(mature):
        return {}
    time = live.plots.time
    young = [] if _twice(young) else [pair for pair in young if live.survives(pair[1], time[pair[0]])]
    ahead = {}
    for picked, given in ((mature, prediction), (young, None)):
        if not picked:
            continue
        positions, covariances = estimator.update_pairs(live, np.array([slot for _, slot, _ in picked], dtype=np.int64),
                                                        np.array([row for row, _, _ in picked]), given,
                                                        np.array([index for _, _, index in picked]))
        ahead.update({row: (positions[k], None if covariances is None else covariances[k])
                      for k, (row, _, _) in enumerate(picked)})
    return ahead


def _twice(pairs: list[tuple[int, int, int]]) -> bool:
    """Whether a track (the pairs' second item) is chosen by two of the (row, slot, index) `pairs`."""
    slots = [slot for _, slot, _ in pairs]
    return len(set(slots)) < len(slots)


def _scores(gate: Gate, live: LiveTracks, slots: np.ndarray, rows: int | np.ndarray, estimator: Estimator
            ) -> tuple[np.ndarray, Prediction | None]:
    """A gate's errors for the tracks at `slots` (K,) against plot `rows` (one row, or, for
    `pairwise` roles, one per track), and the prediction the update resumes from; the estimator
    predicts here, once, if the gate uses a prediction."""
    shared = estimator.predict(live, slots, live.plots.time[rows]) if gate.uses_prediction else None
    scores = gate(live, slots, rows, shared)
    return scores.errors, scores.prediction


def _candidates(live: LiveTracks, rows: range, tracker: Composition) -> list[Candidates]:
    """The tracks within the pre-filter distance of each plot of `rows`, scored; the plots'
    (track, plot) pairs go to each gate in one call (several plots only for `pairwise` roles).

    With `mature_first`, young tracks are out of the running (error inf, the young-track gate not
    asked) for a plot that some mature track's gate accepts: the track-file priority of Blackman &
    Popoli (1999), established tracks before tentative ones. Without it one plot outside an established track's
    gate (a manoeuvre, a plot with a large error) starts a track that is nearer to the next plot
    by the young-track radius's measure, takes it, and the established track starves: one aircraft
    becomes two tracks.

    With `revisit_scans`, a track is no candidate of a plot of a radar whose plot it took less than
    that many of the radar's scans before (`LiveTracks.revisited`): a radar sees a target once a
    revolution, so at 0.5 a track takes at most one plot per revolution of each radar whatever the
    gates and the assigner (nearest neighbour would give a track a clutter plot beside its own of
    the same scan; global nearest neighbour's batches hold one plot per track, but a scan's first
    plots and the previous scan's last are in different batches)."""
    near = [live.near(row, tracker.prefilter_m) for row in rows]
    if tracker.revisit_scans:
        near = [slots[~live.revisited(slots, row, tracker.revisit_scans)] for slots, row in zip(near, rows)]
    counts = [len(slots) for slots in near]
    if not any(counts):  # most plots: clutter far from every track
        return [NO_CANDIDATES] * len(near)
    if len(near) == 1:
        slots, pair_rows = near[0], rows.start
    else:
        slots, pair_rows = np.concatenate(near), np.repeat(np.arange(rows.start, rows.stop), counts)
    mature = live.plot_count.take(slots) >= tracker.mature_from
    scored = np.count_nonzero(mature)
    if scored == len(slots):  # no young candidate (most plots of an aircraft among many): no masks
        errors, prediction = _scores(tracker.gate, live, slots, pair_rows, tracker.estimator)
    else:
        errors, prediction = np.full(len(slots), np.inf), None
        young = ~mature
        if scored:
            errors[mature], prediction = _scores(tracker.gate, live, slots[mature], _of_pairs(pair_rows, mature),
                                                 tracker.estimator)
            if tracker.mature_first:  # their young tracks stay at inf (only mature pairs are scored yet)
                young = _of_unaccepting_plots(young, np.isfinite(errors), counts)
        if young is not None and young.any():
            errors[young], _ = _scores(tracker.young_gate, live, slots[young], _of_pairs(pair_rows, young),
                                       tracker.estimator)
    candidates, begin, first = [], 0, 0
    for own_slots in near:
        end = begin + len(own_slots)
        own_mature = mature[begin:end]
        candidates.append(Candidates(own_slots, errors[begin:end], own_mature, prediction, first) if len(own_slots)
                          else NO_CANDIDATES)
        first += np.count_nonzero(own_mature)
        begin = end
    return candidates


def _of_unaccepting_plots(pairs: np.ndarray, accepted: np.ndarray, counts: list[int]) -> np.ndarray | None:
    """Which of `pairs` (K,), (track, plot) pairs given plot by plot (`counts` of each), belong to a
    plot with no `accepted` pair (K,); None for none of one plot's."""
    if len(counts) == 1:
        return None if np.count_nonzero(accepted) else pairs
    plot = np.repeat(np.arange(len(counts)), counts)
    hit = np.zeros(len(counts), dtype=bool)
    hit[plot[accepted]] = True
    return pairs & ~hit[plot]


def _of_pairs(rows: int | np.ndarray, selected: np.ndarray) -> int | np.ndarray:
    """The plot rows of the `selected` (track, plot) pairs: `rows` itself when all pairs are one plot's."""
    return rows if isinstance(rows, int) else rows[selected]

"""The live tracks: fixed slots with array views, for vectorised gating and cheap management.

Most plots are clutter that starts a track which dies one silence period later, so slots are
reused rather than arrays grown and shrunk, and the times at which tracks fall due for lowering
sit in a heap: management costs nothing until a track is due. A heap entry carries the slot's
generation, which changes whenever the slot's weight changes or the slot is reused, so stale
entries are skipped. A free slot's position is infinite, so it is never within the pre-filter
distance.

The pre-filter (`near`) looks only at the tracks in the grid cells around the plot: the live
tracks sit in a uniform grid of cubes `cell_m` on a side (ECEF), keyed by their position, moved
when their position changes. A track within `distance_m` of the plot lies in a cube at most
ceil(distance_m / cell_m) cubes from the plot's along each axis, so those cubes hold every
candidate and the exact distance test on them gives the same tracks as a test on all; the cost
per plot follows the tracks near it, not all live tracks (issue 16: 1000 aircraft at once).

The state a track shows the loop is its position (ECEF metres) after its last update; what an
estimator keeps beyond that (a filter's velocity and covariance, a network's past states) the
estimator keeps, by slot. A track's history is the rows of its plots in the plot table being
tracked, and only as much of it as the roles read: its first plot's row (an estimator starts its
filter from it, the oracle reads its target) and its `latest_plots` latest (a network's input
window), so a track that lives for hours holds, and carries from one part of a recording to the
next, a few rows rather than all its plots (issue 16, item 4: memory independent of the
recording's length).

A track falls due for lowering at its last association plus the management rule's silence, which
the rule counts in revolutions of the radar of the track's latest plot: `LiveTracks` keeps each
track's latest radar's scan period (`scan_period`) and hands it to `silence` (the silence after
a lowering too is that radar's). It is lowered only when a plot comes later than that by more
than TIME_QUANTUM_S. A plot arriving exactly at the boundary is offered to the track first:
radar plot times are quantised (ASTERIX I048/140 to 1/128 s) and a track revisited one silence
period later would otherwise live or die on which side of the boundary a rounded time falls
(case 07: a radial target with one missed scan, its next plot exactly `silence_s` = two scans
later).

A track's revisits are kept by radar too (`last_seen`: the time of its latest plot of each radar
of the plot table), so that the loop can hold back a second plot of one radar within one
revolution (`revisited`).
"""

from __future__ import annotations

import functools
import heapq
import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.recordings import plot_table
from pipeline.recordings.plot_table import Plots
from pipeline.tracker.management import Evidence, TrackManagement

TIME_QUANTUM_S = 1.0 / 128.0  # ASTERIX CAT048 I048/140 time-of-day resolution (EUROCONTROL CAT048 ed. 1.32)
DEFAULT_CELL_M = 20000.0  # params' default tracker.association.prefilter_m; `track` passes the run's own
_AXIS = 1 << 32           # a cube's key packs its three indices, each offset by half this, into one int


@dataclass
class Track:
    """One track: its id (unique within a run), `rows`, the row of its first plot in the plot table
    followed by the rows of its latest plots (at most `LiveTracks.latest_plots` of them) in
    association order, and `memory`, what its estimator keeps per track (if it keeps it here).
    `rows[-n:]` are its latest n plots for any n up to `latest_plots`; its plot count is
    `LiveTracks.plot_count`."""

    track_id: int
    rows: list[int] = field(default_factory=list)
    memory: object = None


@functools.cache
def _neighbours(reach: int) -> tuple[int, ...]:
    """Key steps from a cube to the cubes at most `reach` cubes from it along each axis."""
    steps = range(-reach, reach + 1)
    return tuple((dx * _AXIS + dy) * _AXIS + dz for dx in steps for dy in steps for dz in steps)


class LiveTracks:
    """The tracks alive now over the plots `plots`, managed by `management`.

    Arrays by slot: `position` (S, 3) the last estimated position, `last_plot` (S, 3) the last
    plot's position, `weight` (S,), `plot_count` (S,), `alive` (S,), `scan_period` (S,) the scan
    period (s) of the radar of the last plot, `last_seen` (S, R) the time (s) of the latest plot
    of each of the plot table's R radars (-inf for none; columns in radar id order); `tracks` the
    Track of each slot (None when free). S grows by doubling when every slot is taken. `cell_m`:
    the grid's cube edge (m); `near` is exact for any distance and fastest for distances up to it. `latest_plots`:
    how many of a track's latest plots its `rows` keep beside its first (what the roles read,
    `pipeline.tracker.run.Composition.latest_plots`). Raises ValueError if it is negative."""

    def __init__(self, plots: Plots, management: TrackManagement, *, latest_plots: int, capacity: int = 64,
                 cell_m: float = DEFAULT_CELL_M) -> None:
        if latest_plots < 0:
            raise ValueError(f"latest_plots must be at least 0, got {latest_plots}")
        self.plots, self.management, self.cell_m, self.latest_plots = plots, management, cell_m, latest_plots
        self._reads_evidence = getattr(management, "reads_evidence", False)  # the others ignore it: not made
        self.tracks: list[Track | None] = [None] * capacity
        self.position = np.full((capacity, 3), np.inf)
        self.last_plot = np.full((capacity, 3), np.inf)
        self.weight = np.zeros(capacity)
        self.plot_count = np.zeros(capacity, dtype=np.int64)
        self.alive = np.zeros(capacity, dtype=bool)
        self.scan_period = np.zeros(capacity)
        self._radar_ids = np.empty(0, dtype=np.int64)
        self.last_seen = np.empty((capacity, 0))
        self._index_radars(plots)
        self._generation = [0] * capacity
        self._due_at = [0.0] * capacity  # the time each slot falls due next (its heap entry's; `survives`)
        self._due: list[tuple[float, int, int]] = []  # (time the slot falls due, slot, generation)
        self._free = list(range(capacity - 1, -1, -1))
        self._next_id = 0
        self._cells: dict[int, set[int]] = {}  # cube key -> slots of the live tracks in it
        self._cell_of: dict[int, int] = {}     # live slot -> its cube key
        self.changed: set[int] = set()  # slots started, associated or removed since the caller last emptied it

    def __len__(self) -> int:
        return len(self.tracks) - len(self._free)

    def _grow(self) -> None:
        capacity = len(self.tracks)
        self.tracks.extend([None] * capacity)
        self.position = np.vstack([self.position, np.full((capacity, 3), np.inf)])
        self.last_plot = np.vstack([self.last_plot, np.full((capacity, 3), np.inf)])
        self.weight = np.concatenate([self.weight, np.zeros(capacity)])
        self.plot_count = np.concatenate([self.plot_count, np.zeros(capacity, dtype=np.int64)])
        self.alive = np.concatenate([self.alive, np.zeros(capacity, dtype=bool)])
        self.scan_period = np.concatenate([self.scan_period, np.zeros(capacity)])
        self.last_seen = np.vstack([self.last_seen, np.full((capacity, self.last_seen.shape[1]), -np.inf)])
        self._generation.extend([0] * capacity)
        self._due_at.extend([0.0] * capacity)
        self._free = list(range(2 * capacity - 1, capacity - 1, -1))

    def _index_radars(self, plots: Plots) -> None:
        """Columns of `last_seen` for every radar of `plots` (radar id order; a radar new to the
        tracks, in a later part of a recording, gets a column of -inf), each plot's column
        (`_column`, by row) and each column's scan period (`_periods`, s)."""
        ids = np.union1d(self._radar_ids, np.array(sorted(plots.radars), dtype=np.int64))
        if len(ids) != len(self._radar_ids):
            seen = np.full((len(self.tracks), len(ids)), -np.inf)
            seen[:, np.searchsorted(ids, self._radar_ids)] = self.last_seen
            self._radar_ids, self.last_seen = ids, seen
        self._periods = np.array([plots.radars[int(radar_id)].scan_period_s for radar_id in ids.tolist()])
        self._column = np.searchsorted(ids, plots.radar_id)

    def revisited(self, slots: np.ndarray, row: int, scans: float) -> np.ndarray:
        """Whether each track at `slots` (K,) took a plot of plot `row`'s radar less than `scans` of
        that radar's revolutions before the plot, (K,) bool: the plot would be its second of that
        radar within one revolution (a split plot, clutter beside the target), not its next look."""
        column = self._column[row]
        return self.plots.time[row] - self.last_seen[slots, column] < scans * self._periods[column]

    def _seen(self, slot: int, row: int) -> None:
        """Plot `row` joined `slot`: its radar's scan period and revisit time."""
        column = self._column[row]
        self.scan_period[slot] = self._periods[column]
        self.last_seen[slot, column] = self.plots.time[row]

    def _key(self, x: float, y: float, z: float) -> int:
        """The key of the cube holding the point (x, y, z) m (finite)."""
        cell, half = self.cell_m, _AXIS // 2
        return ((math.floor(x / cell) + half) * _AXIS + math.floor(y / cell) + half) * _AXIS + math.floor(z / cell) + half

    def _place(self, slot: int) -> None:
        """File `slot` under the cube of its position (after a start or a position change); a track
        whose position is not finite (never within any distance) under none."""
        x, y, z = self.position[slot].tolist()
        old = self._cell_of.get(slot)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            if old is not None:
                self._unplace(slot)
            return
        key = self._key(x, y, z)
        if old == key:
            return
        if old is not None:
            self._unplace(slot)
        self._cells.setdefault(key, set()).add(slot)
        self._cell_of[slot] = key

    def _unplace(self, slot: int) -> None:
        key = self._cell_of.pop(slot, None)
        if key is None:
            return
        cell = self._cells[key]
        cell.discard(slot)
        if not cell:
            del self._cells[key]

    def near(self, row: int, distance_m: float) -> np.ndarray:
        """Slots (sorted) of the tracks whose position is within `distance_m` of plot `row`: the
        tracks of the cubes around the plot's (all placed tracks when those cubes outnumber the
        filled ones, or the distance is infinite), tested exactly."""
        ratio, cells = distance_m / self.cell_m, self._cells
        if not (math.isfinite(ratio) and (2 * math.ceil(ratio) + 1) ** 3 < len(cells)):  # infinite or NaN included
            slots = list(self._cell_of)
        else:
            centre = self._key(*self.plots.position[row].tolist())
            slots = [slot for step in _neighbours(math.ceil(ratio)) for slot in cells.get(centre + step, ())]
        if not slots:
            return np.empty(0, dtype=np.int64)
        slots = np.array(sorted(slots), dtype=np.int64)
        offset = self.position.take(slots, axis=0) - self.plots.position[row]
        return slots[np.einsum("ij,ij->i", offset, offset) < distance_m ** 2]

    def carry(self, plots: Plots) -> int:
        """Move on to the next part of a recording read a part at a time: the plot table becomes
        the plots the live tracks keep (their first and `latest_plots` latest, in table order)
        followed by `plots`, and every live track's rows are renumbered into it. Returns the row of
        `plots`' first plot: at most (latest_plots + 1) rows per live track come before it."""
        live = [track for track in self.tracks if track is not None]
        kept = np.unique(np.concatenate([np.asarray(track.rows, dtype=np.int64) for track in live])) if live \
            else np.empty(0, dtype=np.int64)
        for track in live:
            track.rows = np.searchsorted(kept, track.rows).tolist()
        self.plots = plot_table.joined([self.plots.take(kept), plots])
        self._index_radars(self.plots)
        return len(kept)

    def start(self, row: int) -> int:
        """A new track from plot `row`; its position is the plot's. Returns its slot."""
        if not self._free:
            self._grow()
        slot = self._free.pop()
        self.changed.add(slot)
        self.tracks[slot] = Track(self._next_id, [row])
        self._next_id += 1
        self.position[slot] = self.last_plot[slot] = self.plots.position[row]
        self.weight[slot] = self.management.start
        self.plot_count[slot] = 1
        self.alive[slot] = True
        self.last_seen[slot] = -np.inf
        self._seen(slot, row)
        self._schedule(slot, self.plots.time[row] + self._silence(slot))
        self._place(slot)
        return slot

    def _silence(self, slot: int) -> float:
        """The management rule's silence (s) for `slot` at its weight and its latest radar's scan."""
        return self.management.silence(self.weight[slot], self.scan_period[slot])

    def _schedule(self, slot: int, due: float) -> None:
        self._generation[slot] += 1
        self._due_at[slot] = due
        heapq.heappush(self._due, (due, slot, self._generation[slot]))

    def associate(self, slot: int, row: int, position: np.ndarray, error: float = 0.0) -> None:
        """Add plot `row` to a track, with the position (3,) estimated from it and the gate's normalised
        error of the pair; raise its weight (the management rule's, given the association's `Evidence`). The
        track's rows keep its first and its `latest_plots` latest: the one that falls out of the
        latest is dropped."""
        self.changed.add(slot)
        evidence = self._evidence(slot, row, error) if self._reads_evidence else None
        rows = self.tracks[slot].rows
        rows.append(row)
        if len(rows) > self.latest_plots + 1:
            del rows[1]
        self.position[slot] = position
        self._place(slot)
        self.last_plot[slot] = self.plots.position[row]
        self.weight[slot] = self.management.associated(self.weight[slot], evidence)
        self.plot_count[slot] += 1
        self._seen(slot, row)
        self._schedule(slot, self.plots.time[row] + self._silence(slot))

    def _evidence(self, slot: int, row: int, error: float) -> Evidence:
        """Plot `row` joining `slot` as the management rule sees it (`Evidence`): before the track takes it."""
        elapsed = float(self.plots.time[row] - self.last_seen[slot].max())  # its latest plot, of any radar
        here, before = self.plots.position[row], self.last_plot[slot]
        up = here + before
        up = up / np.linalg.norm(up)
        step = here - before
        climb = abs(float(step @ up))
        level = math.sqrt(max(float(step @ step) - climb * climb, 0.0))
        if elapsed <= 0.0:  # two plots at one time (to the plot times' resolution): no aircraft's next plot
            return Evidence(float(error), 0.0, int(self.plot_count[slot]), math.inf, math.inf)
        return Evidence(float(error), elapsed / self._periods[self._column[row]], int(self.plot_count[slot]),
                        level / elapsed, climb / elapsed)

    def holds(self, slot: int, track_id: int) -> bool:
        """Whether `slot` still holds track `track_id` (not deleted, not reused)."""
        track = self.tracks[slot]
        return track is not None and track.track_id == track_id

    def manage(self, now: float) -> list[Track]:
        """Lower the weight of the tracks whose due time is more than TIME_QUANTUM_S before `now`,
        deleting those the management rule deletes. Returns the deleted tracks."""
        removed = []
        while self._due and self._due[0][0] + TIME_QUANTUM_S < now:
            due, slot, generation = heapq.heappop(self._due)
            if generation != self._generation[slot]:
                continue
            weight = self.management.lowered(self.weight[slot])
            if weight is None:
                removed.append(self._remove(slot))
                continue
            self.weight[slot] = weight
            self._schedule(slot, due + self._silence(slot))
        return removed

    def survives(self, slot: int, now: float) -> bool:
        """Whether `manage`, called up to `now`, leaves the live track at `slot` alive if nothing else
        changes it meanwhile (no association): its lowerings replayed on a copy of its weight, as `manage`
        makes them. The loop updates a scan's chosen young tracks in one call ahead of their plots' turns
        only if they live to them (`pipeline.tracker.run._updated_ahead`)."""
        due, weight = self._due_at[slot], self.weight[slot]
        while due + TIME_QUANTUM_S < now:
            weight = self.management.lowered(weight)
            if weight is None:
                return False
            due = due + self.management.silence(weight, self.scan_period[slot])
        return True

    def _remove(self, slot: int) -> Track:
        track = self.tracks[slot]
        self.changed.add(slot)
        self.tracks[slot] = None
        self._free.append(slot)
        self._generation[slot] += 1
        self.alive[slot] = False
        self._unplace(slot)
        self.position[slot] = np.inf
        self.last_plot[slot] = np.inf
        return track

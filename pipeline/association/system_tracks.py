"""Persistent system track numbers of a fused air picture across common times.

A fused picture's row is a pair of local tracks (one per radar) or one radar's unpaired track. Taking the pair
as the row's identity makes every change of association a new track, so track switches and tracks per truth of
a fused picture would not mean what they mean for one radar. Multi-radar trackers instead number *system
tracks*: the user sees a system track, the local tracks associated to it update it, and it keeps its number
while any of them continues (the system-track management of multi-radar trackers, e.g. EUROCONTROL's ARTAS
and commercial correlators that keep "track ids maintained when targets move from one radar's coverage to
an adjacent one", Navtech Radar, "Track correlation" manual page). The rule here (ours, in that spirit):

- Each local track (user, scenario, track id) remembers the system number it last carried.
- At a common time the picture's rows are taken in picture order (fused pairs, then the first user's
  unpaired tracks, then the second's). A row's candidates are the numbers its local tracks carried; it takes
  the oldest (smallest) candidate not yet taken at this time, else a new number (one more than the largest
  issued). So a fused track continues while either local track does; when two system tracks merge (their
  local tracks become a pair) the older number survives; when a pair splits, the first user's track keeps the
  number (it comes first) and the second's gets a new one unless it carried another.
- Its local tracks then carry the row's number.
Numbers are unique per time, and a new number is never one used before, within one `SystemTracks`.
"""

from __future__ import annotations

import numpy as np


class SystemTracks:
    """The numbering state (real state: each local track's last number, the next free number) over a sequence of
    common times; call `number` once per time, in time order."""

    def __init__(self) -> None:
        self._carried: dict[tuple[int, int, int], int] = {}
        self._next = 0

    def number(self, scenario_id: int, ids: np.ndarray) -> np.ndarray:
        """System numbers (R,) of one time's picture rows from their local track ids (R, 2) [first user's,
        second user's], -1 where a row has none (`table_association.picture`'s order)."""
        ids = np.asarray(ids, dtype=np.int64).reshape(-1, 2)
        taken: set[int] = set()
        out = np.empty(len(ids), dtype=np.int64)
        for row, local in enumerate(ids.tolist()):
            keys = [(user, scenario_id, track) for user, track in enumerate(local) if track >= 0]
            free = sorted({self._carried[key] for key in keys if key in self._carried} - taken)
            if free:
                chosen = free[0]
            else:
                chosen, self._next = self._next, self._next + 1
            taken.add(chosen)
            self._carried.update((key, chosen) for key in keys)
            out[row] = chosen
        return out

"""Track management by M-of-N confirmation and a time-out deleter (a `TrackManagement` rule).

The usual alternative to the thesis's weights (Blackman & Popoli, "Design and Analysis of
Modern Tracking Systems", Artech House 1999, track confirmation: sliding-window M/N
confirmation; deletion after a time without an update, as Stone Soup's `UpdateTimeDeleter`):

- **Opportunity.** One antenna scan (`opportunity_s`, seconds: the params' radar's scan
  period). A track's start and each association fill an opportunity with a hit; a tentative
  track silent for 1.5 opportunities since its last hit, or one more opportunity since its last
  miss, records a miss (half a scan of slack for the plot's place in the scan).
- **Confirmation.** A tentative track is confirmed by the association that makes `m` hits
  within its last `n` opportunities (the start counts as one), and not before; a confirmed
  track stays confirmed until deleted.
- **Deletion.** A tentative track with no hit in its last `n` opportunities is deleted; a
  confirmed track silent for longer than `delete_after_s` seconds is deleted (a plot arriving
  exactly `delete_after_s` after the last hit, to the time quantum, is still offered to it:
  `pipeline.tracker.tracks`).

The weight (the update table's `weight` column) is the track's hits of its last `n`
opportunities as binary digits, the latest the highest, scaled into [0, 1): a tentative
track's weight is below 1, a confirmed track's is exactly 1.0 (`CONFIRMED`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.params import TrackerParams

CONFIRMED = 1.0


@dataclass(frozen=True)
class MOfN:
    """Confirm at `m` hits within the last `n` opportunities of `opportunity_s` seconds; delete a
    confirmed track silent for `delete_after_s` seconds, a tentative one with no hit in `n`."""

    m: int
    n: int
    opportunity_s: float
    delete_after_s: float

    @classmethod
    def from_params(cls, params: TrackerParams) -> "MOfN":
        return cls(params.confirm_m, params.confirm_n, params.opportunity_s, params.delete_after_s)

    @property
    def start(self) -> float:
        return self._weight(1 << (self.n - 1))

    def _weight(self, hits: int) -> float:
        """The weight of a tentative track whose hits are `hits` (bit i: opportunity n - 1 - i ago)."""
        return hits / 2 ** self.n

    def _hits(self, weight: float) -> int:
        return round(float(weight) * 2 ** self.n)

    def associated(self, weight: float) -> float:
        if weight >= CONFIRMED:
            return CONFIRMED
        hits = (self._hits(weight) >> 1) | 1 << (self.n - 1)
        return CONFIRMED if hits.bit_count() >= self.m else self._weight(hits)

    def lowered(self, weight: float) -> float | None:
        if weight >= CONFIRMED:
            return None
        hits = self._hits(weight) >> 1
        return self._weight(hits) if hits else None

    def silence(self, weight: float) -> float:
        if weight >= CONFIRMED:
            return self.delete_after_s
        latest_was_hit = self._hits(weight) >> (self.n - 1)
        return 1.5 * self.opportunity_s if latest_was_hit else self.opportunity_s

    def confirmed(self, weights: np.ndarray) -> np.ndarray:
        return np.asarray(weights) >= CONFIRMED

    def status(self, weight: float) -> str:
        return "confirmed" if self.confirmed(weight) else "tentative"

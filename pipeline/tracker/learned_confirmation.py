"""Track management by a learned confirmation (a `TrackManagement` rule, issue 34): M-of-N whose hits are
weighed by a network's score of their evidence.

M-of-N (`pipeline.tracker.m_of_n`; Blackman & Popoli, "Design and Analysis of Modern Tracking Systems",
Artech House 1999, sliding-window M/N confirmation) counts every hit alike: a clutter plot that happens to
fall in a young track's gate counts as much as an aircraft's next plot. Here each hit counts by how much it
looks like an aircraft's: a scorer (`pipeline.learning.confirmation`: a small network trained on the
simulated tracks of the training routes and clutter) gives each association a score in [0, 1] from its
`Evidence` (the gate's normalised error, the gap in scans, the track's plots so far, the speed the two plots
imply), and a tentative track is confirmed when the scores of the hits within its last `n` opportunities add
up to `threshold`. The threshold is chosen for a target false-track probability (the share of clutter's
candidate tracks confirmed, `tracker.management.learned_false_track_probability`) from the scores the
training's hold-out gave clutter's tracks (`threshold_for`), so it is a knob of the tracker, not of the
training.

- **Opportunity, misses, deletion**: as M-of-N's (an antenna scan of the radar of the track's latest plot; a
  tentative track with no hit in its last `n` opportunities is deleted; a confirmed one silent for longer
  than max(`delete_after_s`, `delete_after_scans` scans)).
- **Scores on a grid**: a hit's score is kept as a level 1..`LEVELS` (1 + round(score x (LEVELS - 1))), a
  miss as 0, and the threshold in levels; a track's start is a hit of the top level (it has no evidence), and
  only an association confirms, as in M-of-N.
  With every score 1 and threshold m x LEVELS the rule is M-of-N with (m, n), to the update (test).
- **The weight** (the update table's `weight` column): a tentative track's levels of its last `n`
  opportunities as digits base 2**`BITS`, the latest the highest, scaled into [0, 1); a confirmed track's
  is exactly 1.0, as M-of-N's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from pipeline.tracker.management import Evidence

CONFIRMED = 1.0
BITS = 4                      # a level's digit: the weight holds n of them (n x BITS <= 52, a double's mantissa)
LEVELS = (1 << BITS) - 1      # a hit's top level (15); 0 is a miss
MAX_N = 52 // BITS            # the longest window the weight holds exactly


def level(score: float) -> int:
    """A hit's level (1..LEVELS) from its score in [0, 1] (clipped)."""
    return 1 + round(min(max(score, 0.0), 1.0) * (LEVELS - 1))


def threshold_for(clutter_maxima: np.ndarray, false_track_probability: float) -> int:
    """The threshold (in levels) that confirms at most `false_track_probability` of clutter's candidate tracks,
    given each one's highest window sum (levels) over its tentative life (`clutter_maxima` (T,), the training's
    hold-out): the least integer above all but that share of them (a track is confirmed at a sum >= the
    threshold). Raises ValueError for a probability outside (0, 1) or no maxima."""
    if not 0.0 < false_track_probability < 1.0:
        raise ValueError(f"false-track probability {false_track_probability}: must lie in (0, 1)")
    maxima = np.sort(np.asarray(clutter_maxima, dtype=np.int64))
    if not len(maxima):
        raise ValueError("no clutter tracks to choose the threshold from")
    allowed = math.floor(false_track_probability * len(maxima))  # clutter tracks that may reach it
    return int(maxima[len(maxima) - allowed - 1]) + 1 if allowed < len(maxima) else int(maxima[0])


@dataclass(frozen=True)
class LearnedConfirmation:
    """Confirm when the levels of the hits within the last `n` opportunities add up to `threshold` (module
    docstring); `score(evidence)` in [0, 1] weighs each hit; delete as M-of-N."""

    n: int
    threshold: float
    delete_after_s: float
    delete_after_scans: float
    score: Callable[[Evidence], float]
    reads_evidence = True  # LiveTracks makes each association's Evidence only for a rule that reads it

    def __post_init__(self) -> None:
        if not 1 <= self.n <= MAX_N:
            raise ValueError(f"learned confirmation over {self.n} opportunities: must be 1..{MAX_N}")

    @property
    def _scale(self) -> int:
        return 1 << (BITS * self.n)

    def _weight(self, digits: int) -> float:
        return digits / self._scale

    def _digits(self, weight: float) -> int:
        return round(float(weight) * self._scale)

    def _top(self, levels: int) -> int:
        return levels << (BITS * (self.n - 1))

    def window_sum(self, weight: float) -> int:
        """The levels of a tentative track's hits within its last `n` opportunities."""
        digits, total = self._digits(weight), 0
        while digits:
            total += digits & LEVELS
            digits >>= BITS
        return total

    def _settled(self, digits: int) -> float:
        return CONFIRMED if self.window_sum(self._weight(digits)) >= self.threshold else self._weight(digits)

    @property
    def start(self) -> float:
        return self._weight(self._top(LEVELS))  # confirmed by an association only, as M-of-N's

    def associated(self, weight: float, evidence: Evidence | None = None) -> float:
        if weight >= CONFIRMED:
            return CONFIRMED
        if evidence is None:
            raise ValueError("a learned confirmation needs each association's evidence")
        return self._settled((self._digits(weight) >> BITS) | self._top(level(self.score(evidence))))

    def lowered(self, weight: float) -> float | None:
        if weight >= CONFIRMED:
            return None
        digits = self._digits(weight) >> BITS
        return self._weight(digits) if digits else None

    def silence(self, weight: float, scan_period_s: float) -> float:
        if weight >= CONFIRMED:
            return max(self.delete_after_s, self.delete_after_scans * scan_period_s)
        latest_was_hit = self._digits(weight) >> (BITS * (self.n - 1))
        return 1.5 * scan_period_s if latest_was_hit else scan_period_s

    def confirmed(self, weights: np.ndarray) -> np.ndarray:
        return np.asarray(weights) >= CONFIRMED

    def status(self, weight: float) -> str:
        return "confirmed" if self.confirmed(weight) else "tentative"

"""Track management by a sequential probability ratio test on each track's hits and misses (a
`TrackManagement` rule): the classical track-existence test beside the thesis's weights and M-of-N.

Wald's SPRT as track confirmation uses it (Blackman & Popoli, "Design and Analysis of Modern
Tracking Systems", Artech House 1999, section 6.2, the track score and its SPRT thresholds; Wald,
"Sequential Analysis", 1947). Hypothesis H1: the track follows an aircraft, detected in a scan with
probability P_D (`sprt_detection_probability`); H0: it follows clutter, a false plot falling in its
gate in a scan with probability P_F (`sprt_false_plot_probability`). The score is the log-likelihood
ratio of its scans, ln P(hits | H1) / P(hits | H0) (nats):

- a hit (the track's start, or an association) adds ln(P_D / P_F);
- a miss (a scan without a plot) adds ln((1 - P_D) / (1 - P_F)), below zero;
- a tentative track is confirmed when the score reaches T2 = ln((1 - beta) / alpha) and deleted when it
  falls to T1 = ln(beta / (1 - alpha)), alpha (`sprt_false_track_probability`) being the risk of
  confirming a clutter track and beta (`sprt_lost_track_probability`) that of deleting an aircraft's;
- a confirmed track's score starts again at the test's width, T2 - T1, above T2, is capped there, and the
  track is deleted when its score falls to T2: the deletion by a drop of the score below its maximum
  (Blackman & Popoli, 6.2), the drop here being the width of the confirmation test (ours: the book leaves
  the threshold to the designer).

This is the SPRT on hits and misses alone, the binary form: the score's kinematic part (the plot's
likelihood in the gate, which IPDA's existence probability also uses) needs the innovation, and a rule
sees only its weight (`pipeline.tracker.management`). The new track's score starts at one hit, prior
odds of one.

**Opportunities**, as M-of-N's (`pipeline.tracker.m_of_n`): a scan of the radar of the track's latest
plot; a track silent for 1.5 scans since its latest hit, or one more scan since its latest miss, records a
miss (half a scan of slack for the plot's place in the scan).

**The weight** (the update table's `weight` column) is the score in nats, on a grid of `QUANTUM` nats; the
half-quantum place after it says whether the latest event was a miss (its silence is one scan) or a hit
(1.5 scans): invisible at a millionth of a nat, as M-of-N's weight holds its hits in its bits. A confirmed
track's weight is above T2, a tentative one's below.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.params import Management
from pipeline.tracker.management import Evidence

QUANTUM = 2.0 ** -20  # nats: the score's grid; half of it marks a miss (exact in a double for |score| < 2**32)


@dataclass(frozen=True)
class SequentialRatioTest:
    """The binary SPRT (module docstring), its increments and thresholds in whole `QUANTUM`s:
    `hit` > 0, `miss` < 0, `lower` (T1) < `upper` (T2)."""

    hit: int
    miss: int
    lower: int
    upper: int

    @classmethod
    def from_probabilities(cls, detection: float, false_plot: float, false_track: float, lost_track: float
                           ) -> "SequentialRatioTest":
        """From P_D, P_F, alpha and beta (module docstring). Raises ValueError unless 0 < P_F < P_D < 1 and
        0 < alpha, beta with alpha + beta < 1 (the thresholds then lie on both sides of zero)."""
        if not 0.0 < false_plot < detection < 1.0:
            raise ValueError(f"the SPRT needs 0 < P_F < P_D < 1: P_F = {false_plot}, P_D = {detection}")
        if not (false_track > 0.0 and lost_track > 0.0 and false_track + lost_track < 1.0):
            raise ValueError(f"the SPRT needs alpha, beta > 0 and alpha + beta < 1: alpha = {false_track}, "
                             f"beta = {lost_track}")

        def units(nats: float) -> int:
            return round(nats / QUANTUM)

        return cls(units(math.log(detection / false_plot)), units(math.log((1 - detection) / (1 - false_plot))),
                   units(math.log(lost_track / (1 - false_track))), units(math.log((1 - lost_track) / false_track)))

    @classmethod
    def from_params(cls, params: Management) -> "SequentialRatioTest":
        return cls.from_probabilities(params.sprt_detection_probability, params.sprt_false_plot_probability,
                                      params.sprt_false_track_probability, params.sprt_lost_track_probability)

    @property
    def _full(self) -> int:
        """A confirmed track's score at its cap: the test's width above T2."""
        return self.upper + (self.upper - self.lower)

    @staticmethod
    def _weight(score: int, missed: bool) -> float:
        return (2 * score + missed) * (QUANTUM / 2)

    @staticmethod
    def _state(weight: float) -> tuple[int, bool]:
        halves = round(float(weight) / (QUANTUM / 2))
        return halves >> 1, bool(halves & 1)

    @property
    def start(self) -> float:
        return self._weight(self._full if self.hit >= self.upper else self.hit, False)

    def associated(self, weight: float, evidence: Evidence | None = None) -> float:
        score, _ = self._state(weight)
        if score > self.upper:  # confirmed
            return self._weight(min(score + self.hit, self._full), False)
        score += self.hit
        return self._weight(self._full if score >= self.upper else score, False)

    def lowered(self, weight: float) -> float | None:
        score, _ = self._state(weight)
        floor = self.upper if score > self.upper else self.lower
        score += self.miss
        return None if score <= floor else self._weight(score, True)

    def silence(self, weight: float, scan_period_s: float) -> float:
        return scan_period_s if self._state(weight)[1] else 1.5 * scan_period_s

    def confirmed(self, weights: np.ndarray) -> np.ndarray:
        return np.asarray(weights) > (self.upper + 0.75) * QUANTUM  # confirmed: score >= upper + 1, tentative < upper

    def status(self, weight: float) -> str:
        return "confirmed" if self.confirmed(weight) else "tentative"

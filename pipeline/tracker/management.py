"""Role: track management, when a track starts, is confirmed and is deleted (Stone Soup's
initiator and deleter; thesis 4.4).

A rule works on one number per track, its weight, and one clock per track: a track with no
association and no weight change for `silence(weight, scan_period_s)` seconds is lowered
(`lowered`), which may delete it. `pipeline.tracker.tracks.LiveTracks` keeps the weights and the
clocks and asks the rule; the loop never reads a weight itself.

A track's life is counted in revolutions of the radar of its latest plot, not in seconds alone:
`scan_period_s` is that radar's scan period (the plot table's `Plots.radars[radar_id]`), so one
recording may hold radars of different periods. A target is seen once per revolution, and a
target moving clockwise in azimuth a little later each time (12.07 s apart for a 12 s radar),
so a silence fixed in seconds that spans two scans of a 6 s radar does not span one of a 12 s
radar, and every tentative track of that radar would die before its second plot (case 25). The
revisit intervals of several sensors are a known need of deleters (Stone Soup issue 610, PR 623:
time-step deleters); a radar display counts target persistence in antenna turns (BR24radar_pi
issue 36).

An association comes with its `Evidence` (the gate's normalised error, the time since the track's
previous plot in scans, the plots the track had, the horizontal and vertical speeds the two plots imply), which
a learned rule scores; `pipeline.tracker.tracks.LiveTracks` makes it only for a rule whose `reads_evidence` is
true, and hands the others None.

The default rule is the thesis's (`ThesisWeights`); `pipeline.tracker.m_of_n.MOfN` is the usual
alternative (M-of-N confirmation, time-out deletion), `pipeline.tracker.sprt.SequentialRatioTest` the
classical track-existence test (the SPRT on hits and misses), and
`pipeline.tracker.learned_confirmation.LearnedConfirmation` M-of-N with each hit weighed by a network's
score of its evidence (issue 34). `pipeline.tracker.registry` names them (`tracker.management.rule`, or a
run's `management`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from pipeline.params import Management

EPSILON = 1e-9  # weights are sums of steps such as 0.2: compare with this tolerance


class Evidence(NamedTuple):
    """What one association tells of its track: `error`, the gate's normalised error of the pair (in
    [0, 1): `pipeline.tracker.gate`); `gap_scans`, the time since the track's previous plot in scans of
    the new plot's radar; `plots`, the plots the track had before this one; `speed_mps`, the horizontal
    distance between the two plots over that time, and `climb_mps` the vertical one, unsigned (m/s: vertical
    along the Earth's radius through their midpoint; a false plot's altitude is anywhere from the ground to
    the ceiling, an aircraft's changes at a few tens of metres a second); both infinite for two plots at one time."""

    error: float
    gap_scans: float
    plots: int
    speed_mps: float
    climb_mps: float


class TrackManagement(Protocol):
    """Weights of a track over its life: `start` for a new one, `associated(w, evidence)` after an
    association (its `Evidence`), `lowered(w)` after a silence of `silence(w, scan_period_s)` seconds at weight w
    whose latest plot came from a radar of scan period `scan_period_s` (s) (None: delete the
    track); `confirmed(w)` says which weights (an array) mean a confirmed track; `status(w)` names
    one."""

    start: float

    def silence(self, weight: float, scan_period_s: float) -> float: ...

    def associated(self, weight: float, evidence: Evidence | None = None) -> float: ...

    def lowered(self, weight: float) -> float | None: ...

    def confirmed(self, weights: np.ndarray) -> np.ndarray: ...

    def status(self, weight: float) -> str: ...


@dataclass(frozen=True)
class ThesisWeights:
    """The thesis's weights (`tracker.weight_*`): a track starts at `start` (0.4), is a candidate at
    `candidate` (0.8) and confirmed at `confirmed_weight` (1.0); each association adds `step`
    (0.2, capped at the confirmed weight); a silence takes `step` off. A track lowered while at the
    candidate weight is deleted (thesis). The thesis does not say what happens to a track lowered
    at or below the start weight: here it is deleted too, so clutter tracks die after one silence
    period.

    The silence is max(`silence_s`, `silence_scans` x the scan period of the radar of the track's
    latest plot) seconds: the thesis's 12 s is two scans of its 6 s radar (10 rpm: params' radar),
    and `silence_scans` (2) keeps those two scans for a slower radar (24 s at 12 s), while a faster
    one keeps the thesis's seconds (12 s at 4 s). `silence_scans` 0: the seconds alone, any radar."""

    start: float
    candidate: float
    confirmed_weight: float
    step: float
    silence_s: float
    silence_scans: float = 0.0

    @classmethod
    def from_params(cls, params: Management) -> "ThesisWeights":
        return cls(params.weight_start, params.weight_candidate, params.weight_confirmed, params.weight_step,
                   params.silence_s, params.silence_scans)

    def associated(self, weight: float, evidence: Evidence | None = None) -> float:
        return min(weight + self.step, self.confirmed_weight)

    def silence(self, weight: float, scan_period_s: float) -> float:
        return max(self.silence_s, self.silence_scans * scan_period_s)

    def lowered(self, weight: float) -> float | None:
        if abs(weight - self.candidate) < EPSILON or weight <= self.start + EPSILON:
            return None
        return weight - self.step

    def confirmed(self, weights: np.ndarray) -> np.ndarray:
        return np.asarray(weights) >= self.confirmed_weight - EPSILON

    def status(self, weight: float) -> str:
        if self.confirmed(weight):
            return "confirmed"
        if weight >= self.candidate - EPSILON:
            return "candidate"
        return "tentative"

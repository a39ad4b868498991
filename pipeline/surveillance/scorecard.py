"""The scorecard of air-traffic surveillance: a tracker's confirmed track updates against the truth, in the
indicators and units an air navigation service provider reads, beside published reference figures.

Sources. EUROCAE ED-129C, as the open COMPASS evaluator implements it (OpenATSGmbH/COMPASS,
doc/user_manual/eval/eval_req_det.tex, "Detection", time-based calculation = ED-129C Appendix C's
inter-arrival time method): the probability of update and the ratio of long gaps. The ECAC radar
separation minima guidelines (annexes: measured en-route trackers, single- and multi-radar; figures as
../shared/spec/field-standards.md quotes them): position error mean and standard deviation, shares of
straight-flight updates within 0.25 NM and of manoeuvring updates within 1 NM. The FAA's orthogonal set
(accuracy, track loss, track swap) and EUROCONTROL ESASSP's indicators (velocity RMS straight and turning,
false and extra tracks) name the rest; ESASSP's requirement values were not available, so none is set
beside them.

How each is computed (`Settings` holds the choices, each documented there):

- Only confirmed updates count: the system tracks a controller is shown.
- Association. Each confirmed update goes to the nearest target (horizontal distance, `association_m`
  at most) whose truth spans its time; a track's target is the one most of its updates went to (ties: the
  lowest id); a track none of whose updates went to a target is a false track. Every confirmed update of a
  track with a target is scored against that target, near or not: a track drifting off its aircraft is
  counted in the large-error shares, not dropped.
- Truth between its samples: a cubic interpolating spline of each target's positions over time (scipy
  `make_interp_spline`; quadratic or linear with fewer samples), its derivatives the true velocity and
  acceleration.
- Errors in the local horizontal plane at the true position (east, north): the position error's
  distance (mean, standard deviation, RMS) and its parts along and across the true horizontal velocity
  (RMS, and the along-track mean: negative = the track lags); the horizontal velocity error (RMS) on
  straight and on manoeuvring updates. An update is manoeuvring where the target's true horizontal
  acceleration exceeds `manoeuvre_mps2`.
- Probability of update (ED-129C App. C): for each target its reference periods are the runs of truth
  samples in coverage; the times of its tracks' updates split each period into gaps (its start and end
  included); a gap longer than the update interval plus `miss_tolerance_scans` scans is a miss and adds
  its length minus one update interval to the missed time MT; PD = 1 - MT / DT, DT the periods' total
  length. A target's first gap holds the track's initiation (a confirmed track needs several plots):
  the time a controller does not see the aircraft.
- Ratio of long gaps (ED-129C REQ 18, as COMPASS): the same with only the gaps longer than
  `long_gap_scans` (3 x 1.1) update intervals: sum of (gap - update interval) / DT; at most 0.5 %.
- Tracks per aircraft (targets with a track), extra tracks (a track of a target that already had an
  earlier one, over all confirmed tracks with a target), false tracks, swaps (a change of the target a
  track's consecutive updates went to), initiation time (from the start of a target's first reference
  period to its first confirmed update; mean and 95th percentile), targets never tracked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from pipeline.geometry import geodesy
from pipeline.geometry.asterix_units import NAUTICAL_MILE_M
from pipeline.params import Scorecard


INDICATORS = ("probability_of_update", "ratio_of_long_gaps", "position_error_mean_m", "position_error_sigma_m",
              "position_rms_m", "along_track_rms_m", "across_track_rms_m", "along_track_mean_m",
              "velocity_rms_straight_mps", "velocity_rms_manoeuvring_mps", "straight_within_0_25_nm",
              "manoeuvring_within_1_nm", "tracks_per_aircraft", "extra_track_ratio", "false_update_ratio",
              "initiation_mean_s", "initiation_p95_s")  # `combined`'s ratios, errors and times
COUNTS = ("confirmed_updates", "scored_updates", "targets", "targets_never_tracked", "confirmed_tracks",
          "false_tracks", "track_swaps", "straight_updates", "manoeuvring_updates")  # `combined`'s counts (sums)
ROUNDING = 1e-9  # a gap of exactly long_gap_scans update intervals, to this relative rounding, is not long


@dataclass(frozen=True)
class Settings:
    """The scorecard's choices where its sources leave one open (module docstring): the update interval (the
    radar's scan period) and params' `scorecard` section (`from_params`), each documented there."""

    update_interval_s: float          # the radar's scan period: the update interval ED-129C's gaps are counted in
    association_m: float              # an update farther than this from every target goes to none
    miss_tolerance_scans: float       # a gap up to (1 + this) update intervals is no miss
    long_gap_scans: float             # ED-129C: a long gap is longer than 3 x update interval x 1.1
    manoeuvre_mps2: float             # true horizontal acceleration above which an update is manoeuvring

    @classmethod
    def from_params(cls, update_interval_s: float, section: Scorecard) -> Settings:
        """The settings of params' `scorecard` section for a radar of scan period `update_interval_s`."""
        return cls(update_interval_s, section.association_m, section.miss_tolerance_scans, section.long_gap_scans,
                   section.manoeuvre_mps2)

    def __post_init__(self) -> None:
        for name, low in (("update_interval_s", 0.0), ("association_m", 0.0), ("miss_tolerance_scans", -1.0),
                          ("long_gap_scans", 0.0), ("manoeuvre_mps2", 0.0)):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= low:
                raise ValueError(f"scorecard setting {name} = {value!r}: must be a finite number above {low:g}")


@dataclass(frozen=True)
class TrackUpdates:
    """A tracker's updates: track id (U,), time (U,) s, ECEF position (U, 3) m, ECEF velocity (U, 3) m/s (NaN
    where unknown), and whether the track was confirmed at the update (U,)."""

    track_id: np.ndarray
    time_s: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    confirmed: np.ndarray


@dataclass(frozen=True)
class Truth:
    """True positions: target id (T,), time (T,) s, ECEF position (T, 3) m, in radar coverage (T,)."""

    target_id: np.ndarray
    time_s: np.ndarray
    position: np.ndarray
    in_coverage: np.ndarray


@dataclass(frozen=True)
class Reference:
    """A published figure an indicator is held against: `at_most` (or at least, when False) `value`."""

    indicator: str
    value: float
    at_most: bool
    source: str


def _ecac(figures: str, mean_nm: float, sigma_nm: float, straight: float, manoeuvring: float) -> tuple:
    """The four figures of the ECAC radar separation guidelines for a kind of tracker (`figures`)."""
    source = f"ECAC radar separation guidelines, {figures} tracker"
    return ((figures, Reference("position_error_mean_m", mean_nm * NAUTICAL_MILE_M, True, f"{source}: mean {mean_nm} NM")),
            (figures, Reference("position_error_sigma_m", sigma_nm * NAUTICAL_MILE_M, True,
                                f"{source}: sigma {sigma_nm} NM")),
            (figures, Reference("straight_within_0_25_nm", straight, False,
                                f"{source}: {100 * straight:.2f} % of straight updates within 0.25 NM")),
            (figures, Reference("manoeuvring_within_1_nm", manoeuvring, False,
                                f"{source}: {100 * manoeuvring:.2f} % of manoeuvring updates within 1 NM")))


REFERENCES = (  # (figure set, reference), the figures of field-standards.md with their sources
    *_ecac("single-radar", 0.13, 0.13, 0.9830, 0.9986),
    *_ecac("multi-radar", 0.06, 0.08, 0.9955, 1.0),
    ("ED-129C", Reference("ratio_of_long_gaps", 0.005, True, "EUROCAE ED-129C REQ 18 (as COMPASS): at most 0.5 %")),
)


class _Trajectories:
    """Each target's truth as splines of position over time, with their first and second derivatives."""

    def __init__(self, truth: Truth) -> None:
        self.targets = np.unique(truth.target_id)
        self.spans, self.splines = {}, {}
        for target in self.targets.tolist():
            rows = np.flatnonzero(truth.target_id == target)
            rows = rows[np.argsort(truth.time_s[rows], kind="stable")]
            times, keep = np.unique(truth.time_s[rows], return_index=True)
            self.spans[target] = (times[0], times[-1])
            self.splines[target] = (make_interp_spline(times, truth.position[rows[keep]], k=min(3, len(times) - 1))
                                    if len(times) > 1 else None, truth.position[rows[keep][0]])

    def at(self, target: int, time_s: np.ndarray, derivative: int = 0) -> np.ndarray:
        spline, only = self.splines[target]
        if spline is None:
            return np.broadcast_to(only if derivative == 0 else np.zeros(3), (len(time_s), 3)).copy()
        if derivative > spline.k:
            return np.zeros((len(time_s), 3))
        return spline(time_s, nu=derivative)

    def spanning(self, target: int, time_s: np.ndarray) -> np.ndarray:
        first, last = self.spans[target]
        return (time_s >= first) & (time_s <= last)


def _horizontal(vectors: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(N, 2) east and north parts of ECEF vectors (N, 3) in the local frames `rotations` (N, 3, 3)."""
    return np.einsum("nij,nj->ni", rotations, vectors)[:, :2]


def _frames(points: np.ndarray) -> np.ndarray:
    latitude, longitude, _ = geodesy.ecef_to_geodetic(points)
    return geodesy.enu_rotations(np.atleast_1d(latitude), np.atleast_1d(longitude))


def _associated(updates: TrackUpdates, trajectories: _Trajectories, settings: Settings) -> np.ndarray:
    """Each update's nearest target within `association_m` (horizontal) whose truth spans its time; -1 for none."""
    best, nearest = np.full(len(updates.time_s), np.inf), np.full(len(updates.time_s), -1, dtype=np.int64)
    for target in trajectories.targets.tolist():
        rows = np.flatnonzero(trajectories.spanning(target, updates.time_s))
        if not len(rows):
            continue
        truth = trajectories.at(target, updates.time_s[rows])
        distance = np.linalg.norm(_horizontal(updates.position[rows] - truth, _frames(truth)), axis=1)
        closer = (distance < best[rows]) & (distance <= settings.association_m)
        best[rows[closer]], nearest[rows[closer]] = distance[closer], target
    return nearest


def _track_targets(track_id: np.ndarray, nearest: np.ndarray) -> dict[int, int]:
    """Each track's target: the one most of its updates went to (ties: the lowest id); -1 for a false track."""
    targets = {}
    for track in np.unique(track_id).tolist():
        went = nearest[(track_id == track) & (nearest >= 0)]
        if not len(went):
            targets[track] = -1
            continue
        ids, counts = np.unique(went, return_counts=True)
        targets[track] = int(ids[np.argmax(counts)])
    return targets


def _periods(truth: Truth, target: int, update_interval_s: float) -> list[tuple[float, float]]:
    """A target's reference periods: runs of its in-coverage truth samples, a run broken where two samples
    in coverage are more than 1.5 update intervals apart or a sample between them is out of coverage."""
    rows = np.flatnonzero(truth.target_id == target)
    rows = rows[np.argsort(truth.time_s[rows], kind="stable")]
    times, inside = truth.time_s[rows], truth.in_coverage[rows]
    periods, start, previous = [], None, None
    for time, covered in zip(times.tolist(), inside.tolist()):
        if covered and start is not None and time - previous <= 1.5 * update_interval_s:
            previous = time
            continue
        if start is not None:
            periods.append((start, previous))
        start, previous = (time, time) if covered else (None, None)
    if start is not None:
        periods.append((start, previous))
    return periods


def gap_times(periods: list[tuple[float, float]], update_times: np.ndarray, settings: Settings
              ) -> tuple[float, float, float]:
    """(DT, MT, MT of long gaps) s of one target (ED-129C App. C, module docstring): its reference `periods`
    and the times of its tracks' confirmed updates."""
    interval = settings.update_interval_s
    duration = missed = long_missed = 0.0
    for start, end in periods:
        inside = np.sort(update_times[(update_times >= start) & (update_times <= end)])
        gaps = np.diff(np.concatenate([[start], inside, [end]]))
        duration += end - start
        missed += float(np.sum(gaps[gaps > (1.0 + settings.miss_tolerance_scans) * interval] - interval))
        long_missed += float(np.sum(gaps[gaps > settings.long_gap_scans * interval * (1.0 + ROUNDING)] - interval))
    return duration, missed, long_missed


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else float("nan")


def _share(passed: np.ndarray) -> float:
    return float(np.mean(passed)) if len(passed) else float("nan")


@dataclass(frozen=True)
class Parts:
    """What one recording (one of the bench's units) adds to a scorecard: per scored update (S,) its
    horizontal position error's distance and its along- and across-track parts (m), its velocity error (m/s,
    NaN where the track gives none) and whether the target was manoeuvring; per target in coverage with a
    track, its tracks and initiation time (s); and the sums behind the ratios. `combined` pools any number."""

    distance: np.ndarray
    along: np.ndarray
    across: np.ndarray
    velocity_miss: np.ndarray
    manoeuvring: np.ndarray
    tracks_per_target: np.ndarray
    initiation_s: np.ndarray
    duration_s: float
    missed_s: float
    long_missed_s: float
    confirmed_updates: int
    false_updates: int
    targets: int
    targets_never_tracked: int
    confirmed_tracks: int
    false_tracks: int
    swaps: int


def parts(updates: TrackUpdates, truth: Truth, settings: Settings) -> Parts:
    """The scorecard's parts of one recording (module docstring). A recording with no target in coverage (a
    bench route flown wholly outside the radar's coverage) adds its confirmed tracks and their errors, no time."""
    confirmed = np.flatnonzero(updates.confirmed)
    confirmed = confirmed[np.argsort(updates.time_s[confirmed], kind="stable")]  # each track's updates in time order
    scored = TrackUpdates(updates.track_id[confirmed], updates.time_s[confirmed], updates.position[confirmed],
                          updates.velocity[confirmed], updates.confirmed[confirmed])
    trajectories = _Trajectories(truth)
    nearest = _associated(scored, trajectories, settings)
    targets_of = _track_targets(scored.track_id, nearest)
    target = np.array([targets_of[t] for t in scored.track_id.tolist()], dtype=np.int64)
    in_span = np.zeros(len(target), dtype=bool)
    for t in np.unique(target[target >= 0]).tolist():
        in_span[target == t] = trajectories.spanning(t, scored.time_s[target == t])
    rows = np.flatnonzero(in_span)  # a track's updates within its target's truth
    position_error, velocity_error, true_velocity, manoeuvring = (np.empty((len(rows), 2)), np.full((len(rows), 2), np.nan),
                                                                  np.empty((len(rows), 2)), np.empty(len(rows), bool))
    for t in np.unique(target[rows]).tolist():
        mine = target[rows] == t
        times = scored.time_s[rows[mine]]
        truth_position = trajectories.at(t, times)
        frames = _frames(truth_position)
        position_error[mine] = _horizontal(scored.position[rows[mine]] - truth_position, frames)
        true_velocity[mine] = _horizontal(trajectories.at(t, times, 1), frames)
        velocity_error[mine] = _horizontal(scored.velocity[rows[mine]], frames) - true_velocity[mine]
        manoeuvring[mine] = np.linalg.norm(_horizontal(trajectories.at(t, times, 2), frames), axis=1) \
            > settings.manoeuvre_mps2
    speed = np.linalg.norm(true_velocity, axis=1)
    along_unit = np.divide(true_velocity, speed[:, None], out=np.zeros_like(true_velocity), where=speed[:, None] > 0)

    covered = [t for t in trajectories.targets.tolist() if truth.in_coverage[truth.target_id == t].any()]
    duration = missed = long_missed = 0.0
    initiation, tracks_per_target, never = [], [], 0
    for t in covered:
        periods = _periods(truth, t, settings.update_interval_s)
        own = target == t
        dt, mt, long_mt = gap_times(periods, scored.time_s[own], settings)
        duration, missed, long_missed = duration + dt, missed + mt, long_missed + long_mt
        tracks = [track for track, of in targets_of.items() if of == t]
        if not tracks:
            never += 1
            continue
        tracks_per_target.append(len(tracks))
        initiation.append(float(scored.time_s[own].min()) - periods[0][0])
    return Parts(np.linalg.norm(position_error, axis=1), np.sum(position_error * along_unit, axis=1),
                 along_unit[:, 0] * position_error[:, 1] - along_unit[:, 1] * position_error[:, 0],
                 np.where(np.isfinite(velocity_error).all(axis=1), np.linalg.norm(velocity_error, axis=1), np.nan),
                 manoeuvring, np.array(tracks_per_target, dtype=np.int64), np.array(initiation), duration, missed,
                 long_missed, int(len(scored.time_s)), int(np.count_nonzero(target < 0)), len(covered), never,
                 len(targets_of), sum(1 for of in targets_of.values() if of < 0), _swaps(scored.track_id, nearest))


def combined(pieces: list[Parts]) -> dict[str, float]:
    """The indicators of the module docstring, by name (metres, seconds, m/s, shares in [0, 1]; NaN where
    nothing was there to measure), over the recordings whose `parts` are `pieces`: every update and target of
    them pooled, as one recording of them all would be scored."""
    joined = {name: np.concatenate([getattr(piece, name) for piece in pieces]) for name in
              ("distance", "along", "across", "velocity_miss", "manoeuvring", "tracks_per_target", "initiation_s")}
    total = {name: sum(getattr(piece, name) for piece in pieces) for name in
             ("duration_s", "missed_s", "long_missed_s", "confirmed_updates", "false_updates", "targets",
              "targets_never_tracked", "confirmed_tracks", "false_tracks", "swaps")}
    distance, manoeuvring, velocity = joined["distance"], joined["manoeuvring"], joined["velocity_miss"]
    known = np.isfinite(velocity)
    per_target, initiation = joined["tracks_per_target"], joined["initiation_s"]
    with_target = total["confirmed_tracks"] - total["false_tracks"]
    duration = total["duration_s"]
    return {
        "confirmed_updates": total["confirmed_updates"], "scored_updates": int(len(distance)),
        "targets": total["targets"], "targets_never_tracked": total["targets_never_tracked"],
        "confirmed_tracks": total["confirmed_tracks"], "false_tracks": total["false_tracks"],
        "false_update_ratio": (total["false_updates"] / total["confirmed_updates"] if total["confirmed_updates"]
                               else float("nan")),
        "probability_of_update": 1.0 - total["missed_s"] / duration if duration else float("nan"),
        "ratio_of_long_gaps": total["long_missed_s"] / duration if duration else float("nan"),
        "position_error_mean_m": float(distance.mean()) if len(distance) else float("nan"),
        "position_error_sigma_m": float(distance.std()) if len(distance) else float("nan"),
        "position_rms_m": _rms(distance), "along_track_rms_m": _rms(joined["along"]),
        "across_track_rms_m": _rms(joined["across"]),
        "along_track_mean_m": float(joined["along"].mean()) if len(distance) else float("nan"),
        "velocity_rms_straight_mps": _rms(velocity[known & ~manoeuvring]),
        "velocity_rms_manoeuvring_mps": _rms(velocity[known & manoeuvring]),
        "straight_updates": int(np.count_nonzero(~manoeuvring)), "manoeuvring_updates": int(np.count_nonzero(manoeuvring)),
        "straight_within_0_25_nm": _share(distance[~manoeuvring] <= 0.25 * NAUTICAL_MILE_M),
        "manoeuvring_within_1_nm": _share(distance[manoeuvring] <= NAUTICAL_MILE_M),
        "tracks_per_aircraft": float(per_target.mean()) if len(per_target) else float("nan"),
        "extra_track_ratio": float(np.sum(per_target - 1)) / with_target if with_target else float("nan"),
        "track_swaps": total["swaps"],
        "initiation_mean_s": float(initiation.mean()) if len(initiation) else float("nan"),
        "initiation_p95_s": float(np.percentile(initiation, 95)) if len(initiation) else float("nan"),
    }


def scorecard(updates: TrackUpdates, truth: Truth, settings: Settings) -> dict[str, float]:
    """The indicators of one recording: `combined` of its `parts`. Raises ValueError for a truth without a
    target in coverage: nothing to score against."""
    if not truth.in_coverage.any():
        raise ValueError("the truth has no target in coverage: nothing to score against")
    return combined([parts(updates, truth, settings)])


def _swaps(track_id: np.ndarray, nearest: np.ndarray) -> int:
    """Changes of target between consecutive associated updates of a track (updates in time order per track)."""
    swaps = 0
    for track in np.unique(track_id).tolist():
        went = nearest[(track_id == track) & (nearest >= 0)]
        swaps += int(np.count_nonzero(went[1:] != went[:-1]))
    return swaps


def judged(card: dict[str, float]) -> list[dict]:
    """Each reference figure (REFERENCES) beside the card's value: figure set, indicator, value, reference,
    source and whether it passes (None where the value is NaN)."""
    rows = []
    for figures, reference in REFERENCES:
        value = card[reference.indicator]
        passes = None if not np.isfinite(value) else (value <= reference.value if reference.at_most
                                                       else value >= reference.value)
        rows.append({"figures": figures, "indicator": reference.indicator, "value": value,
                     "reference": reference.value, "at_most": reference.at_most, "source": reference.source,
                     "passes": passes})
    return rows

"""Stone Soup (dstl/Stone-Soup 1.9.1, the field's open tracking framework) as a peer tracker on our plots.

Set up as its tutorials build a tracker (`MultiTargetTracker`'s loop, written out for JPDA as its JPDA
tutorial does): a Kalman predictor and updater, a
Mahalanobis-distance hypothesiser with a gate, an association (global nearest neighbour,
`GNNWith2DAssignment`, or joint probabilistic data association with efficient hypothesis management,
`JPDAwithEHM`, its updates the Gaussian mixture of a track's hypotheses, `PDAUpdater`), an initiator that confirms a track at `min_points` updates (`MultiMeasurementInitiator`)
and a deleter that ends a track silent for `delete_after_s` (`UpdateTimeDeleter`). What it is given is ours,
so that the comparison is of the association and track management alone:

- The plots as our tracker takes them: each plot's ECEF position with its converted-measurement covariance
  (`pipeline.recordings.plot_table`, thesis section 4.2) as a `Detection` of a linear Gaussian measurement of
  the position (its own model, its own covariance), at its own time.
- The motion model of our tuned CV filter (`motion_models` "cv": discrete white-noise acceleration, the
  tuned process noise; Stone Soup's own `ConstantVelocity` is the continuous-time model, another
  covariance), and its start spread for a new track's velocity.
- The plots in batches of `batch_window_s` (0.05 s: 3 degrees of a 10 rpm antenna), each batch's plots at
  its mean time (at most 7.5 m off for an aircraft at 300 m/s, against plot errors of hundreds of metres).
  Stone Soup associates and updates a batch at one time (its PDA updater gives the mixture the missed
  detection's time); the plots of one antenna scan are seconds apart, but the plots that compete for a
  track, near each other, come within a few hundredths of a second of each other.

Stone Soup shows a track only once confirmed, with the states of its initiation in it: those first
`min_points - 1` updates are given back as not confirmed, as our tracker marks a track's first updates, so
both are scored on what a controller would have seen.

Stone Soup is a pinned dependency of the bench, but a user's environment may lack it: `missing` says so (the
bench then skips its runs with that message rather than stopping on an import error).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from datetime import datetime, timedelta

import numpy as np
from scipy.stats import chi2

from pipeline.filters import motion_models
from pipeline.filters.classical_filters import FilterSettings
from pipeline.params import StoneSoupPeer
from pipeline.recordings.plot_table import Plots

EPOCH = datetime(1970, 1, 1)  # Stone Soup's times are datetimes: Unix seconds from here (microseconds)
ASSOCIATIONS = ("gnn", "jpda")



PACKAGE = "stonesoup"  # its import name; on PyPI `stonesoup`, pinned in pyproject.toml


def missing() -> str | None:
    """Why Stone Soup's runs cannot run here (the package not installed, with the command that installs the
    pinned version), or None when it can be imported."""
    if importlib.util.find_spec(PACKAGE) is not None:
        return None
    return ("Stone Soup is not installed in this environment (`pip install -c constraints.txt stonesoup`, or "
            "`make env`): its peer runs are skipped")

@dataclass(frozen=True)
class StoneSoupSettings:
    """A Stone Soup tracker's set-up (module docstring); `from_params` builds it from params' `peers.stone_soup`."""

    association: str                  # "gnn" (GNNWith2DAssignment) or "jpda" (JPDAwithEHM)
    noise_std: float                  # the CV model's white-noise acceleration, m/s^2 (our tuned CV's)
    velocity_std_mps: float           # a new track's velocity spread (our tuned CV's)
    gate_probability: float           # the chi-square gate's probability (3 degrees of freedom; ours)
    min_points: int                   # updates to confirm a track (the tutorials' 3-point initiation)
    delete_after_s: float             # a track silent this long is deleted
    batch_window_s: float             # plots this close in time are one batch, at one time (module docstring)
    detection_probability: float      # JPDA's P_d
    clutter_density: float            # JPDA's clutter spatial density, per m^3

    def __post_init__(self) -> None:
        if self.association not in ASSOCIATIONS:
            raise ValueError(f"Stone Soup association {self.association!r}: must be one of {ASSOCIATIONS}")

    @property
    def gate_distance(self) -> float:
        """The Mahalanobis distance of the gate (Stone Soup's measure is the distance, not its square)."""
        return float(np.sqrt(chi2.ppf(self.gate_probability, 3)))

    @classmethod
    def from_params(cls, association: str, peer: StoneSoupPeer, cv: FilterSettings,
                    gate_probability: float) -> StoneSoupSettings:
        """The set-up of `association` from params' `peers.stone_soup`, our tuned CV filter's settings `cv` and our
        gate's probability (`tracker.association.kalman_gate_probability`)."""
        return cls(association, float(cv.noise_std[0]), float(cv.velocity_std_mps), gate_probability,
                   peer.min_points, peer.delete_after_s, peer.batch_window_s, peer.detection_probability,
                   peer.clutter_density_per_m3)


def _transition_model(noise_std: float):
    """Our CV model (`motion_models`) as a Stone Soup linear Gaussian transition model."""
    from stonesoup.base import Property
    from stonesoup.models.base import TimeVariantModel
    from stonesoup.models.transition.linear import LinearGaussianTransitionModel

    class TunedConstantVelocity(LinearGaussianTransitionModel, TimeVariantModel):
        """Constant velocity with discrete white-noise acceleration (pipeline.filters.motion_models "cv")."""

        noise_std: float = Property(doc="white-noise acceleration standard deviation, m/s^2")

        @property
        def ndim_state(self) -> int:
            return 6

        def matrix(self, time_interval: timedelta, **kwargs) -> np.ndarray:
            return motion_models.transition("cv", time_interval.total_seconds())

        def covar(self, time_interval: timedelta, **kwargs) -> np.ndarray:
            return motion_models.process_noise("cv", time_interval.total_seconds(), self.noise_std)

    return TunedConstantVelocity(noise_std=noise_std)


def track_with_stone_soup(plots: Plots, settings: StoneSoupSettings) -> dict[str, np.ndarray]:
    """Track `plots` (one scenario, time order) with Stone Soup: one row per update of a track, as our update
    table (`pipeline.tracker.updates.COLUMNS`: track id, time, plot id, radar id, ECEF position, the position's
    covariance) with `confirmed` (U,) bool (False for the updates before the track's confirmation) and
    `velocity` (U, 3) m/s; rows in track id order, each track's in time order."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator.probability import JPDAwithEHM
    from stonesoup.deleter.time import UpdateTimeDeleter
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import KalmanUpdater
    from stonesoup.updater.probability import PDAUpdater

    predictor = KalmanPredictor(_transition_model(settings.noise_std))
    updater = KalmanUpdater(measurement_model=None)
    distance = DistanceHypothesiser(predictor, updater, measure=Mahalanobis(), missed_distance=settings.gate_distance)
    if settings.association == "gnn":
        associator, track_updater = GNNWith2DAssignment(distance), updater
    else:  # the tracks' update is the mixture of a track's hypotheses (Stone Soup's PDAUpdater)
        associator = JPDAwithEHM(PDAHypothesiser(predictor, updater, settings.clutter_density,
                                                 prob_detect=settings.detection_probability,
                                                 prob_gate=settings.gate_probability))
        track_updater = PDAUpdater(measurement_model=None, gm_method=True)  # each plot with its own covariance
    deleter = UpdateTimeDeleter(timedelta(seconds=settings.delete_after_s))
    prior = GaussianState(np.zeros((6, 1)), np.diag([0.0, settings.velocity_std_mps ** 2] * 3))
    initiator = MultiMeasurementInitiator(prior, deleter, GNNWith2DAssignment(distance), updater,
                                          min_points=settings.min_points)
    bounds = batches(plots.time, settings.batch_window_s)

    def scans():
        for begin, end in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
            when = _when(float(np.mean(plots.time[begin:end])))
            yield when, {Detection(plots.position[row].reshape(3, 1), timestamp=when, metadata={"row": row},
                                   measurement_model=LinearGaussian(ndim_state=6, mapping=(0, 2, 4),
                                                                    noise_covar=plots.covariance[row]))
                         for row in range(begin, end)}

    seen, tracks = {}, set()
    for time, detections in scans():  # MultiTargetTracker's loop, which JPDA's hypotheses need written out
        associated = set()
        for track, hypothesis in associator.associate(tracks, detections, time).items():
            singles = getattr(hypothesis, "single_hypotheses", [hypothesis])  # JPDA's: the missed detection's first
            if any(singles):  # GNN: its detection; JPDA: some detection in its gate
                track.append(track_updater.update(hypothesis))
                associated |= {single.measurement for single in singles if single}
            else:  # no detection: the prediction, so the deleter sees no update (JPDA's mixture of the missed
                track.append(singles[0].prediction)  # detection alone would count as one, and a track never end)
        tracks -= deleter.delete_tracks(tracks)
        started = initiator.initiate(detections - associated, time)
        tracks |= started
        seen.update((track.id, track) for track in started)
    updated = {track_id: [(row, state) for state in track.states if hasattr(state, "hypothesis")
                          for row in [_measurement_row(state.hypothesis)] if row is not None]
               for track_id, track in seen.items()}
    rows = []  # tracks numbered in the order of their first plot (Stone Soup's ids are random UUIDs)
    for number, updates in enumerate(sorted((u for u in updated.values() if u), key=lambda u: u[0][0])):
        for k, (row, state) in enumerate(updates):
            rows.append((number, row, k >= settings.min_points - 1,
                         np.asarray(state.state_vector, dtype=float).reshape(6), np.asarray(state.covar, dtype=float)))
    return _table(plots, rows)


def batches(times_s: np.ndarray, window_s: float) -> np.ndarray:
    """Bounds (B + 1,) of the runs of plots (time order) each within `window_s` of its run's first plot."""
    bounds, start = [0], 0
    for row in range(1, len(times_s)):
        if times_s[row] - times_s[start] > window_s:
            bounds.append(row)
            start = row
    return np.array(bounds + [len(times_s)] if len(times_s) else [0], dtype=np.int64)


def _when(unix_s: float) -> datetime:
    return EPOCH + timedelta(seconds=float(unix_s))


def _measurement_row(hypothesis) -> int | None:
    """The plot row of an update's detection (JPDA's hypothesis: its most probable single hypothesis), or None
    for an update on no detection (a missed detection's prediction in JPDA)."""
    single = getattr(hypothesis, "single_hypotheses", None)
    if single is not None:
        hypothesis = max(single, key=lambda h: float(h.probability))
    measurement = getattr(hypothesis, "measurement", None)
    return None if measurement is None or not hasattr(measurement, "metadata") else measurement.metadata.get("row")


def _table(plots: Plots, rows: list) -> dict[str, np.ndarray]:
    position_index, velocity_index = motion_models.measured_indices("cv"), motion_models.velocity_indices("cv")
    count = len(rows)
    plot_rows = np.array([row for _, row, *_ in rows], dtype=np.int64)
    states = np.array([state for *_, state, _ in rows]).reshape(count, 6)
    covariances = np.array([covariance for *_, covariance in rows]).reshape(count, 6, 6)
    return {"track_id": np.array([number for number, *_ in rows], dtype=np.int64),
            "time_unix_s": plots.time[plot_rows], "plot_id": plots.plot_id[plot_rows],
            "radar_id": plots.radar_id[plot_rows], "x_ecef_m": states[:, position_index[0]],
            "y_ecef_m": states[:, position_index[1]], "z_ecef_m": states[:, position_index[2]],
            "position_covariance": covariances[:, position_index][:, :, position_index],
            "velocity": states[:, velocity_index],
            "confirmed": np.array([confirmed for _, _, confirmed, *_ in rows], dtype=bool)}

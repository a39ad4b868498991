"""Role: the gate (Stone Soup's hypothesiser), and the gates that need no network.

A gate scores the candidate tracks of one plot in a single batch: `gate(tracks, slots, row,
prediction)` gives, for the tracks at `slots` (K,) and plot `row` of `tracks.plots`, a
*normalised* association error per track (the distance, or reconstruction error, divided by
the gate's size; infinite outside the gate) and the prediction the update should resume from.
Normalising makes the errors of young tracks (gated by the constant radius, in metres) and of
mature tracks (gated by a prediction window, a variable window, a chi-square bound or an
autoencoder threshold) comparable, which the thesis's rule "lowest association error wins"
needs but does not spell out.

A gate with `uses_prediction` set is given the estimator's prediction of the candidates at the
plot's time, made once by the loop (and handed to the update as well); the others get None.
A gate with `pairwise` set also takes `row` as an array (K,), a plot per track: the loop then
scores the (track, plot) pairs of a whole antenna scan in one call (`pipeline.tracker.run`).
A gate declares, as an estimator does (`pipeline.tracker.estimator`), how many of a track's latest
plots it reads in `latest_plots` (the autoencoder's window; 0 for the gates here).

- `RadiusGate` (`radius`, and every method's young tracks): distance from the track's last
  plot, within a constant radius.
- `WindowGate` (`via`): distance from the predicted position, within a constant window.
- `ChiSquareGate` (the classical methods): Mahalanobis distance d^2 = y' S^-1 y of the plot from
  the predicted position, S the predicted position covariance plus the plot's measurement
  covariance, within the chi-square quantile of the gate probability (3 degrees of freedom:
  the validation gate of Bar-Shalom, Li and Kirubarajan, "Estimation with Applications to
  Tracking and Navigation", 2001, section 5.4.2); the error is d^2 / quantile.
- `AcceptAll` (the oracle, whose assigner uses the truth): every track, error 0.
- `RadiusFloorGate` (`lstm_update`'s young tracks under `tracker.lstm_update.young_window_fallback`,
  issue 27): a learned gate that also accepts what `RadiusGate` accepts, so it is never narrower
  than the young-track radius of every other method.

The gates that run networks (`mia`, `ae`) are in `pipeline.tracker.network_gates`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np
from scipy.stats import chi2

from pipeline.filters.batch_filters import inverse3
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.tracks import LiveTracks


class Scores(NamedTuple):
    """Normalised errors (K,) (inf outside the gate) and the prediction the update resumes from
    (the loop's, the gate's own, or None)."""

    errors: np.ndarray
    prediction: Prediction | None


class Gate(Protocol):
    uses_prediction: bool
    pairwise: bool
    latest_plots: int

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int, prediction: Prediction | None
                 ) -> Scores: ...


def within(distance: np.ndarray, size: float | np.ndarray) -> np.ndarray:
    """Normalised errors: distance / size inside the gate (distance < size), inf outside."""
    return np.where(distance < size, distance / size, np.inf)


@dataclass(frozen=True)
class RadiusGate:
    """Distance (m) from each track's last plot, within `radius_m`."""

    radius_m: float
    uses_prediction = False
    pairwise = True
    latest_plots = 0

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int, prediction: Prediction | None) -> Scores:
        distance = np.linalg.norm(tracks.last_plot[slots] - tracks.plots.position[row], axis=1)
        return Scores(within(distance, self.radius_m), None)


@dataclass(frozen=True)
class WindowGate:
    """VIA: distance (m) from each track's predicted position, within `window_m`."""

    window_m: float
    uses_prediction = True
    pairwise = True
    latest_plots = 0

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int, prediction: Prediction | None) -> Scores:
        distance = np.linalg.norm(prediction.positions - tracks.plots.position[row], axis=1)
        return Scores(within(distance, self.window_m), prediction)


class ChiSquareGate:
    """Chi-square gate on the Mahalanobis distance of the plot from each track's prediction, which
    must carry covariances; `probability` is the share of true plots it lets through."""

    uses_prediction = True
    pairwise = True
    latest_plots = 0

    def __init__(self, probability: float) -> None:
        self.threshold = float(chi2.ppf(probability, df=3))

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int, prediction: Prediction | None) -> Scores:
        """The errors, and the prediction with the inverse innovation covariances it gated with (for
        the update, `Prediction.innovation_inverse`)."""
        innovation = tracks.plots.position[row] - prediction.positions
        inverse, _ = inverse3(prediction.covariances + tracks.plots.covariance[row])
        distance = np.einsum("ni,nij,nj->n", innovation, inverse, innovation)
        return Scores(within(distance, self.threshold), Prediction(prediction.positions, prediction.covariances,
                                                                   prediction.state, inverse))


class BoundedChiSquareGate(ChiSquareGate):
    """The chi-square gate, and the plot within `window_m` of the prediction: for an estimator whose
    covariance can grow without bound on input unlike its training material (the LSTM update's
    MC-dropout spread on a track fed clutter, issue 18: such a gate took plots ever further off, and
    clutter tracks ran 170-310 km from any aircraft)."""

    def __init__(self, probability: float, window_m: float) -> None:
        super().__init__(probability)
        self.window_m = window_m

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int, prediction: Prediction | None) -> Scores:
        scores = super().__call__(tracks, slots, row, prediction)
        far = np.linalg.norm(tracks.plots.position[row] - prediction.positions, axis=1) >= self.window_m
        return Scores(np.where(far, np.inf, scores.errors), scores.prediction)


class RadiusFloorGate:
    """A pair is accepted when the `learned` gate or `RadiusGate(radius_m)` accepts it (issue 27: a learned
    gate refuses plots unlike its training, e.g. a target faster than any it saw, and then every plot
    starts its own track). The error is the smaller of the two, the radius's on the chi-square's scale:
    (distance / radius)^2, what d^2 / quantile is for an isotropic Gaussian innovation whose gate is
    that ball, so that a pair the radius alone takes compares with the learned gate's pairs as one
    gate's would (the learned gates here are chi-square gates; Bar-Shalom et al. 2001, 5.4.2). The
    prediction is the learned gate's (the update resumes from it, whichever test accepted)."""

    def __init__(self, learned: Gate, radius_m: float) -> None:
        self.learned, self.radius_m = learned, radius_m
        self.uses_prediction, self.pairwise = learned.uses_prediction, learned.pairwise
        self.latest_plots = learned.latest_plots

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int | np.ndarray, prediction: Prediction | None
                 ) -> Scores:
        scores = self.learned(tracks, slots, row, prediction)
        distance = np.linalg.norm(tracks.last_plot[slots] - tracks.plots.position[row], axis=1)
        return Scores(np.minimum(scores.errors, within(distance, self.radius_m) ** 2), scores.prediction)


class AcceptAll:
    """No gating: every candidate track, error 0 (for an assigner that decides by other means)."""

    uses_prediction = False
    pairwise = True
    latest_plots = 0

    def __call__(self, tracks: LiveTracks, slots: np.ndarray, row: int, prediction: Prediction | None) -> Scores:
        return Scores(np.zeros(len(slots)), None)

"""The learned track confirmation's network (issue 34): a score in [0, 1] per association of a candidate track,
how much the association looks like an aircraft's next plot, from its evidence (`pipeline.tracker.management`'s
`Evidence`: error, gap in scans, plots so far, speed).

The thesis's autoencoder was a first try at telling an aircraft's track from clutter's by its plots; here the
telling is done where track management decides, association by association, so that the learned rule
(`pipeline.tracker.learned_confirmation.LearnedConfirmation`) weighs each hit of M-of-N by it.

- **Features** (`features`, (N, 5)): the gate's normalised error (in [0, 1)); log(1 + the gap in scans); the
  track's plots so far, at most `PLOTS_CAP`, over `PLOTS_CAP`; the horizontal speed of the two plots over
  `SPEED_SCALE_MPS`, at most `SPEED_CAP`; log(1 + their vertical speed, at most `CLIMB_CAP_MPS`, /
  `CLIMB_SCALE_MPS`) (clutter's pairs imply any speed and climb, an aircraft's those of aircraft; two plots at one
  time, infinite ones).
- **Network** (`HitScorer`): two tanh layers of `hidden` units and a logit; trained by binary cross-entropy on
  the associations of candidate tracks (label: the plot is an aircraft's and the track's previous plot the same
  aircraft's; the material `pipeline.bench.confirmation_training`, the Lightning task
  `pipeline.learning.confirmation_fit`).
- **At tracking time** (`Scorer`): the weights as NumPy arrays, one association at a time (a tentative track's
  association is a few microseconds; confirmed tracks are not scored), and the hold-out's clutter tracks'
  highest window sums, from which `tracker.management.learned_false_track_probability` sets the threshold
  (`pipeline.tracker.learned_confirmation.threshold_for`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from torch import Tensor, nn

from pipeline import io
from pipeline.learning import model_store

STAGE = "train_confirmation"
PLOTS_CAP = 8               # the track's plots so far count up to this
SPEED_SCALE_MPS = 300.0     # the speed feature's unit
SPEED_CAP = 4.0             # ... at most this many of them (1,200 m/s: faster than any aircraft here)
CLIMB_SCALE_MPS = 30.0      # the vertical speed's unit, under a log ...
CLIMB_CAP_MPS = 3000.0      # ... at most this (two plots at one time: infinite speeds)
FEATURES = 5


def features(error: np.ndarray, gap_scans: np.ndarray, plots: np.ndarray, speed_mps: np.ndarray,
             climb_mps: np.ndarray) -> np.ndarray:
    """The network's inputs (N, 5) of N associations' evidence (each (N,); module docstring)."""
    return np.column_stack([np.clip(np.nan_to_num(np.asarray(error, dtype=float), posinf=1.0), 0.0, 1.0),
                            np.log1p(np.maximum(np.asarray(gap_scans, dtype=float), 0.0)),
                            np.minimum(np.asarray(plots, dtype=float), PLOTS_CAP) / PLOTS_CAP,
                            np.minimum(np.asarray(speed_mps, dtype=float) / SPEED_SCALE_MPS, SPEED_CAP),
                            np.log1p(np.minimum(np.abs(np.asarray(climb_mps, dtype=float)), CLIMB_CAP_MPS)
                                     / CLIMB_SCALE_MPS)])


@dataclass(frozen=True)
class ConfirmationConfig:
    hidden: int


class HitScorer(nn.Module):
    """Features (N, 5) -> logits (N,) of "an aircraft's next plot" (module docstring)."""

    def __init__(self, config: ConfirmationConfig) -> None:
        super().__init__()
        self.config = config
        self.layers = nn.Sequential(nn.Linear(FEATURES, config.hidden), nn.Tanh(), nn.Linear(config.hidden, config.hidden),
                                    nn.Tanh(), nn.Linear(config.hidden, 1))

    def forward(self, inputs: Tensor) -> Tensor:
        return self.layers(inputs).squeeze(-1)


class Scorer:
    """A trained `HitScorer` as NumPy arrays: `scores(features)` (N,) and `__call__(evidence)` (one association's
    score, what `LearnedConfirmation` asks), the same numbers as the network's to float64 rounding (test)."""

    def __init__(self, network: HitScorer) -> None:
        linear = [layer for layer in network.layers if isinstance(layer, nn.Linear)]
        self._weights = [layer.weight.detach().double().numpy().copy() for layer in linear]
        self._biases = [layer.bias.detach().double().numpy().copy() for layer in linear]

    def logits(self, inputs: np.ndarray) -> np.ndarray:
        h = np.asarray(inputs, dtype=float)
        for k, (weight, bias) in enumerate(zip(self._weights, self._biases)):
            h = h @ weight.T + bias
            if k < len(self._weights) - 1:
                h = np.tanh(h)
        return h[:, 0]

    def scores(self, inputs: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-self.logits(inputs)))

    def __call__(self, evidence: tuple[float, float, int, float, float]) -> float:
        """One association's score from its evidence (error, gap in scans, plots so far, horizontal and vertical
        speed in m/s): `scores` of its `features`, in scalar arithmetic (a few microseconds)."""
        error, gap, plots, speed, climb = evidence
        h = np.array([min(max(error, 0.0), 1.0) if math.isfinite(error) else 1.0, math.log1p(max(gap, 0.0)),
                      min(plots, PLOTS_CAP) / PLOTS_CAP, min(speed / SPEED_SCALE_MPS, SPEED_CAP),
                      math.log1p(min(abs(climb), CLIMB_CAP_MPS) / CLIMB_SCALE_MPS)])
        for k, (weight, bias) in enumerate(zip(self._weights, self._biases)):
            h = weight @ h + bias
            if k < len(self._weights) - 1:
                h = np.tanh(h)
        return float(1.0 / (1.0 + math.exp(-float(h[0]))))


@dataclass(frozen=True)
class TrainedConfirmation:
    """The `confirmation` piece the tracker loads: the scorer, the window the hold-out's sums were taken over
    (`confirm_n` at training) and the hold-out's clutter tracks' highest window sums (levels)."""

    scorer: Scorer
    window: int
    clutter_maxima: np.ndarray


def load(path: Path) -> TrainedConfirmation:
    """The train_confirmation stage's bundle; InputError naming the file when it is missing, foreign or lacks the
    hold-out's clutter sums (`model_store.load_network`)."""
    network = model_store.load_network(path, lambda config: HitScorer(ConfirmationConfig(**config)), STAGE)
    extras = model_store.read_bundle(path).get("extras", {})
    if "clutter_maxima" not in extras or "window" not in extras:
        raise io.InputError(f"{path}: no hold-out clutter sums in the bundle; make it again with `dvc repro {STAGE}`")
    return TrainedConfirmation(Scorer(network), int(extras["window"]), np.asarray(extras["clutter_maxima"], dtype=np.int64))

"""The classical filters of the tracker, defined with filterpy: a CV or CA Kalman filter, or an IMM.

`FilterSettings` is everything that defines one (its motion models, their process noise and
the spread of a new track's velocity); the tuner chooses these values and saves them in
`models/kalman_tuned.json`, the tracker loads them.

The filterpy objects built here are the reference: the tuner, the comparison and the tracker
(`pipeline.tracker.kalman`) run the same equations on NumPy arrays in the one Kalman core
(`pipeline.filters.batch_filters`), which the tests check against these objects step by step. A filter
is started at one plot (`start_filter`); `advance` steps it to a plot's time and
`predicted_gaussian` gives the prediction at any time without changing it (what gating needs).

Two IMMs, each filterpy's `IMMEstimator` over models in one 9-entry state (see
`pipeline.filters.motion_models`):
- `imm`: a constant-velocity and a constant-acceleration model;
- `imm_ct` (issue 33): a constant-velocity model and two coordinated turns of a known rate, one each way
  (`pipeline.filters.turn_model`), the classical IMM for manoeuvring aircraft (Bar-Shalom, Li &
  Kirubarajan 2001, 11.7.3: CV with left and right turns of a design rate). The turns share one process
  noise and their rate is tuned.
- `imm_ca_ct` (issue 33): the same with the constant-acceleration model too, for the speed changes and
  climbs a turn model does not follow (measured beside `imm_ct`: the comparison has both).
A turning model's transition depends on the track's vertical, so it is made per track at each step
(`turn_transition`); its process noise is `cv9`'s.

The IMM's prediction for gating mixes the models with the predicted mode probabilities (c-bar),
which is the IMM's own predicted density; filterpy's `x_prior` weights them with the last posterior
ones instead. A track switches from a model to each other one with the same probability.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
from filterpy.kalman import IMMEstimator, KalmanFilter

from pipeline.filters import motion_models, turn_model
from pipeline.io import InputError
from pipeline.params.learning import FILTER_KINDS as KINDS
from pipeline.params.learning import REQUIRED_FILTERS
TURN = "ct"  # a coordinated turn of the kind's turn rate, alternately left and right (`turn_model`)
MODELS = {"cv": ("cv",), "ca": ("ca",), "imm": ("cv9", "ca"), "imm_ct": ("cv9", TURN, TURN),
          "imm_ca_ct": ("cv9", "ca", TURN, TURN)}
NOISE_VALUES = {kind: len(dict.fromkeys(models)) for kind, models in MODELS.items()}  # the turns share one
TURNING_KINDS = tuple(kind for kind, models in MODELS.items() if TURN in models)


@dataclass(frozen=True)
class FilterSettings:
    """One classical filter. `noise_std` has one entry per motion model of the kind (cv: acceleration m/s^2;
    ca: acceleration increments m/s^3; imm: both, in that order), except the two turns, which share one
    (white acceleration, m/s^2, after the others: `imm_ct` CV then turns, `imm_ca_ct` CV, CA, turns).
    `turn_rate_dps`: the turns' rate, deg/s (0 for a kind without turns)."""

    kind: str
    noise_std: tuple[float, ...]
    velocity_std_mps: float          # spread of a new track's unknown velocity
    acceleration_std_mps2: float     # spread of a new track's unknown acceleration (ca, imm)
    switch_probability: float        # imm: probability of changing model between two updates
    initial_cv_probability: float    # imm: probability of the CV model for a new track
    turn_rate_dps: float = 0.0       # imm_ct: the turns' rate (each way), deg/s

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"filter kind {self.kind!r}: must be one of {KINDS}")
        if len(self.noise_std) != NOISE_VALUES[self.kind]:
            raise ValueError(f"{self.kind}: needs {NOISE_VALUES[self.kind]} process-noise values, got {self.noise_std}")
        if (self.kind in TURNING_KINDS) != (self.turn_rate_dps > 0.0):
            raise ValueError(f"{self.kind}: turn_rate_dps = {self.turn_rate_dps}: must be above 0 exactly for the "
                             f"kinds with turns {TURNING_KINDS}")

    @property
    def models(self) -> tuple[str, ...]:
        return MODELS[self.kind]

    @property
    def is_imm(self) -> bool:
        return len(self.models) > 1

    @property
    def motion_bases(self) -> tuple[str, ...]:
        """Each model's motion model before its turn (`motion_models`): a turn's is `cv9`, the turn itself
        added per track (`turn_rates`)."""
        return tuple("cv9" if model == TURN else model for model in self.models)

    @property
    def model_noise_std(self) -> tuple[float, ...]:
        """Each model's process noise: `noise_std`, the turns' one value (the last) repeated for each turn."""
        return tuple(self.noise_std[min(index, len(self.noise_std) - 1)] for index in range(len(self.models)))

    def turn_rates(self) -> np.ndarray:
        """Each model's turn rate (M,) rad/s, positive counter-clockwise seen from above: 0 but for the turns,
        left then right."""
        rate, rates, sign = np.radians(self.turn_rate_dps), np.zeros(len(self.models)), 1.0
        for index, model in enumerate(self.models):
            if model == TURN:
                rates[index], sign = sign * rate, -sign
        return rates

    @property
    def measured(self) -> list[int]:
        return motion_models.measured_indices(self.models[0])

    def transition_probabilities(self) -> np.ndarray:
        """The IMM's Markov matrix (M, M): stay with 1 - switch_probability, move to each other model with
        an equal share of it."""
        switch, count = self.switch_probability, len(self.models)
        matrix = np.full((count, count), switch / (count - 1))
        np.fill_diagonal(matrix, 1.0 - switch)
        return matrix

    def initial_probabilities(self) -> np.ndarray:
        """A new track's mode probabilities (M,): initial_cv_probability on CV, the rest shared equally."""
        count = len(self.models)
        return np.array([self.initial_cv_probability] + [(1.0 - self.initial_cv_probability) / (count - 1)]
                        * (count - 1))

    def with_values(self, noise_std: tuple[float, ...], velocity_std_mps: float) -> "FilterSettings":
        return FilterSettings(self.kind, tuple(float(v) for v in noise_std), float(velocity_std_mps),
                              self.acceleration_std_mps2, self.switch_probability, self.initial_cv_probability,
                              self.turn_rate_dps)

    def to_dict(self) -> dict:
        return {**asdict(self), "noise_std": list(self.noise_std)}

    @classmethod
    def from_dict(cls, values: dict) -> "FilterSettings":
        return cls(**{**values, "noise_std": tuple(values["noise_std"])})


SETTINGS_KEYS = tuple(field.name for field in fields(FilterSettings))
PROBABILITY_KEYS = ("switch_probability", "initial_cv_probability")
SPREAD_KEYS = ("velocity_std_mps", "acceleration_std_mps2")


def load_settings(path) -> dict[str, FilterSettings]:
    """The tuned filters saved by the tune stage, by kind, every value checked.

    The file may be edited by hand or damaged, and a filter takes any number: a negative
    probability or spread does not fail, it changes every track silently. So the filters the bench
    always runs (`REQUIRED_FILTERS`: cv, ca, imm) must be there, the others (those `kalman.filters` adds)
    may be, each with every key of `FilterSettings`, its probabilities in [0, 1], its
    standard deviations finite and above 0, and its turn rate above 0 for a kind with turns, 0 for the
    others; otherwise InputError names the file, the filter, the key and the value."""
    try:
        saved = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no tuned Kalman filters; run `dvc repro tune_kalman`") from None
    except ValueError as error:  # not JSON, or not UTF-8
        raise InputError(f"{path}: not a tuned-filter file ({error})") from None
    filters = saved.get("filters") if isinstance(saved, dict) else None
    if not isinstance(filters, dict):
        raise InputError(f"{path}: not a tuned-filter file (no 'filters' object)")
    for kind in filters:
        if kind not in KINDS:
            raise InputError(f"{path}: filter {kind!r}: unknown (the tune stage saves {', '.join(KINDS)})")
    missing = [kind for kind in REQUIRED_FILTERS if kind not in filters]
    if missing:
        raise InputError(f"{path}: filter {missing[0]!r}: missing (the tune stage saves {', '.join(REQUIRED_FILTERS)} "
                         "and those kalman.filters adds)")
    return {kind: _checked_settings(path, kind, filters[kind]) for kind in KINDS if kind in filters}


def _checked_settings(path, kind: str, values: object) -> FilterSettings:
    """One filter of a tuned-filter file, refused unless it is one the tune stage could have saved."""
    where = f"{path}: filter {kind!r}"
    if not isinstance(values, dict):
        raise InputError(f"{where} = {values!r}: must be an object with the keys {', '.join(SETTINGS_KEYS)}")
    for key in SETTINGS_KEYS:
        if key not in values:
            raise InputError(f"{where}: key {key!r} missing")
    for key in values:
        if key not in SETTINGS_KEYS:
            raise InputError(f"{where}: key {key!r}: unknown (known: {', '.join(SETTINGS_KEYS)})")
    if values["kind"] != kind:
        raise InputError(f"{where}, kind = {values['kind']!r}: must be {kind!r}, the filter it is saved under")
    noise, count = values["noise_std"], NOISE_VALUES[kind]
    if not isinstance(noise, list) or len(noise) != count:
        raise InputError(f"{where}, noise_std = {noise!r}: must list {count} standard deviation(s), one per "
                         f"motion model {tuple(dict.fromkeys(MODELS[kind]))}")
    for index, value in enumerate(noise):
        _check_spread(f"{where}, noise_std[{index}]", value)
    for key in SPREAD_KEYS:
        _check_spread(f"{where}, {key}", values[key])
    for key in PROBABILITY_KEYS:
        value = values[key]
        if not _is_number(value) or not 0.0 <= value <= 1.0:
            raise InputError(f"{where}, {key} = {value!r}: must be a probability in [0, 1]")
    rate = values["turn_rate_dps"]
    if kind in TURNING_KINDS:
        _check_spread(f"{where}, turn_rate_dps", rate)
    elif rate != 0 or isinstance(rate, bool):
        raise InputError(f"{where}, turn_rate_dps = {rate!r}: must be 0, {kind} has no turning model")
    return FilterSettings.from_dict(values)


def _is_number(value: object) -> bool:
    """A finite JSON number: Python's json reads NaN and Infinity, and true and false are ints to it."""
    if isinstance(value, bool):
        return False
    return isinstance(value, int) or (isinstance(value, float) and math.isfinite(value))


def _check_spread(where: str, value: object) -> None:
    if not _is_number(value) or value <= 0.0:
        raise InputError(f"{where} = {value!r}: must be a finite standard deviation above 0")


def _kalman(model: str, state: np.ndarray, covariance: np.ndarray) -> KalmanFilter:
    kf = KalmanFilter(dim_x=motion_models.state_size(model), dim_z=3)
    kf.x, kf.P, kf.H = state.copy(), covariance.copy(), motion_models.measurement_matrix(model)
    return kf


def start_filter(settings: FilterSettings, position: np.ndarray, covariance: np.ndarray
                 ) -> KalmanFilter | IMMEstimator:
    """A filter started at one measurement."""
    filters = [_kalman(model, *motion_models.initial_state(model, position, covariance, settings.velocity_std_mps,
                                                            settings.acceleration_std_mps2))
               for model in settings.motion_bases]
    if not settings.is_imm:
        return filters[0]
    return IMMEstimator(filters, settings.initial_probabilities(), settings.transition_probabilities())


def _sub_filters(estimator: KalmanFilter | IMMEstimator) -> list[KalmanFilter]:
    return estimator.filters if isinstance(estimator, IMMEstimator) else [estimator]


def _transitions(estimator: KalmanFilter | IMMEstimator, settings: FilterSettings, dt: float) -> list[np.ndarray]:
    """Each model's F over dt: a turn's about the local vertical at the first model's position, as the
    Kalman core takes it (`batch_filters.turned`)."""
    first = _sub_filters(estimator)[0].x
    up = turn_model.local_vertical(first[motion_models.measured_indices(settings.models[0])])
    return [turn_model.turn_transition(dt, rate, up) if model == TURN else motion_models.transition(model, dt)
            for model, rate in zip(settings.models, settings.turn_rates())]


def advance(estimator: KalmanFilter | IMMEstimator, settings: FilterSettings, dt: float) -> None:
    """Predict the filter dt seconds ahead (in place)."""
    for kf, F, model, noise in zip(_sub_filters(estimator), _transitions(estimator, settings, dt),
                                   settings.motion_bases, settings.model_noise_std):
        kf.F = F
        kf.Q = motion_models.process_noise(model, dt, noise)
    estimator.predict()


def update(estimator: KalmanFilter | IMMEstimator, position: np.ndarray, covariance: np.ndarray) -> None:
    for kf in _sub_filters(estimator):
        kf.R = covariance
    estimator.update(position)


def predicted_gaussian(estimator: KalmanFilter | IMMEstimator, settings: FilterSettings, dt: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The predicted state and covariance dt seconds ahead, the filter unchanged."""
    filters = _sub_filters(estimator)
    transitions = _transitions(estimator, settings, dt)
    if isinstance(estimator, IMMEstimator):
        weights = estimator.omega  # mixing weights: omega[i, j] of model i in model j's start
        means = [sum(weights[i, j] * filters[i].x for i in range(len(filters))) for j in range(len(filters))]
        spreads = [sum(weights[i, j] * (filters[i].P + np.outer(filters[i].x - means[j], filters[i].x - means[j]))
                       for i in range(len(filters))) for j in range(len(filters))]
        probabilities = estimator.cbar
    else:
        means, spreads, probabilities = [filters[0].x], [filters[0].P], np.ones(1)
    states, covariances = [], []
    for mean, spread, transition, model, noise in zip(means, spreads, transitions, settings.motion_bases,
                                                      settings.model_noise_std):
        states.append(transition @ mean)
        covariances.append(transition @ spread @ transition.T + motion_models.process_noise(model, dt, noise))
    state = sum(p * s for p, s in zip(probabilities, states))
    covariance = sum(p * (c + np.outer(s - state, s - state)) for p, s, c in zip(probabilities, states, covariances))
    return state, covariance


def posterior(estimator: KalmanFilter | IMMEstimator) -> tuple[np.ndarray, np.ndarray]:
    return estimator.x, estimator.P


def model_probabilities(estimator: KalmanFilter | IMMEstimator) -> np.ndarray:
    """The IMM's mode probabilities (its models in `FilterSettings.models` order); [1] for a single model."""
    return estimator.mu.copy() if isinstance(estimator, IMMEstimator) else np.ones(1)

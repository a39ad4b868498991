"""The classical filters of the tracker, defined with filterpy: a CV or CA Kalman filter, or an IMM.

`FilterSettings` is everything that defines one (its motion models, their process noise and
the spread of a new track's velocity); the tuner chooses these values and saves them in
`models/kalman_tuned.json`, the tracker loads them.

The filterpy objects built here are the reference: the tuner, the comparison and the tracker
(`pipeline.tracker.kalman`) run the same equations on NumPy arrays in the one Kalman core
(`pipeline.filters.batch_filters`), which the tests check against these objects step by step. A filter
is started at one plot (`start_filter`); `advance` steps it to a plot's time and
`predicted_gaussian` gives the prediction at any time without changing it (what gating needs).

The IMM is filterpy's `IMMEstimator` over a constant-velocity and a constant-acceleration
model in one 9-entry state (see `pipeline.filters.motion_models`). Its prediction for gating mixes the
models with the predicted mode probabilities (c-bar), which is the IMM's own predicted
density; filterpy's `x_prior` weights them with the last posterior ones instead.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
from filterpy.kalman import IMMEstimator, KalmanFilter

from pipeline.filters import motion_models
from pipeline.io import InputError

KINDS = ("cv", "ca", "imm")
MODELS = {"cv": ("cv",), "ca": ("ca",), "imm": ("cv9", "ca")}


@dataclass(frozen=True)
class FilterSettings:
    """One classical filter. `noise_std` has one entry per motion model of the kind
    (cv: acceleration m/s^2; ca: acceleration increments m/s^3; imm: both, in that order)."""

    kind: str
    noise_std: tuple[float, ...]
    velocity_std_mps: float          # spread of a new track's unknown velocity
    acceleration_std_mps2: float     # spread of a new track's unknown acceleration (ca, imm)
    switch_probability: float        # imm: probability of changing model between two updates
    initial_cv_probability: float    # imm: probability of the CV model for a new track

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"filter kind {self.kind!r}: must be one of {KINDS}")
        if len(self.noise_std) != len(MODELS[self.kind]):
            raise ValueError(f"{self.kind}: needs {len(MODELS[self.kind])} process-noise values, got {self.noise_std}")

    @property
    def models(self) -> tuple[str, ...]:
        return MODELS[self.kind]

    @property
    def measured(self) -> list[int]:
        return motion_models.measured_indices(self.models[0])

    def transition_probabilities(self) -> np.ndarray:
        switch = self.switch_probability
        return np.array([[1.0 - switch, switch], [switch, 1.0 - switch]])

    def initial_probabilities(self) -> np.ndarray:
        return np.array([self.initial_cv_probability, 1.0 - self.initial_cv_probability])

    def with_values(self, noise_std: tuple[float, ...], velocity_std_mps: float) -> "FilterSettings":
        return FilterSettings(self.kind, tuple(float(v) for v in noise_std), float(velocity_std_mps),
                              self.acceleration_std_mps2, self.switch_probability, self.initial_cv_probability)

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
    probability or spread does not fail, it changes every track silently. So each of the three
    filters must be there with every key of `FilterSettings`, its probabilities in [0, 1] and its
    standard deviations finite and above 0; otherwise InputError names the file, the filter, the
    key and the value."""
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
    missing = [kind for kind in KINDS if kind not in filters]
    if missing:
        raise InputError(f"{path}: filter {missing[0]!r}: missing (the tune stage saves {', '.join(KINDS)})")
    return {kind: _checked_settings(path, kind, filters[kind]) for kind in KINDS}


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
    noise, count = values["noise_std"], len(MODELS[kind])
    if not isinstance(noise, list) or len(noise) != count:
        raise InputError(f"{where}, noise_std = {noise!r}: must list {count} standard deviation(s), one per "
                         f"motion model {MODELS[kind]}")
    for index, value in enumerate(noise):
        _check_spread(f"{where}, noise_std[{index}]", value)
    for key in SPREAD_KEYS:
        _check_spread(f"{where}, {key}", values[key])
    for key in PROBABILITY_KEYS:
        value = values[key]
        if not _is_number(value) or not 0.0 <= value <= 1.0:
            raise InputError(f"{where}, {key} = {value!r}: must be a probability in [0, 1]")
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
               for model in settings.models]
    if settings.kind != "imm":
        return filters[0]
    return IMMEstimator(filters, settings.initial_probabilities(), settings.transition_probabilities())


def _sub_filters(estimator: KalmanFilter | IMMEstimator) -> list[KalmanFilter]:
    return estimator.filters if isinstance(estimator, IMMEstimator) else [estimator]


def advance(estimator: KalmanFilter | IMMEstimator, settings: FilterSettings, dt: float) -> None:
    """Predict the filter dt seconds ahead (in place)."""
    for kf, model, noise in zip(_sub_filters(estimator), settings.models, settings.noise_std):
        kf.F = motion_models.transition(model, dt)
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
    if isinstance(estimator, IMMEstimator):
        weights = estimator.omega  # mixing weights: omega[i, j] of model i in model j's start
        means = [sum(weights[i, j] * filters[i].x for i in range(len(filters))) for j in range(len(filters))]
        spreads = [sum(weights[i, j] * (filters[i].P + np.outer(filters[i].x - means[j], filters[i].x - means[j]))
                       for i in range(len(filters))) for j in range(len(filters))]
        probabilities = estimator.cbar
    else:
        means, spreads, probabilities = [filters[0].x], [filters[0].P], np.ones(1)
    states, covariances = [], []
    for mean, spread, model, noise in zip(means, spreads, settings.models, settings.noise_std):
        transition = motion_models.transition(model, dt)
        states.append(transition @ mean)
        covariances.append(transition @ spread @ transition.T + motion_models.process_noise(model, dt, noise))
    state = sum(p * s for p, s in zip(probabilities, states))
    covariance = sum(p * (c + np.outer(s - state, s - state)) for p, s, c in zip(probabilities, states, covariances))
    return state, covariance


def posterior(estimator: KalmanFilter | IMMEstimator) -> tuple[np.ndarray, np.ndarray]:
    return estimator.x, estimator.P


def model_probabilities(estimator: KalmanFilter | IMMEstimator) -> np.ndarray:
    """The IMM's mode probabilities (CV, CA); [1] for a single model."""
    return estimator.mu.copy() if isinstance(estimator, IMMEstimator) else np.ones(1)

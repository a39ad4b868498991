"""Motion models of the classical trackers: transition F and process noise Q over a time step.

Four models, each defined once here and used by the filterpy reference filters
(`pipeline.filters.classical_filters`), by the one Kalman core that the tracker, the tuner and the
comparison run (`pipeline.filters.batch_filters`) and by its differentiable twin (`pipeline.filters.torch_filters`):

- `cv`: constant velocity, state [x, vx, y, vy, z, vz], white-noise acceleration of standard
  deviation q (filterpy's `Q_discrete_white_noise(dim=2)`).
- `ca`: constant acceleration, state [x, vx, ax, y, vy, ay, z, vz, az], white-noise
  acceleration increments of standard deviation q per second (filterpy's
  `Q_discrete_white_noise(dim=3)`, the discrete Wiener-process acceleration model).
- `cv9`: constant velocity in the CA state, acceleration reset to zero at each step, so an
  IMM can mix it with `ca` (filterpy's IMMEstimator needs one state layout for all models).
- `singer`: Singer's model (Singer 1970, IEEE Trans. AES-6(4)) in the CA state: the acceleration
  is a first-order Gauss-Markov process of manoeuvre time constant tau (alpha = 1 / tau) and
  variance sigma_m^2 (`noise_std` = sigma_m, m/s^2). Not a tuned kind of the classical tracker
  (`classical_filters.KINDS`); the torch filters (`pipeline.filters.torch_filters`) run it.

The noise is the same on the three axes, so the filters give the same result in ECEF as in
a local east-north-up frame (Q and the transition commute with a rotation of the axes):
the tracker stays in ECEF and takes the measurement covariance rotated there.

Every function takes `dt` as a scalar or an array (then the result has dt's shape in front),
so the tuner can step hundreds of tracks at once.
"""

from __future__ import annotations

from fractions import Fraction
from math import factorial
from types import ModuleType

import numpy as np

DIMENSIONS = {"cv": 2, "ca": 3, "cv9": 3, "singer": 3}  # state entries per axis


def state_size(model: str) -> int:
    return 3 * DIMENSIONS[model]


def measured_indices(model: str) -> list[int]:
    """Where x, y, z sit in the model's state."""
    return [axis * DIMENSIONS[model] for axis in range(3)]


def velocity_indices(model: str) -> list[int]:
    return [axis * DIMENSIONS[model] + 1 for axis in range(3)]


def measurement_matrix(model: str) -> np.ndarray:
    """H: picks the position out of the state."""
    matrix = np.zeros((3, state_size(model)))
    matrix[[0, 1, 2], measured_indices(model)] = 1.0
    return matrix


def _per_axis(block: np.ndarray) -> np.ndarray:
    """The same (..., d, d) block on each of the three axes: (..., 3d, 3d)."""
    d = block.shape[-1]
    out = np.zeros((*block.shape[:-2], 3 * d, 3 * d))
    for axis in range(3):
        out[..., axis * d:(axis + 1) * d, axis * d:(axis + 1) * d] = block
    return out


def transition(model: str, dt: float | np.ndarray, manoeuvre_time_s: float | None = None) -> np.ndarray:
    """F over dt; `singer` also needs its manoeuvre time constant tau (s)."""
    dt = np.asarray(dt, dtype=float)
    if model == "singer":
        return _per_axis(singer_blocks(dt, 1.0 / _manoeuvre_time(manoeuvre_time_s), np.float64(1.0))[0])
    one, zero = np.ones_like(dt), np.zeros_like(dt)
    if model == "cv":
        rows = [[one, dt], [zero, one]]
    elif model == "ca":
        rows = [[one, dt, dt ** 2 / 2], [zero, one, dt], [zero, zero, one]]
    elif model == "cv9":
        rows = [[one, dt, zero], [zero, one, zero], [zero, zero, zero]]
    else:
        raise ValueError(f"motion model {model!r}: must be cv, ca, cv9 or singer")
    return _per_axis(np.moveaxis(np.array(rows), (0, 1), (-2, -1)))


def process_noise(model: str, dt: float | np.ndarray, noise_std: float, manoeuvre_time_s: float | None = None
                  ) -> np.ndarray:
    """Q over dt for process noise of standard deviation `noise_std` (m/s^2 for cv/cv9, m/s^3 for ca;
    for singer the acceleration's standard deviation sigma_m, m/s^2, with its manoeuvre time tau, s)."""
    dt = np.asarray(dt, dtype=float)
    if model == "singer":
        return _per_axis(singer_blocks(dt, 1.0 / _manoeuvre_time(manoeuvre_time_s), np.float64(noise_std) ** 2)[1])
    variance = noise_std ** 2
    if model in ("cv", "cv9"):
        rows = [[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]]
        if model == "cv9":
            zero = np.zeros_like(dt)
            rows = [rows[0] + [zero], rows[1] + [zero], [zero, zero, zero]]
    elif model == "ca":
        rows = [[dt ** 4 / 4, dt ** 3 / 2, dt ** 2 / 2], [dt ** 3 / 2, dt ** 2, dt], [dt ** 2 / 2, dt, np.ones_like(dt)]]
    else:
        raise ValueError(f"motion model {model!r}: must be cv, ca, cv9 or singer")
    return variance * _per_axis(np.moveaxis(np.array(rows), (0, 1), (-2, -1)))


def initial_state(model: str, position: np.ndarray, covariance: np.ndarray, velocity_std: float,
                  acceleration_std: float) -> tuple[np.ndarray, np.ndarray]:
    """State and covariance of a track started at one measurement: position measured, velocity
    and acceleration unknown (zero, with the given spreads). Batched over leading axes of `position`."""
    position = np.asarray(position, dtype=float)
    size = state_size(model)
    state = np.zeros((*position.shape[:-1], size))
    state[..., measured_indices(model)] = position
    spread = np.zeros((*position.shape[:-1], size, size))
    measured = measured_indices(model)
    for row, i in enumerate(measured):
        for column, j in enumerate(measured):
            spread[..., i, j] = covariance[..., row, column]
    for index in velocity_indices(model):
        spread[..., index, index] = velocity_std ** 2
    if DIMENSIONS[model] == 3:
        for index in (2, 5, 8):
            spread[..., index, index] = acceleration_std ** 2 if model in ("ca", "singer") else 0.0
    return state, spread


# ----------------------------------------------------------------------------- Singer's model
#
# Singer (1970), as restated by Li & Jilkov (2003), "Survey of maneuvering target tracking. Part I:
# dynamic models", IEEE Trans. AES-39(4), section IV.A: per axis, state [x, v, a] with
# da/dt = -alpha a + w, w white of spectral density 2 alpha sigma_m^2, so over a step T, with u = alpha T,
#
#   F = [[1, T, (u - 1 + e^-u) / alpha^2], [0, 1, (1 - e^-u) / alpha], [0, 0, e^-u]]
#
# and Q = 2 alpha sigma_m^2 [q_ij] with
#   q11 = (1 - e^-2u + 2u + 2u^3/3 - 2u^2 - 4u e^-u) / (2 alpha^5)
#   q12 = (e^-2u + 1 - 2e^-u + 2u e^-u - 2u + u^2) / (2 alpha^4)
#   q13 = (1 - e^-2u - 2u e^-u) / (2 alpha^3)
#   q22 = (4e^-u - 3 - e^-2u + 2u) / (2 alpha^3)
#   q23 = (e^-2u + 1 - 2e^-u) / (2 alpha^2)
#   q33 = (1 - e^-2u) / (2 alpha).
# Each entry is T^p g(u) for a function g of u alone: F13 = T^2 g, F23 = T g, Q11 = sigma_m^2 T^4 g,
# and so on, and each g is a sum of terms c u^a e^(-b u) over a power of u (the table below, the
# formulas above). Below SINGER_SERIES_BELOW the closed forms cancel badly (q11's terms are of
# order u, their sum of order u^5 / 10: about 20 eps / u^4 relative error), so there g is summed
# from its Taylor series, whose coefficients are computed exactly from the same table.

SINGER_SERIES_BELOW = 0.5   # u = alpha T below which g(u) is summed from its series
SINGER_SERIES_TERMS = 20    # the series' terms: the first left out is below 1e-18 relative at u = 0.5

# g(u) = sum of c u^a e^(-b u) over the (c, a, b) terms, divided by u^m: {entry: (terms, m, p)}, p the power of T.
_SINGER_FUNCTIONS = {
    "F13": (((1, 1, 0), (-1, 0, 0), (1, 0, 1)), 2, 2),
    "F23": (((1, 0, 0), (-1, 0, 1)), 1, 1),
    "Q11": (((1, 0, 0), (-1, 0, 2), (2, 1, 0), (Fraction(2, 3), 3, 0), (-2, 2, 0), (-4, 1, 1)), 4, 4),
    "Q12": (((1, 0, 2), (1, 0, 0), (-2, 0, 1), (2, 1, 1), (-2, 1, 0), (1, 2, 0)), 3, 3),
    "Q13": (((1, 0, 0), (-1, 0, 2), (-2, 1, 1)), 2, 2),
    "Q22": (((4, 0, 1), (-3, 0, 0), (-1, 0, 2), (2, 1, 0)), 2, 2),
    "Q23": (((1, 0, 2), (1, 0, 0), (-2, 0, 1)), 1, 1),
    "Q33": (((1, 0, 0), (-1, 0, 2)), 0, 0),
}
_SINGER_BASIS = ((0, 0), (1, 0), (2, 0), (3, 0), (0, 1), (0, 2), (1, 1))  # the (a, b) of u^a e^(-b u) in the terms


def _series(terms: tuple, power: int) -> list[float]:
    """Taylor coefficients (lowest order first) of sum(c u^a e^(-b u)) / u^power, exact to rounding;
    the coefficients below u^power must cancel (they do for Singer's entries)."""
    def coefficient(k: int) -> Fraction:
        return sum((Fraction(c) * Fraction(-b) ** (k - a) / factorial(k - a) for c, a, b in terms if k >= a),
                   Fraction(0))
    assert all(coefficient(k) == 0 for k in range(power)), terms
    return [float(coefficient(k)) for k in range(power, power + SINGER_SERIES_TERMS)]


# Per entry (columns, in _SINGER_FUNCTIONS' order): its terms' coefficients on the basis, its power
# of u and of T, and its Taylor coefficients.
_SINGER_CLOSED = np.array([[float(sum(c for c, a, b in terms if (a, b) == basis)) for terms, _, _ in
                            _SINGER_FUNCTIONS.values()] for basis in _SINGER_BASIS])
_SINGER_U_POWER = np.array([power for _, power, _ in _SINGER_FUNCTIONS.values()], dtype=float)
_SINGER_T_POWER = np.array([power for _, _, power in _SINGER_FUNCTIONS.values()], dtype=float)
_SINGER_SERIES = np.array([_series(terms, power) for terms, power, _ in _SINGER_FUNCTIONS.values()]).T


def _manoeuvre_time(manoeuvre_time_s: float | None) -> float:
    if manoeuvre_time_s is None or not manoeuvre_time_s > 0.0:
        raise ValueError(f"singer: manoeuvre_time_s = {manoeuvre_time_s!r}: must be a time constant above 0 s")
    return manoeuvre_time_s


def singer_blocks(dt, alpha, variance, xp: ModuleType = np):
    """Singer's per-axis F and Q, (..., 3, 3) each, over steps dt (s) with manoeuvre frequency alpha
    (1/s) and acceleration variance sigma_m^2 (m^2/s^4), all broadcast together (formulas above).

    `xp` is the array module, numpy or torch: the same arithmetic serves the NumPy reference and the
    differentiable torch filters (`pipeline.filters.torch_filters`), whose network scales alpha per step."""
    def table(values: np.ndarray):  # on torch's side on the data's device
        return xp.asarray(values, dtype=u.dtype) if xp is np else xp.asarray(values, dtype=u.dtype, device=u.device)

    u = alpha * dt
    small = u < SINGER_SERIES_BELOW
    closed_u = xp.where(small, SINGER_SERIES_BELOW, u)   # the closed form never sees u near 0 (no 0/0, no NaN gradient)
    e = xp.exp(-closed_u)
    basis = xp.stack([xp.ones_like(u), closed_u, closed_u ** 2, closed_u ** 3, e, e * e, closed_u * e], -1)
    closed = basis @ table(_SINGER_CLOSED) / closed_u[..., None] ** table(_SINGER_U_POWER)
    series_u = xp.where(small, u, 0.0)
    powers = xp.cumprod(xp.stack([series_u] * (SINGER_SERIES_TERMS - 1), -1), -1)   # u, u^2, ...
    series = table(_SINGER_SERIES[0]) + powers @ table(_SINGER_SERIES[1:])
    g = xp.where(small[..., None], series, closed) * dt[..., None] ** table(_SINGER_T_POWER)
    F13, F23, Q11, Q12, Q13, Q22, Q23, Q33 = (g[..., i] for i in range(8))
    one, zero = xp.ones_like(u), xp.zeros_like(u)
    F = [[one, dt * one, F13], [zero, one, F23], [zero, zero, xp.exp(-u)]]
    Q = [[Q11, Q12, Q13], [Q12, Q22, Q23], [Q13, Q23, Q33]]
    return stacked_matrix(F, xp), variance[..., None, None] * stacked_matrix(Q, xp)


def stacked_matrix(rows: list[list], xp: ModuleType = np):
    """(..., r, c) from r lists of c entries, all of one shape (...)."""
    return xp.stack([xp.stack(row, -1) for row in rows], -2)

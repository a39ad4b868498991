"""Tuning of the classical filters on the training routes, as a filter tuner does.

The material is each training route's target plots in time order with the true position
at each plot (only the target's plots: tuning is about estimation, association comes
later). Every filter runs over every route at once (`pipeline.filters.batch_filters`); a gap
longer than `restart_gap_s` restarts it, as the tracker would have deleted the silent track.

The cost is computed from the filtered positions after `burn_in_updates` updates of each
(re)start:
- `rmse`: root-mean-square distance to the truth, metres;
- `nees`: |ln(ANEES / 3)|, where ANEES is the mean normalised estimation error squared of the
  position, which is 3 for a filter whose covariance tells the truth about its errors;
- `rmse_in_gate` (ours): the RMSE, raised in proportion when more target plots fall outside the
  tracker's chi-square gate than the gate's probability P_G allows:
  rmse * (1 + max(0, miss - (1 - P_G)) / (1 - P_G)), miss the share of gated plots whose
  innovation distance (`batch_filters.FilteredSequences`) exceeds the gate. The gated plots are
  those the tracker gates with the filter's prediction: from the
  `tracker.association.young_track_plots`-th plot after each (re)start on, burn-in or not (a new
  track's velocity spread decides whether its third plot is kept). RMSE alone tunes
  with the true association, so it never sees the gate: on routes that are mostly straight it
  drives the IMM's CV model to no process noise, whose tight prediction then gates out the
  target's plots in a long turn and splits the track. Twice the allowed misses doubles the cost.

Nelder-Mead (scipy.optimize) searches the logarithms of the process-noise values and of a
new track's velocity spread, so they stay positive and are searched on a relative scale,
within a factor of 1000 of the start values: a value that wants to go to zero (the IMM's CV
model would like no noise at all) then converges at the bound instead of drifting forever,
and the report says which values ended at a bound. The IMM's model switch probability is a
design value of the filter like its noise (Bar-Shalom, Li & Kirubarajan 2001, 11.6.6: it
follows the expected sojourn time in each mode), so it is tuned too, by its log-odds within a
factor of 1000 of the start odds: left at the usual 0.05, the IMM stays on its quiet CV model
too long when a fighter starts a 6 deg/s turn and gates out the plot that would have switched it
(measured on the test split: issue 13). The IMM with turns also tunes its turns' rate, by its logarithm
within a factor of 1000 of the start rate, as the noise (issue 33). The search stops when the values agree
to 1 % and the cost to 1e-3 (metres, or the NEES cost's relative units).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
import pyarrow as pa
from scipy import optimize, special
from scipy.stats import chi2

from pipeline.filters import batch_filters
from pipeline.filters.classical_filters import FilterSettings
from pipeline.geometry import geodesy
from pipeline.params import TUNING_COSTS, Radar

log = logging.getLogger("pipeline")

SIMPLEX_STEP = 0.7  # the first simplex spans a factor of two in each value (scipy's default, 5 %, of log 1 is 0)
SEARCH_RANGE = np.log(1000.0)  # each value is searched within a factor of 1000 of its start value


class TuningError(RuntimeError):
    """Tuning did not give a usable filter; the message has the values it reached."""


@dataclass(frozen=True)
class Sequences:
    """Measurement sequences packed into B rows of T plots (see `_packed`)."""

    times: np.ndarray          # (B, T)
    positions: np.ndarray      # (B, T, 3)
    covariances: np.ndarray    # (B, T, 3, 3)
    truth: np.ndarray          # (B, T, 3)
    valid: np.ndarray          # (B, T)
    restart: np.ndarray        # (B, T)
    scored: np.ndarray         # (B, T): counted in the cost (valid and past the burn-in)
    gated: np.ndarray          # (B, T): gated by the tracker with the filter's prediction (valid, old enough)
    gate_probability: float    # the tracker's chi-square gate probability P_G (3 degrees of freedom)


def target_sequences(plots: pa.Table, radar: Radar, restart_gap_s: float, burn_in_updates: int,
                     gate_probability: float, gated_from: int, segment_plots: int | None = None) -> Sequences:
    """Each route's target plots, with the truth and the converted-measurement covariance, to be
    held to the tracker's gate of probability `gate_probability` from the `gated_from`-th plot of
    each (re)start on (the tracker's young-track plots, which it gates by a radius, before).
    `segment_plots`: the filter also restarts after this many plots, so rows are at most that long
    (training segments for gradient descent, `pipeline.learning.filter_training`)."""
    target = plots.filter(plots.column("is_target"))
    route = target.column("scenario_id").to_numpy()
    time = target.column("time_unix_s").to_numpy()
    order = np.lexsort((time, route))
    route, time = route[order], time[order]
    position = np.column_stack([target.column(f"{a}_ecef_m").to_numpy()[order] for a in "xyz"])
    truth = np.column_stack([target.column(f"true_{a}_ecef_m").to_numpy()[order] for a in "xyz"])
    if not len(time):
        raise TuningError("no target plots to tune on")
    gap = np.diff(time, prepend=-np.inf)
    restart_at = np.concatenate([[True], route[1:] != route[:-1]]) | (gap > restart_gap_s)
    index = np.arange(len(time))
    since_restart = index - np.maximum.accumulate(np.where(restart_at, index, 0))
    if segment_plots is not None:
        restart_at |= since_restart % segment_plots == 0
        since_restart = index - np.maximum.accumulate(np.where(restart_at, index, 0))
    row, column = _packed(np.diff(np.flatnonzero(np.append(restart_at, True))))
    B, T = row.max() + 1, column.max() + 1

    def padded(values: np.ndarray, fill: float | bool) -> np.ndarray:
        out = np.full((B, T, *values.shape[1:]), fill, dtype=values.dtype)
        out[row, column] = values
        return out

    valid = padded(np.ones(len(time), bool), False)
    covariance = np.where(valid[..., None, None], padded(geodesy.measurement_covariance(position, radar), 0.0),
                          np.eye(3))  # padding: any invertible covariance, never used
    return Sequences(padded(time, 0.0), padded(position, 0.0), covariance, padded(truth, 0.0), valid,
                     padded(restart_at, False),
                     padded(since_restart >= burn_in_updates, False), padded(since_restart >= gated_from, False),
                     gate_probability)


def _packed(lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of every plot when the sequences (each starting with a restart) are packed
    into as few rows as first-fit decreasing finds, each as long as the longest sequence: a
    restart makes a sequence independent of what precedes it in its row, and the batch steps
    column by column, so fewer, fuller rows are faster."""
    capacity = int(lengths.max())
    free: list[int] = []
    placement = np.empty((len(lengths), 2), dtype=np.int64)
    for sequence in np.argsort(-lengths, kind="stable"):
        row = next((r for r, room in enumerate(free) if room >= lengths[sequence]), len(free))
        if row == len(free):
            free.append(capacity)
        placement[sequence] = row, capacity - free[row]
        free[row] -= lengths[sequence]
    row = np.repeat(placement[:, 0], lengths)
    column = np.repeat(placement[:, 1], lengths) + np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths,
                                                                                      lengths)
    return row, column


@dataclass(frozen=True)
class Assessment:
    """How one filter did over the material."""

    rmse_m: float
    plot_rmse_m: float    # the raw plots' error over the same samples, for scale
    anees: float          # mean position NEES; 3 for a consistent filter
    anees_bounds: tuple[float, float]   # its 95 % interval for this many samples if consistent
    nees_in_interval: float  # share of single NEES values inside chi-square(3)'s 95 % interval (0.95 if consistent)
    samples: int
    gate_misses: float    # share of scored plots outside the tracker's gate (1 - P_G if consistent)
    gate_allowance: float  # 1 - P_G

    def cost(self, kind: str) -> float:
        if kind == "rmse":
            return self.rmse_m
        if kind == "rmse_in_gate":
            return self.rmse_m * (1.0 + max(0.0, self.gate_misses - self.gate_allowance) / self.gate_allowance)
        return abs(float(np.log(self.anees / 3.0)))

    def to_dict(self) -> dict:
        return {"rmse_m": self.rmse_m, "plot_rmse_m": self.plot_rmse_m, "anees": self.anees, "anees_bounds": list(self.anees_bounds),
                "nees_in_95_interval": self.nees_in_interval, "samples": self.samples,
                "gate_misses": self.gate_misses, "gate_allowance": self.gate_allowance}


def assess(settings: FilterSettings, material: Sequences) -> Assessment:
    """Run the filter over every route and measure its error and consistency."""
    filtered = batch_filters.filter_sequences(settings, material.times, material.positions, material.covariances,
                                              material.valid, material.restart)
    error = (filtered.position - material.truth)[material.scored]
    spread = filtered.covariance[material.scored]
    gate = chi2.ppf(material.gate_probability, df=3)
    inverse, determinant = batch_filters.inverse3(spread)
    # Positive definite: the leading principal minors are positive (Sylvester; NaN fails too).
    minor = spread[:, 0, 0] * spread[:, 1, 1] - spread[:, 0, 1] * spread[:, 1, 0]
    if not ((spread[:, 0, 0] > 0) & (minor > 0) & (determinant > 0)).all():
        raise TuningError(f"{settings.kind}: a position covariance is not positive definite with noise "
                          f"{settings.noise_std} and velocity spread {settings.velocity_std_mps}")
    nees = (inverse * error[:, :, None] * error[:, None, :]).sum(axis=(1, 2))
    samples = len(nees)
    if not samples:
        raise TuningError("no plots past the burn-in to tune on")
    low, high = chi2.ppf([0.025, 0.975], df=3)
    return Assessment(
        rmse_m=float(np.sqrt((error ** 2).sum(axis=1).mean())),
        plot_rmse_m=float(np.sqrt(((material.positions - material.truth)[material.scored] ** 2).sum(axis=1).mean())),
        anees=float(nees.mean()),
        anees_bounds=tuple(float(b) for b in chi2.ppf([0.025, 0.975], df=3 * samples) / samples),
        nees_in_interval=float(((nees >= low) & (nees <= high)).mean()), samples=samples,
        gate_misses=float((filtered.innovation_distance[material.gated] > gate).mean()),
        gate_allowance=1.0 - material.gate_probability)


def _tunes_switching(settings: FilterSettings) -> bool:
    return len(settings.models) > 1


def _tunes_turns(settings: FilterSettings) -> bool:
    return settings.turn_rate_dps > 0.0


def _search_values(settings: FilterSettings) -> np.ndarray:
    """The searched values: log noise values, log velocity spread and, for an IMM, the log-odds of switching,
    and for the IMM with turns the log turn rate."""
    logs = np.log([*settings.noise_std, settings.velocity_std_mps])
    if _tunes_switching(settings):
        logs = np.append(logs, special.logit(settings.switch_probability))
    if _tunes_turns(settings):
        logs = np.append(logs, np.log(settings.turn_rate_dps))
    return logs


def _settings_at(start: FilterSettings, searched: np.ndarray) -> FilterSettings:
    noises = len(start.noise_std)
    values = np.exp(searched[:noises + 1])
    tuned = start.with_values(tuple(values[:noises]), values[noises])
    if _tunes_switching(start):
        tuned = replace(tuned, switch_probability=float(special.expit(searched[noises + 1])))
    if _tunes_turns(start):
        tuned = replace(tuned, turn_rate_dps=float(np.exp(searched[-1])))
    return tuned


def at_bounds(start: FilterSettings, tuned: FilterSettings) -> list[str]:
    """Which tuned values ended at the edge of the search range."""
    names = [f"noise_std[{i}]" for i in range(len(start.noise_std))] + ["velocity_std_mps"]
    if _tunes_switching(start):
        names.append("switch_probability")
    if _tunes_turns(start):
        names.append("turn_rate_dps")
    distance = np.abs(_search_values(tuned) - _search_values(start))
    return [name for name, d in zip(names, distance) if d > SEARCH_RANGE - 1e-2]


def tune(start: FilterSettings, material: Sequences, cost: str, max_iterations: int
         ) -> tuple[FilterSettings, Assessment, Assessment, int]:
    """The tuned settings, the assessment before and after, and the cost evaluations used.

    The search may take `max_iterations` Nelder-Mead iterations per searched value (scipy's own default is
    200 per value): an IMM with turns searches six values where the CV filter searches two, and needs the
    room. Raises TuningError, with the values reached, when the search does not converge or the
    tuned filter is not usable."""
    if cost not in TUNING_COSTS:
        raise ValueError(f"tuning cost {cost!r}: must be one of {TUNING_COSTS}")
    before = assess(start, material)
    evaluations = 0

    def objective(logs: np.ndarray) -> float:
        nonlocal evaluations
        evaluations += 1
        try:
            value = assess(_settings_at(start, logs), material).cost(cost)
        except TuningError:
            return np.inf
        if evaluations % 10 == 0:
            log.info("tune %s: %d evaluations, cost %.4g at %s", start.kind, evaluations, value,
                     np.round(np.exp(logs), 3).tolist())
        return value

    initial = _search_values(start)
    simplex = np.vstack([initial, initial + np.eye(len(initial)) * SIMPLEX_STEP])
    bounds = optimize.Bounds(initial - SEARCH_RANGE, initial + SEARCH_RANGE)
    result = optimize.minimize(objective, initial, method="Nelder-Mead", bounds=bounds,
                               options={"maxiter": max_iterations * len(initial), "xatol": 1e-2, "fatol": 1e-3,
                                        "initial_simplex": simplex})
    reached = _settings_at(start, result.x)
    if not result.success or not np.isfinite(result.fun):
        raise TuningError(f"{start.kind}: Nelder-Mead did not converge ({result.message}) after {result.nit} "
                          f"iterations; reached cost {result.fun:.6g} with noise {reached.noise_std} and "
                          f"velocity spread {reached.velocity_std_mps:.6g}, switch probability "
                          f"{reached.switch_probability:.4g}, turn rate {reached.turn_rate_dps:.4g} deg/s; nothing saved")
    after = assess(reached, material)
    return reached, before, after, evaluations

"""The classical trackers' filters, their batched twin, tuning, OSPA and the tune_kalman stage.

Synthetic flights are made in a flat local frame (east, north, up in metres) with plots of known
Gaussian noise (50, 50, 30 m standard deviation) every 6 s: the filters are the same in any
Cartesian frame (`pipeline.filters.motion_models`), so no geodesy is needed to check them. Where the code
works on ECEF plots near a radar (the batched filters, tuning material), the same flights are placed
around the radar with pymap3d and get the radar's converted-measurement noise; the tune_kalman stage
runs on a few minutes of the simulator's plots.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import dask
import numpy as np
import pyarrow as pa
import pymap3d
import pytest
from filterpy.common import Q_discrete_white_noise
from scipy.stats import binom, chi2

from pipeline import io
from pipeline.bench import engine, ospa
from pipeline.filters import batch_filters, classical_filters, motion_models, tuning
from pipeline.filters.classical_filters import FilterSettings
from pipeline.geometry import geodesy
from pipeline.params import ParamError
from pipeline.settings import parse_params
from pipeline.simulation import routes, simulate
from pipeline.stages.compare_stage import tuning_table
from pipeline.stages.tune_stage import run_tune
from pipeline.tracker.management import ThesisWeights

DT = 6.0                                  # scan period, s
SCANS = 60
NOISE_STD = np.array([50.0, 50.0, 30.0])  # plot noise, m
R = np.diag(NOISE_STD ** 2)
SPEED = 200.0                             # m/s
RUNS = 20                                 # Monte-Carlo runs per consistency check
BURN_IN = 5                               # updates left out of the consistency checks
T0 = 1.78e9                               # an instant in 2026, Unix seconds


# ----------------------------------------------------------------------------- helpers

def settings(kind: str, noise_std: tuple[float, ...], velocity_std_mps: float = 500.0) -> FilterSettings:
    """A filter with the given process noise; a new track's velocity is unknown up to 500 m/s; the IMM with
    turns turns at 3 deg/s."""
    return FilterSettings(kind, tuple(noise_std), velocity_std_mps, acceleration_std_mps2=20.0,
                          switch_probability=0.05, initial_cv_probability=0.9,
                          turn_rate_dps=3.0 if kind in classical_filters.TURNING_KINDS else 0.0)


def flight(turn_rates_dps: np.ndarray, heading_rad: float = 0.3, start: tuple[float, float, float] = (20e3, -5e3, 8e3),
           speed: float = SPEED) -> tuple[np.ndarray, np.ndarray]:
    """Times and true local (east, north, up) positions of a level flight, one point per scan; the
    heading turns at turn_rates_dps[k] (a coordinated turn: constant speed, constant rate) between
    scans k and k+1."""
    position = [np.asarray(start, dtype=float)]
    heading = heading_rad
    for rate in np.radians(turn_rates_dps):
        if rate == 0.0:
            step = speed * DT * np.array([np.sin(heading), np.cos(heading)])
        else:
            step = speed / rate * np.array([np.cos(heading) - np.cos(heading + rate * DT),
                                            np.sin(heading + rate * DT) - np.sin(heading)])
        heading += rate * DT
        position.append(position[-1] + [step[0], step[1], 0.0])
    return np.arange(len(position)) * DT, np.array(position)


def run_filter(kind_settings: FilterSettings, times: np.ndarray, truth: np.ndarray, rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray]:
    """Filter one noisy realisation of a flight with filterpy (through `classical_filters`): the position
    NEES after each update (NaN at the start) and the mode probabilities after each plot."""
    plots = truth + rng.normal(size=truth.shape) * NOISE_STD
    estimator = classical_filters.start_filter(kind_settings, plots[0], R)
    measured = kind_settings.measured
    nees, probabilities = [np.nan], [classical_filters.model_probabilities(estimator)]
    for k in range(1, len(times)):
        classical_filters.advance(estimator, kind_settings, times[k] - times[k - 1])
        classical_filters.update(estimator, plots[k], R)
        state, covariance = classical_filters.posterior(estimator)
        error = state[measured] - truth[k]
        nees.append(error @ np.linalg.solve(covariance[np.ix_(measured, measured)], error))
        probabilities.append(classical_filters.model_probabilities(estimator))
    return np.array(nees), np.array(probabilities)


def anees_per_scan(kind_settings: FilterSettings, times: np.ndarray, truth: np.ndarray, seed: int) -> np.ndarray:
    """ANEES at each scan after the burn-in: the position NEES averaged over RUNS independent runs."""
    rng = np.random.default_rng(seed)
    nees = np.array([run_filter(kind_settings, times, truth, rng)[0] for _ in range(RUNS)])
    return nees[:, 1 + BURN_IN:].mean(axis=0)


ANEES_BOUNDS = chi2.ppf([0.005, 0.995], df=3 * RUNS) / RUNS   # two-sided 99 % interval of one scan's ANEES


def scans_allowed_outside(scans: int) -> int:
    """How many scans' ANEES may leave the 99 % interval: the 99.9 % quantile of Binomial(scans, 0.01)."""
    return int(binom.ppf(0.999, scans, 0.01))


STRAIGHT = np.zeros(SCANS - 1)
TURNING = np.full(SCANS - 1, 3.0)  # 3 deg/s at 200 m/s: 10.5 m/s^2 of centripetal acceleration
MATCHED = {"cv": (8.0,), "ca": (3.0,), "imm": (1.0, 3.0)}  # noise that covers a 3 deg/s turn
BATCH_NOISE = {"cv": (5.0,), "ca": (2.0,), "imm": (1.0, 3.0), "imm_ct": (1.0, 2.0), "imm_ca_ct": (1.0, 3.0, 2.0)}  # the batched twin's checks
FLAT_FRAME_KINDS = tuple(kind for kind in classical_filters.KINDS if kind not in classical_filters.TURNING_KINDS)


# ----------------------------------------------------------------------------- consistency of each filter

@pytest.mark.parametrize("kind", FLAT_FRAME_KINDS)
@pytest.mark.parametrize("motion", ["straight", "turning"])
def test_filter_is_consistent_when_its_noise_covers_the_motion(kind, motion):
    """Each filter (CV 8 m/s^2, CA 3 m/s^3, IMM 1 m/s^2 + 3 m/s^3) tells the truth about its errors on a
    straight flight and on a 3 deg/s coordinated turn at 200 m/s, 60 scans, plots with 50/50/30 m noise.

    The statistic: at each scan after a burn-in of 5 updates, the ANEES over 20 independent runs is
    chi-square(3 x 20) / 20 for a consistent filter, so it lies in chi2.ppf([0.005, 0.995], 60) / 20
    (about 1.8-4.6) with probability 0.99. Scans are tested separately because a filter's errors are
    correlated in time, which would make an interval for the mean over all scans and runs too narrow
    (and the test flaky); at most the 99.9 % quantile of Binomial(scans, 0.01) scans (4 of 54) may fall
    outside. An overconfident filter leaves the interval at nearly every scan (next test).
    """
    times, truth = flight(STRAIGHT if motion == "straight" else TURNING)
    anees = anees_per_scan(settings(kind, MATCHED[kind]), times, truth, seed=1)
    outside = (anees < ANEES_BOUNDS[0]) | (anees > ANEES_BOUNDS[1])
    assert outside.sum() <= scans_allowed_outside(len(anees)), \
        f"{kind}, {motion} flight: ANEES outside {ANEES_BOUNDS.round(2)} at {outside.sum()} scans: {anees.round(2)}"
    assert 2.0 < anees.mean() < 4.0


@pytest.mark.parametrize("kind, noise_std", [("cv", (0.1,)), ("ca", (0.1,)), ("imm", (0.01, 0.1))])
def test_filter_with_too_little_noise_for_the_turn_is_overconfident(kind, noise_std):
    """The same check fails where it should: with process noise far below the 10.5 m/s^2 of the turn
    the filter lags the turn and claims errors far smaller than its own, at every scan."""
    times, truth = flight(TURNING)
    anees = anees_per_scan(settings(kind, noise_std), times, truth, seed=1)
    assert (anees > ANEES_BOUNDS[1]).all()


def test_imm_switches_to_the_turn_model_in_a_turn():
    """IMM (CV 1 m/s^2, CA 3 m/s^3): straight for 20 scans, a 3 deg/s turn for 60 s, straight again. The
    CA model's probability, averaged over 10 runs, stays low on the straight legs (after the first
    few updates) and is high through the turn."""
    before, turn, after = 20, 10, 20
    rates = np.concatenate([np.zeros(before), np.full(turn, 3.0), np.zeros(after - 1)])
    times, truth = flight(rates)
    imm = settings("imm", (1.0, 3.0))
    rng = np.random.default_rng(2)
    ca_probability = np.array([run_filter(imm, times, truth, rng)[1][:, 1] for _ in range(10)]).mean(axis=0)
    # The aircraft turns between plots `before` and `before + turn`; plot before + 1 is the first off the line.
    assert ca_probability[3:before + 1].max() < 0.5
    assert ca_probability[before + 2:before + turn + 1].mean() > 0.5
    assert ca_probability[before + turn + 4:].max() < 0.5


def test_imm_with_turns_takes_the_turn_of_the_aircrafts_direction_and_follows_it_closer(radar):
    """The IMM with turns (CV 1 m/s^2, turns of 6 deg/s with 1 m/s^2) in ECEF, where each turn is about the
    track's own vertical: a 250 m/s flight 40 km from the radar, straight for 15 scans, a 6 deg/s turn
    to the right for 10 scans (a fighter's, 26 m/s^2), straight again. Averaged over 10 runs, the right
    turn's model leads through the turn and the left one stays unlikely; through the turn its position
    error is below the CV + CA IMM's (1 m/s^2 + 3 m/s^3), which lags the turn."""
    before, turn, after = 15, 10, 15
    times, enu = flight(np.concatenate([np.zeros(before), np.full(turn, 6.0), np.zeros(after - 1)]),
                        start=(30e3, 25e3, 9000.0), speed=250.0)
    truth = to_ecef(enu, radar)
    turns = replace(settings("imm_ct", (1.0, 1.0)), turn_rate_dps=6.0)
    rng = np.random.default_rng(7)
    probabilities, errors = [], {"imm_ct": [], "imm": []}
    for _ in range(10):
        plots, covariance = radar_plots(truth, radar, rng)
        for kind, kind_settings in (("imm_ct", turns), ("imm", settings("imm", (1.0, 3.0)))):
            estimator = classical_filters.start_filter(kind_settings, plots[0], covariance[0])
            mu, error = [], []
            for k in range(1, len(times)):
                classical_filters.advance(estimator, kind_settings, times[k] - times[k - 1])
                classical_filters.update(estimator, plots[k], covariance[k])
                mu.append(classical_filters.model_probabilities(estimator))
                error.append(np.linalg.norm(classical_filters.posterior(estimator)[0][kind_settings.measured]
                                            - truth[k]))
            errors[kind].append(error)
            if kind == "imm_ct":
                probabilities.append(mu)
    mu = np.mean(probabilities, axis=0)   # (plots - 1, 3): CV, left, right
    in_turn = slice(before + 1, before + turn)  # plot k + 1 is at index k
    assert mu[in_turn, 2].mean() > 0.5 and mu[in_turn, 1].max() < 0.2
    assert mu[3:before, 0].mean() > 0.5
    assert np.mean(errors["imm_ct"], axis=0)[in_turn].mean() < np.mean(errors["imm"], axis=0)[in_turn].mean()


# ----------------------------------------------------------------------------- the batched twin

@pytest.fixture(scope="module")
def radar(make_params):
    return make_params(1).radar


def to_ecef(enu: np.ndarray, radar) -> np.ndarray:
    """Points of the radar's local east-north-up frame in ECEF."""
    return np.column_stack(pymap3d.enu2ecef(enu[:, 0], enu[:, 1], enu[:, 2], radar.latitude_deg, radar.longitude_deg,
                                            radar.height_m, ell=geodesy.WGS84_ELLIPSOID))


def radar_plots(truth_ecef: np.ndarray, radar, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Plots of true ECEF positions with the radar's noise, and that noise's (converted-measurement) covariance."""
    covariance = geodesy.measurement_covariance(truth_ecef, radar)
    noise = np.einsum("nij,nj->ni", np.linalg.cholesky(covariance), rng.normal(size=truth_ecef.shape))
    return truth_ecef + noise, covariance


def random_flight(rng: np.random.Generator, radar, scans: int) -> tuple[np.ndarray, np.ndarray]:
    """Times (from T0, one missed scan) and true ECEF positions of a flight 30-150 km from the radar,
    at 100-300 m/s, straight or turning at up to 3 deg/s."""
    distance, bearing = rng.uniform(30000.0, 150000.0), rng.uniform(0.0, 2 * np.pi)
    start = (distance * np.sin(bearing), distance * np.cos(bearing), rng.uniform(2000.0, 11000.0))
    rate = rng.choice([0.0, rng.uniform(-3.0, 3.0)])
    times, enu = flight(np.full(scans, rate), rng.uniform(0.0, 2 * np.pi), start, rng.uniform(100.0, 300.0))
    keep = np.arange(scans + 1) != scans // 2  # the radar missed one scan: a 12 s step
    return T0 + times[keep], to_ecef(enu[keep], radar)


def realistic_rows(radar, seed: int = 5, rows: int = 3, steps: int = 20):
    """Three rows of ECEF plots of random flights near the radar, with converted-measurement
    covariances: row 0 plain, row 1 restarted at step 9 with another flight, row 2 with two padding
    steps inside and four at the end."""
    rng = np.random.default_rng(seed)
    times, positions, covariances = np.empty((rows, steps)), np.empty((rows, steps, 3)), np.empty((rows, steps, 3, 3))
    for row in range(rows):
        times[row], truth = random_flight(rng, radar, steps)
        positions[row], covariances[row] = radar_plots(truth, radar, rng)
    other_times, truth = random_flight(rng, radar, steps - 9)
    times[1, 9:] = other_times + 3600.0
    positions[1, 9:], covariances[1, 9:] = radar_plots(truth, radar, rng)
    valid = np.ones((rows, steps), dtype=bool)
    restart = np.zeros((rows, steps), dtype=bool)
    restart[:, 0] = restart[1, 9] = True
    valid[2, [6, 7]] = valid[2, -4:] = False
    times[2, ~valid[2]], positions[2, ~valid[2]], covariances[2, ~valid[2]] = 0.0, 0.0, np.eye(3)  # never read
    return times, positions, covariances, valid, restart


def filterpy_reference(kind_settings: FilterSettings, times, positions, covariances, valid, restart):
    """What the tracker's per-track filterpy objects give for the same rows, one step at a time."""
    rows, steps = times.shape
    out_x, out_P = np.full((rows, steps, 3), np.nan), np.full((rows, steps, 3, 3), np.nan)
    probabilities = []
    measured = kind_settings.measured
    for row in range(rows):
        estimator, last = None, None
        for step in np.flatnonzero(valid[row]):
            if restart[row, step]:
                estimator = classical_filters.start_filter(kind_settings, positions[row, step], covariances[row, step])
            else:
                classical_filters.advance(estimator, kind_settings, times[row, step] - last)
                classical_filters.update(estimator, positions[row, step], covariances[row, step])
            last = times[row, step]
            x, P = classical_filters.posterior(estimator)
            out_x[row, step], out_P[row, step] = x[measured], P[np.ix_(measured, measured)]
        probabilities.append(classical_filters.model_probabilities(estimator))
    return out_x, out_P, np.array(probabilities)


@pytest.mark.parametrize("kind", classical_filters.KINDS)
def test_batched_filters_equal_filterpy_step_by_step(radar, kind):
    """`batch_filters.filter_sequences` (what tuning runs) gives filterpy's filtered positions and
    covariances at every plot, through a restart in the middle of a row and padding steps (NaN there),
    and ends with filterpy's mode probabilities."""
    rows = realistic_rows(radar)
    kind_settings = settings(kind, BATCH_NOISE[kind], velocity_std_mps=300.0)
    filtered = batch_filters.filter_sequences(kind_settings, *rows)
    x, P, last = filtered.position, filtered.covariance, filtered.last
    expected_x, expected_P, expected_probabilities = filterpy_reference(kind_settings, *rows)
    valid = rows[3]
    assert np.isnan(x[~valid]).all() and np.isnan(P[~valid]).all()
    np.testing.assert_allclose(x[valid], expected_x[valid], rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(P[valid], expected_P[valid], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(last.mu, expected_probabilities, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("kind", classical_filters.KINDS)
def test_innovation_distance_is_the_nis_the_tracker_gates_with(radar, kind):
    """`filter_sequences`'s innovation distance at each plot is d' S^-1 d of the plot against
    filterpy's prediction to its time (`predicted_gaussian`, the tracker's gate) with S = P + R;
    NaN where the row restarts or is padding."""
    times, positions, covariances, valid, restart = rows = realistic_rows(radar)
    kind_settings = settings(kind, BATCH_NOISE[kind], velocity_std_mps=300.0)
    distance = batch_filters.filter_sequences(kind_settings, *rows).innovation_distance
    measured = kind_settings.measured
    expected = np.full(times.shape, np.nan)
    for row in range(times.shape[0]):
        estimator, last = None, None
        for step in np.flatnonzero(valid[row]):
            if restart[row, step]:
                estimator = classical_filters.start_filter(kind_settings, positions[row, step], covariances[row, step])
            else:
                state, covariance = classical_filters.predicted_gaussian(estimator, kind_settings,
                                                                         times[row, step] - last)
                d = positions[row, step] - state[measured]
                S = covariance[np.ix_(measured, measured)] + covariances[row, step]
                expected[row, step] = d @ np.linalg.solve(S, d)
                classical_filters.advance(estimator, kind_settings, times[row, step] - last)
                classical_filters.update(estimator, positions[row, step], covariances[row, step])
            last = times[row, step]
    assert np.isnan(distance[np.isnan(expected)]).all()
    np.testing.assert_allclose(distance[~np.isnan(expected)], expected[~np.isnan(expected)], rtol=1e-8)


@pytest.mark.parametrize("kind", classical_filters.KINDS)
def test_gating_prediction_is_the_filters_own_prediction(radar, kind):
    """`predicted_gaussian` (what the tracker gates with) leaves the filter unchanged and gives what
    advancing it would: for the IMM the models' predictions mixed with the predicted mode
    probabilities (c-bar). The batched filters predict the same."""
    times, positions, covariances, _, _ = realistic_rows(radar)
    kind_settings = settings(kind, BATCH_NOISE[kind], velocity_std_mps=300.0)
    estimator = classical_filters.start_filter(kind_settings, positions[0, 0], covariances[0, 0])
    for k in range(1, 8):
        classical_filters.advance(estimator, kind_settings, times[0, k] - times[0, k - 1])
        classical_filters.update(estimator, positions[0, k], covariances[0, k])
    before = classical_filters.posterior(estimator)[0].copy()
    state, covariance = classical_filters.predicted_gaussian(estimator, kind_settings, 9.0)
    np.testing.assert_array_equal(classical_filters.posterior(estimator)[0], before)

    probabilities = estimator.cbar.copy() if kind_settings.is_imm else np.ones(1)
    classical_filters.advance(estimator, kind_settings, 9.0)
    models = estimator.filters if kind_settings.is_imm else [estimator]
    mean = sum(p * f.x for p, f in zip(probabilities, models))
    spread = sum(p * (f.P + np.outer(f.x - mean, f.x - mean)) for p, f in zip(probabilities, models))
    np.testing.assert_allclose(state, mean, rtol=1e-12)
    np.testing.assert_allclose(covariance, spread, rtol=1e-9, atol=1e-6)

    batch = batch_filters.filter_sequences(kind_settings, times[:1, :8], positions[:1, :8], covariances[:1, :8],
                                           np.ones((1, 8), bool), np.eye(1, 8, dtype=bool)).last
    measured = kind_settings.measured
    x, P = batch_filters.predict_positions(kind_settings, batch, np.array([9.0]))
    np.testing.assert_allclose(x[0], state[measured], rtol=1e-12)
    np.testing.assert_allclose(P[0], covariance[np.ix_(measured, measured)], rtol=1e-9, atol=1e-6)


# ----------------------------------------------------------------------------- tuning material and tuning

Point = tuple[float, float, float]


def plots_table(rows: list[tuple[int, float, Point, Point | None]]) -> pa.Table:
    """A simulated-plots table with the columns tuning reads, from (scenario, time, plot position,
    true position or None for a false plot) rows in any order."""
    truth = [t if t is not None else (np.nan,) * 3 for _, _, _, t in rows]
    columns = {"scenario_id": pa.array([r[0] for r in rows], pa.int32()),
               "time_unix_s": pa.array([r[1] for r in rows], pa.float64()),
               "is_target": pa.array([r[3] is not None for r in rows])}
    for axis, name in enumerate("xyz"):
        columns[f"{name}_ecef_m"] = pa.array([r[2][axis] for r in rows], pa.float64())
        columns[f"true_{name}_ecef_m"] = pa.array([t[axis] for t in truth], pa.float64())
    return pa.table(columns)


def test_target_sequences_restart_after_gaps_and_routes_and_skip_the_burn_in(radar):
    """Tuning material from a hand-made table: route 1 has plots at 0-12 s and, after a 30 s gap
    (restart_gap_s = 24), at 42-60 s; route 2 at 0-12 s and, after exactly 24 s (no restart),
    at 36 s; false plots are left out. Each (re)start begins a sequence; the first burn_in = 3
    plots of each are not scored, and the tracker gates with the filter from the third plot
    (gated_from = 2: the start and one update are gated by the young-track radius)."""
    point = to_ecef(np.array([[30000.0, 40000.0, 9000.0]]), radar)[0]
    rows, expected = [], {}  # expected: plot x -> (restart, scored, gated)
    for scenario, times, restarts in ((1, [0.0, 6.0, 12.0, 42.0, 48.0, 54.0, 60.0], {0.0, 42.0}),
                                      (2, [0.0, 6.0, 12.0, 36.0], {0.0})):
        since = 0
        for time in times:
            since = 0 if time in restarts else since + 1
            x = point[0] + 1000.0 * scenario + time      # identifies the plot
            rows.append((scenario, T0 + time, (x, point[1], point[2]), (x + 40.0, point[1], point[2])))
            expected[x] = (time in restarts, since >= 3, since >= 2)
    rows += [(1, T0 + 3.0, tuple(point + 5e4), None), (2, T0 + 20.0, tuple(point - 5e4), None)]
    material = tuning.target_sequences(plots_table(rows[::-1]), radar, restart_gap_s=24.0, burn_in_updates=3,
                                       gate_probability=0.995, gated_from=2)

    valid = material.valid
    assert valid.sum() == len(expected) == 11
    got = {float(x): (bool(r), bool(s), bool(g)) for x, r, s, g in zip(
        material.positions[valid][:, 0], material.restart[valid], material.scored[valid], material.gated[valid])}
    assert got == expected
    assert not (material.restart | material.scored | material.gated)[~valid].any()
    np.testing.assert_allclose(material.truth[valid][:, 0] - material.positions[valid][:, 0], 40.0)
    # Between restarts a row runs forward in time, so each sequence is one route's plots in order.
    for row in range(valid.shape[0]):
        steps = np.flatnonzero(valid[row])
        assert material.restart[row, steps[0]]
        following = steps[1:][~material.restart[row, steps[1:]]]
        assert (material.times[row, following] > material.times[row, following - 1]).all()
    np.testing.assert_allclose(material.covariances[valid],
                               geodesy.measurement_covariance(material.positions[valid], radar))


@pytest.fixture(scope="module")
def material(radar) -> tuning.Sequences:
    """Tuning material from 8 random flights of 16 plots with the radar's noise (two flights per
    scenario an hour apart, so also restarted by the gap), and some false plots."""
    rng = np.random.default_rng(3)
    rows = []
    for index in range(8):
        times, truth = random_flight(rng, radar, 16)
        plots, _ = radar_plots(truth, radar, rng)
        rows += [(index // 2, t + 3600.0 * (index % 2), tuple(p), tuple(e)) for t, p, e in zip(times, plots, truth)]
    clutter = to_ecef(rng.uniform([-1e5, -1e5, 1000.0], [1e5, 1e5, 12000.0], (30, 3)), radar)
    rows += [(index % 4, T0 + rng.uniform(0.0, 100.0), tuple(p), None) for index, p in enumerate(clutter)]
    return tuning.target_sequences(plots_table(rows), radar, restart_gap_s=24.0, burn_in_updates=3,
                                   gate_probability=0.995, gated_from=2)


@pytest.mark.parametrize("cost, start_noise", [("rmse", 200.0), ("nees", 0.05), ("rmse_in_gate", 0.05)])
def test_tuning_lowers_its_cost_from_a_bad_start(material, cost, start_noise):
    """CV tuning on a few random flights: from 200 m/s^2 of process noise (far too much for airliners:
    the estimate follows the plots' noise) to a lower RMSE, and from 0.05 m/s^2 (far too little: the
    filter lags the turns and is overconfident) to an ANEES nearer 3 (cost |ln(ANEES / 3)|), or to
    a filter whose gate keeps the target's plots as often as it promises (`rmse_in_gate`)."""
    start = settings("cv", (start_noise,), velocity_std_mps=400.0)
    tuned, before, after, evaluations = tuning.tune(start, material, cost, 200)
    assert after.cost(cost) < before.cost(cost)
    assert after.cost(cost) == pytest.approx(tuning.assess(tuned, material).cost(cost))
    if cost == "rmse":
        assert tuned.noise_std[0] < start_noise and after.rmse_m < after.plot_rmse_m
    elif cost == "nees":
        assert tuned.noise_std[0] > start_noise and after.anees_bounds[0] < after.anees < after.anees_bounds[1]
    else:
        assert before.gate_misses > 5 * before.gate_allowance
        assert tuned.noise_std[0] > start_noise and after.gate_misses < 2 * after.gate_allowance
    assert after.samples == before.samples == material.scored.sum()
    assert evaluations > 1


def test_imm_tuning_searches_the_switch_probability_too(material):
    """The IMM's switch probability is tuned with its noise (log-odds, within a factor of 1000 of the
    start odds): from a start of 1e-6 (the IMM never leaves the mode it starts in) the tuner moves
    it, keeps it a probability, and reports the values that ended at the search's edge by name."""
    start = replace(settings("imm", (1.0, 3.0)), switch_probability=1e-6)
    tuned, before, after, _ = tuning.tune(start, material, "rmse_in_gate", 300)
    assert 0.0 < tuned.switch_probability < 1.0 and tuned.switch_probability != start.switch_probability
    assert after.cost("rmse_in_gate") <= before.cost("rmse_in_gate")
    assert set(tuning.at_bounds(start, tuned)) <= {"noise_std[0]", "noise_std[1]", "velocity_std_mps",
                                                     "switch_probability"}
    assert tuning.at_bounds(start, replace(start, switch_probability=1e-6 * 1000.1)) == ["switch_probability"]
    assert "switch_probability" not in tuning.at_bounds(settings("cv", (1.0,)), settings("cv", (1.0,)))


def test_imm_with_turns_tuning_searches_its_turn_rate_too(material):
    """The IMM with turns tunes its turns' rate with its noise, switch probability and velocity spread (log,
    within a factor of 1000 of the start), names it when it ends at the search's edge, and lowers its cost."""
    start = replace(settings("imm_ct", (1.0, 1.0)), turn_rate_dps=0.5)
    tuned, before, after, _ = tuning.tune(start, material, "rmse_in_gate", 300)
    assert tuned.turn_rate_dps != start.turn_rate_dps and tuned.turn_rate_dps > 0.0
    assert after.cost("rmse_in_gate") <= before.cost("rmse_in_gate")
    assert tuning.at_bounds(start, replace(start, turn_rate_dps=0.5 * 1000.1)) == ["turn_rate_dps"]
    assert "turn_rate_dps" not in tuning.at_bounds(settings("imm", (1.0, 3.0)), settings("imm", (1.0, 3.0)))


def test_tuning_that_does_not_converge_raises_with_the_values_reached(material):
    """With one Nelder-Mead iteration tuning fails: TuningError naming the filter and the values it reached."""
    start = settings("imm", (1.0, 3.0))
    with pytest.raises(tuning.TuningError, match=r"imm: Nelder-Mead did not converge .* noise \(.*velocity spread"):
        tuning.tune(start, material, "rmse", 1)



@pytest.mark.parametrize("bad", ["negative", "nan"])
def test_assessment_rejects_a_covariance_that_is_not_positive_definite(material, monkeypatch, bad):
    """A filtered position covariance that is not positive definite (here one with a negative
    eigenvalue, or NaN) at one scored plot makes `assess` raise TuningError naming the filter."""
    filter_sequences = batch_filters.filter_sequences

    def spoilt(*args):
        filtered = filter_sequences(*args)
        row, step = np.argwhere(material.scored)[len(np.argwhere(material.scored)) // 2]
        filtered.covariance[row, step] = np.diag([1e4, -1.0, 1e4]) if bad == "negative" else np.nan
        return filtered

    monkeypatch.setattr(batch_filters, "filter_sequences", spoilt)
    with pytest.raises(tuning.TuningError, match=r"cv: a position covariance is not positive definite"):
        tuning.assess(settings("cv", (5.0,)), material)


def test_inverse3_is_the_inverse_and_determinant():
    """`batch_filters.inverse3` (cofactors) gives numpy's inverse and determinant of 3 x 3 covariances
    like the filters' (metres^2, correlated), batched over leading axes."""
    rng = np.random.default_rng(4)
    factor = rng.normal(size=(4, 5, 3, 3)) * [300.0, 50.0, 20.0]
    S = factor @ np.swapaxes(factor, -1, -2) + np.eye(3)
    inverse, determinant = batch_filters.inverse3(S)
    np.testing.assert_allclose(inverse, np.linalg.inv(S), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(determinant, np.linalg.det(S), rtol=1e-9)


@pytest.mark.parametrize("kind", ["cv", "imm"])
def test_update_takes_a_given_innovation_inverse_but_the_imm_refuses_one(kind):
    """`batch_filters.updated` with S^-1 given (as the tracker's chi-square gate hands it on) gives
    the update that inverts S itself, to the bit; the IMM, whose mode probabilities need S's
    determinant too, refuses one."""
    filters = settings(kind, (5.0, 0.5) if kind == "imm" else (5.0,))
    rng = np.random.default_rng(6)
    z = rng.normal(0.0, 100.0, (4, 3))
    R = np.tile(np.diag([2500.0, 2500.0, 900.0]), (4, 1, 1))
    F_and_Q = batch_filters.motion(filters, np.full(4, 6.0))
    prior = batch_filters.predicted(filters, batch_filters.start(filters, z, R), F_and_Q[:, 0], F_and_Q[:, 1])
    position = slice(None, None, prior.x.shape[-1] // 3)
    S_inverse, _ = batch_filters.inverse3(prior.P[..., position, position] + R[:, None])
    own = batch_filters.updated(filters, prior, z + 50.0, R)
    if kind == "imm":
        with pytest.raises(ValueError, match="determinant"):
            batch_filters.updated(filters, prior, z + 50.0, R, S_inverse)
        return
    given = batch_filters.updated(filters, prior, z + 50.0, R, S_inverse)
    np.testing.assert_array_equal(given.x, own.x)
    np.testing.assert_array_equal(given.P, own.P)


# ----------------------------------------------------------------------------- OSPA

def test_ospa_of_hand_computed_cases():
    """OSPA (cutoff c, order p): nothing vs nothing is 0, anything vs nothing is c, a matched pair costs
    its distance cut at c, an extra estimate costs c, averaged over the larger set."""
    assert ospa.ospa(np.empty((0, 0)), 2000.0, 2.0) == 0.0
    assert ospa.ospa(np.empty((0, 1)), 2000.0, 2.0) == 2000.0
    assert ospa.ospa(np.empty((2, 0)), 2000.0, 2.0) == 2000.0
    assert ospa.ospa(np.array([[300.0]]), 2000.0, 2.0) == pytest.approx(300.0)
    assert ospa.ospa(np.array([[5000.0]]), 2000.0, 2.0) == pytest.approx(2000.0)
    two_estimates = np.array([[100.0], [400.0]])  # one truth: the nearer is matched, the other is false
    assert ospa.ospa(two_estimates, 1000.0, 2.0) == pytest.approx(np.sqrt((100.0 ** 2 + 1000.0 ** 2) / 2))
    # Two of each: the best assignment (100 + 200), not the crossed one; order 1 averages distances.
    assert ospa.ospa(np.array([[100.0, 900.0], [800.0, 200.0]]), 1000.0, 1.0) == pytest.approx(150.0)


def test_scan_ospa_counts_misses_and_false_tracks_at_the_cutoff():
    """OSPA per scan of a tracker run on one target (cutoff 1000 m): scan 0 the target is in coverage
    but only a new, unconfirmed track -> 1000; scan 1 a confirmed track, updated twice, its last
    update 300 m off -> 300; scan 2 neither target nor track -> 0; scan 3 a confirmed track but the
    target out of coverage -> 1000; scan 4 in coverage, the track below the confirmed weight -> 1000."""

    def truth_at(times):
        return np.column_stack([100.0 * times, np.zeros_like(times), np.full_like(times, 9000.0)])

    # (scan, track, time, offset from the truth along y, weight, association)
    rows = [(0, 1, 1.0, 50.0, 0.2, "start"),
            (1, 1, 6.5, 700.0, 0.8, "imm"), (1, 1, 7.0, 300.0, 0.8, "imm"),
            (3, 1, 19.0, 10.0, 0.8, "imm"),
            (4, 2, 25.0, 10.0, 0.4, "radius")]
    times = np.array([r[2] for r in rows])
    positions = truth_at(times) + np.column_stack([np.zeros(len(rows)), [r[3] for r in rows], np.zeros(len(rows))])
    updates = {"track_id": np.array([r[1] for r in rows]), "time_unix_s": times,
               "plot_id": np.arange(len(rows)), "x_ecef_m": positions[:, 0], "y_ecef_m": positions[:, 1],
               "z_ecef_m": positions[:, 2], "weight": np.array([r[4] for r in rows]),
               "association": np.array([r[5] for r in rows]), "association_error": np.zeros(len(rows))}
    rule = ThesisWeights(start=0.2, candidate=0.6, confirmed_weight=0.8, step=0.2, silence_s=12.0)
    result = ospa.scan_ospa(updates, np.array([r[0] for r in rows]), management=rule,
                            scans_in_coverage=np.array([0, 1, 4]), all_scans=np.arange(5), truth_at=truth_at,
                            cutoff=1000.0, order=2.0)
    np.testing.assert_allclose(result, [1000.0, 300.0, 0.0, 1000.0, 1000.0])


# ----------------------------------------------------------------------------- motion models

@pytest.mark.parametrize("model, dim", [("cv", 2), ("ca", 3)])
def test_process_noise_is_filterpys_white_noise_model(model, dim):
    """Q of cv and ca is filterpy's Q_discrete_white_noise (three axes, state ordered by axis), for one
    dt and for an array of dt (one Q per entry)."""
    for dt in (0.5, 6.0, 12.0):
        expected = Q_discrete_white_noise(dim=dim, dt=dt, var=7.0 ** 2, block_size=3, order_by_dim=True)
        np.testing.assert_allclose(motion_models.process_noise(model, dt, 7.0), expected, rtol=1e-12)
    dts = np.array([[0.5, 6.0], [12.0, 3.0]])
    batched = motion_models.process_noise(model, dts, 7.0)
    assert batched.shape == (2, 2, 3 * dim, 3 * dim)
    for index in np.ndindex(dts.shape):
        expected = Q_discrete_white_noise(dim=dim, dt=dts[index], var=49.0, block_size=3, order_by_dim=True)
        np.testing.assert_allclose(batched[index], expected, rtol=1e-12)


def test_constant_acceleration_transition_moves_a_state_exactly():
    """F of ca carries [x, vx, ax, y, ...] along constant acceleration: x + v t + a t^2 / 2, v + a t, a."""
    position, velocity = np.array([1e3, -2e3, 8e3]), np.array([200.0, -50.0, 3.0])
    acceleration = np.array([2.0, -1.0, 0.5])
    state = np.column_stack([position, velocity, acceleration]).reshape(-1)
    for dt in (6.0, 12.5):
        moved = (motion_models.transition("ca", dt) @ state).reshape(3, 3)
        np.testing.assert_allclose(moved[:, 0], position + velocity * dt + acceleration * dt ** 2 / 2, rtol=1e-14)
        np.testing.assert_allclose(moved[:, 1], velocity + acceleration * dt, rtol=1e-14)
        np.testing.assert_allclose(moved[:, 2], acceleration, rtol=1e-14)


# ----------------------------------------------------------------------------- params

@pytest.mark.parametrize("key, value", [
    ("cost", "mae"),
    ("split", "nowhere"),
    ("imm_noise_std", [1.0]),
    ("cv_noise_std", [-1.0]),
    ("ca_noise_std", 1.0),
    ("max_iterations", 0),
    ("imm_switch_probability", 0.0),
    ("imm_switch_probability", 1.0),
    ("imm_initial_cv_probability", 1.5),
    ("restart_gap_s", 0.0),
    ("imm_ct_noise_std", [1.0, 1.0, 1.0]),
    ("imm_ca_ct_noise_std", [1.0, 3.0]),
    ("imm_ct_turn_rate_dps", 0.0),
    ("filters", ["cv", "ca"]),
    ("filters", ["cv", "ca", "imm", "imm"]),
    ("filters", ["cv", "ca", "imm", "singer"]),
])
def test_kalman_params_reject_bad_values_naming_the_key(params_tree, key, value):
    """params.yaml's `kalman` section: a bad value is a ParamError that names kalman.<key>."""
    params_tree["kalman"][key] = value
    with pytest.raises(ParamError, match=rf"kalman\.{key}\b"):
        parse_params(params_tree)


# ----------------------------------------------------------------------------- the tune_kalman stage

TUNE_TARGET_PLOTS = 25  # of each simulated route: tuning time grows with the longest sequence


@pytest.fixture(scope="module")
def simulated_split(make_params, tmp_path_factory) -> tuple[object, Path]:
    """One constant-jerk and one random-turns route of the training split, simulated, and all their
    plots up to each route's 25th target plot, written as <folder>/train/plots.parquet."""
    params = make_params(1)
    split = params.routes.split(params.kalman.split)
    plots, _ = simulate.simulate_split(params, split, routes.generate_split(params, split))
    time, scenario = plots.column("time_unix_s").to_numpy(), plots.column("scenario_id").to_numpy()
    target = plots.column("is_target").to_numpy()
    last = {s: np.sort(time[(scenario == s) & target])[:TUNE_TARGET_PLOTS][-1] for s in np.unique(scenario)}
    keep = time <= np.array([last[s] for s in scenario])
    folder = tmp_path_factory.mktemp("tune") / "simulated"
    io.write_parquet(plots.filter(pa.array(keep)), folder / params.kalman.split / "plots.parquet")
    return params, folder


@pytest.fixture(scope="module")
def tracking_uri(tmp_path_factory) -> str:
    """An MLflow store in a temporary SQLite file, shared by the stage tests (creating one takes seconds)."""
    return f"sqlite:///{tmp_path_factory.mktemp('mlflow') / 'mlflow.db'}"


def test_tune_stage_saves_tuned_filters_and_a_report(simulated_split, tracking_uri, tmp_path, monkeypatch):
    """tune_kalman on a tiny simulated split: models/kalman_tuned.json loads as the tuned filters
    of kalman.filters, reports/kalman_tuning.json has each filter's cost before and after (not higher after),
    and one MLflow run records them."""
    import mlflow

    params, simulated = simulated_split
    monkeypatch.setenv("MLFLOW_TRACKING_URI", tracking_uri)
    run_tune(params, simulated, tmp_path / "models", tmp_path / "reports")

    filters = classical_filters.load_settings(tmp_path / "models" / "kalman_tuned.json")
    assert set(filters) == set(params.kalman.filters) == {"cv", "ca", "imm", "imm_ct"}
    assert all(filters[kind].kind == kind for kind in filters)
    report = json.loads((tmp_path / "reports" / "kalman_tuning.json").read_text())
    assert report["cost"] == params.kalman.cost
    for kind in params.kalman.filters:
        entry = report["filters"][kind]
        assert entry["cost_after"] <= entry["cost_before"]
        # the report's figures to six significant digits (`io.write_metrics`), the model file's whole
        assert entry["noise_std"] == pytest.approx(list(filters[kind].noise_std), rel=1e-5)
        assert entry["switch_probability"] == pytest.approx(filters[kind].switch_probability, rel=1e-5)
    table = tuning_table(report).splitlines()
    imm_row = next(line for line in table if line.startswith("| IMM"))
    assert "model switch probability" in table[0] and f"| {filters['imm'].switch_probability:.3g} |" in imm_row
    assert "| - |" in next(line for line in table if line.startswith("| Kalman CV"))
    client = mlflow.MlflowClient(tracking_uri=tracking_uri)
    runs = client.search_runs([client.get_experiment_by_name(params.training.experiment).experiment_id])
    assert len(runs) == 1 and runs[0].data.tags["stage"] == "tune_kalman"
    assert runs[0].data.metrics["imm.cost_after"] == pytest.approx(report["filters"]["imm"]["cost_after"], rel=1e-5)


def test_tune_stage_that_does_not_converge_saves_nothing(simulated_split, make_params, tracking_uri, tmp_path,
                                                        monkeypatch):
    """With kalman.max_iterations = 1 the stage stops with TuningError and writes no tuned filters."""
    _, simulated = simulated_split
    monkeypatch.setenv("MLFLOW_TRACKING_URI", tracking_uri)
    with pytest.raises(tuning.TuningError, match=r"cv: Nelder-Mead did not converge"):
        run_tune(make_params(1, {"kalman.max_iterations": 1}), simulated, tmp_path / "models", tmp_path / "reports")
    assert not (tmp_path / "models" / "kalman_tuned.json").exists()
    assert not (tmp_path / "reports" / "kalman_tuning.json").exists()


def test_tune_stage_with_an_unreachable_scheduler_stops_naming_it_and_saves_nothing(simulated_split, make_params,
                                                                                     tracking_uri, tmp_path,
                                                                                     monkeypatch):
    _, simulated = simulated_split
    monkeypatch.setenv("MLFLOW_TRACKING_URI", tracking_uri)
    with dask.config.set({"scheduler-address": "tcp://127.0.0.1:9"}), pytest.raises(
            engine.SchedulerUnreachable, match="DASK_SCHEDULER_ADDRESS=tcp://127.0.0.1:9"):
        run_tune(make_params(1), simulated, tmp_path / "models", tmp_path / "reports")
    assert not (tmp_path / "models").exists() or not any((tmp_path / "models").iterdir())
    assert not (tmp_path / "reports").exists() or not any((tmp_path / "reports").iterdir())


def test_tune_stage_gives_the_same_files_with_one_and_two_workers(simulated_split, make_params, tracking_uri,
                                                                  tmp_path, monkeypatch, caplog):
    """compute.workers = 1 tunes the filters in the stage's process, 2 on a local Dask cluster of
    two worker processes: models/kalman_tuned.json is byte for byte the same, and so is reports/kalman_tuning.json
    (each filter's `seconds` is apart, in reports/timings/). The workers' progress lines reach the stage's log."""
    _, simulated = simulated_split
    monkeypatch.setenv("MLFLOW_TRACKING_URI", tracking_uri)
    outputs = {}
    for workers in (1, 2):
        folder = tmp_path / f"workers-{workers}"
        with caplog.at_level("INFO", logger="pipeline"):
            run_tune(make_params(1, {"compute.workers": workers}), simulated, folder / "models", folder / "reports")
        timings = json.loads((folder / "reports" / "timings" / "kalman_tuning.json").read_text())
        assert all(entry["seconds"] > 0 for entry in timings["filters"].values())
        outputs[workers] = ((folder / "models" / "kalman_tuned.json").read_bytes(),
                            (folder / "reports" / "kalman_tuning.json").read_bytes())
    assert outputs[1][0] == outputs[2][0]
    assert outputs[1][1] == outputs[2][1]
    heads = {(record.getMessage().split(":")[0], record.processName == "MainProcess") for record in caplog.records}
    tuned = make_params(1).kalman.filters
    assert {(f"tune_kalman {kind}", True) for kind in tuned} <= heads  # each result as it arrives
    assert {(f"tune {kind}", False) for kind in tuned} <= heads       # progress, from the workers

"""The differentiable torch Kalman core (`pipeline.filters.torch_filters`) and Singer's model.

The torch filters are checked against the NumPy core (`pipeline.filters.batch_filters`), step by step and
over padded, restarted sequences, and Singer's model against filterpy's KalmanFilter; then what the
torch side adds: per-step scales, gradients cut by truncated BPTT, and learning a noise scale.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from filterpy.kalman import KalmanFilter
from scipy.linalg import expm

from pipeline.filters import batch_filters, motion_models, torch_filters, tuning
from pipeline.filters.torch_filters import FilterSpec, Scales, SequenceBatch
from tests.test_classical import plots_table, radar_plots, random_flight, realistic_rows, settings

NOISE = {"cv": (5.0,), "ca": (2.0,), "imm": (1.0, 3.0)}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def radar(make_params):
    return make_params(1).radar


@pytest.fixture(scope="module")
def material(radar) -> tuning.Sequences:
    """Tuning material: 6 random flights of 16 plots with the radar's noise, two per scenario an hour apart."""
    rng = np.random.default_rng(3)
    rows = []
    for index in range(6):
        times, truth = random_flight(rng, radar, 16)
        plots, _ = radar_plots(truth, radar, rng)
        rows += [(index // 2, t + 3600.0 * (index % 2), tuple(p), tuple(e)) for t, p, e in zip(times, plots, truth)]
    return tuning.target_sequences(plots_table(rows), radar, restart_gap_s=24.0, burn_in_updates=3,
                                   gate_probability=0.995, gated_from=2)


def tensors(*arrays: np.ndarray) -> list[torch.Tensor]:
    return [torch.as_tensor(np.array(array)) for array in arrays]


def singer_spec(manoeuvre_time_s: float = 20.0, sigma_m: float = 4.0) -> FilterSpec:
    return FilterSpec("singer", (sigma_m,), 300.0, 20.0, manoeuvre_time_s=manoeuvre_time_s)


def local_sequence(seed: int = 7, rows: int = 5, steps: int = 25):
    """A fixed random sequence in a local frame: times with steps of 1-12 s, plots along noisy
    straight-and-curving paths 10-100 km away, each with its own random covariance (m^2)."""
    rng = np.random.default_rng(seed)
    dt = rng.uniform(1.0, 12.0, (rows, steps))
    acceleration = rng.normal(0.0, 3.0, (rows, steps, 3)).cumsum(axis=1) * 0.2
    velocity = rng.uniform(-250.0, 250.0, (rows, 1, 3)) + (acceleration * dt[..., None]).cumsum(axis=1)
    positions = rng.uniform(1e4, 1e5, (rows, 1, 3)) + (velocity * dt[..., None]).cumsum(axis=1)
    factor = rng.normal(size=(rows, steps, 3, 3)) * [80.0, 40.0, 20.0]
    covariances = factor @ np.swapaxes(factor, -1, -2) + 100.0 * np.eye(3)
    noisy = positions + np.einsum("btij,btj->bti", np.linalg.cholesky(covariances), rng.normal(size=positions.shape))
    return dt, noisy, covariances


# ----------------------------------------------------------------------------- Singer's model (NumPy)

def van_loan(dt: float, alpha: float, variance: float) -> tuple[np.ndarray, np.ndarray]:
    """F and Q of da/dt = -alpha a + w (w of spectral density 2 alpha variance) for one axis, by Van
    Loan's matrix exponential (1978): independent of the closed forms."""
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -alpha]])
    M = np.zeros((6, 6))
    M[:3, :3], M[3:, 3:], M[2, 5] = -A, A.T, 2 * alpha * variance
    E = expm(M * dt)
    F = E[3:, 3:].T
    return F, F @ E[:3, 3:]


def test_singer_model_is_a_first_order_markov_acceleration():
    """motion_models' singer F and Q (three axes, state [x, vx, ax, ...]) equal Van Loan's matrix
    exponential of Singer's continuous model, on both sides of the series threshold (u = alpha dt from
    1e-6 to 2.4), for one dt and for an array; a track starts with the acceleration spread as ca."""
    for dt, tau in ((6.0, 1e6), (1.0, 1000.0), (6.0, 60.0), (6.0, 12.01), (6.0, 11.99), (3.0, 6.0), (12.0, 5.0)):
        F, Q = van_loan(dt, 1.0 / tau, 4.0 ** 2)
        np.testing.assert_allclose(motion_models.transition("singer", dt, tau), np.kron(np.eye(3), F),
                                   rtol=1e-12, atol=1e-11)
        np.testing.assert_allclose(motion_models.process_noise("singer", dt, 4.0, tau), np.kron(np.eye(3), Q),
                                   rtol=1e-10, atol=1e-13 * np.abs(Q).max())
    dts = np.array([[0.5, 6.0], [12.0, 3.0]])
    batched = motion_models.process_noise("singer", dts, 4.0, 20.0)
    assert batched.shape == (2, 2, 9, 9)
    np.testing.assert_allclose(batched[1, 0], motion_models.process_noise("singer", 12.0, 4.0, 20.0), rtol=1e-15)
    _, spread = motion_models.initial_state("singer", np.zeros(3), np.eye(3), 300.0, 20.0)
    np.testing.assert_array_equal(spread, motion_models.initial_state("ca", np.zeros(3), np.eye(3), 300.0, 20.0)[1])


@pytest.mark.parametrize("tau", [None, 0.0, -5.0])
def test_singer_model_needs_a_positive_manoeuvre_time(tau):
    with pytest.raises(ValueError, match="singer: manoeuvre_time_s"):
        motion_models.transition("singer", 6.0, tau)


# ----------------------------------------------------------------------------- equal to the NumPy core

@pytest.mark.parametrize("model", ["cv", "ca", "cv9", "singer"])
def test_torch_motion_is_motion_models(model):
    """torch_filters.motion gives motion_models' F and Q for every dt of a batch (float64)."""
    dt = np.array([0.0, 0.5, 6.0, 12.0, 30.0])
    kind = {"cv9": "imm"}.get(model, model)
    spec = singer_spec(15.0) if kind == "singer" else FilterSpec.from_settings(settings(kind, NOISE[kind]))
    noise, index = dict(zip(spec.models, spec.noise_std.tolist())), spec.models.index(model)
    F, Q = torch_filters.motion(spec, torch.as_tensor(dt))
    extra = (15.0,) if model == "singer" else ()
    np.testing.assert_allclose(F[:, index].numpy(), motion_models.transition(model, dt, *extra), rtol=1e-14)
    np.testing.assert_allclose(Q[:, index].numpy(), motion_models.process_noise(model, dt, noise[model], *extra),
                               rtol=1e-13, atol=1e-300)


@pytest.mark.parametrize("kind", ["cv", "ca", "imm"])
def test_torch_filter_equals_the_numpy_core_step_by_step(kind):
    """From the same start, each predict (mixing, F, Q) and update (z, R) of the torch filter gives the
    NumPy core's states, covariances and mode probabilities (every entry, not just the position), and
    its combined position estimates, at each of 25 steps of 5 tracks with their own time steps and
    measurement covariances."""
    dt, z, R = local_sequence()
    kind_settings = settings(kind, NOISE[kind], velocity_std_mps=300.0)
    spec = FilterSpec.from_settings(kind_settings)
    expected = batch_filters.start(kind_settings, z[:, 0], R[:, 0])
    state = torch_filters.start(spec, *tensors(z[:, 0], R[:, 0]))
    for step in range(1, dt.shape[1]):
        F_and_Q = batch_filters.motion(kind_settings, dt[:, step])
        expected = batch_filters.updated(kind_settings, batch_filters.predicted(kind_settings, expected, F_and_Q[:, 0],
                                                                                F_and_Q[:, 1]), z[:, step], R[:, step])
        prior = torch_filters.predicted(spec, state, *torch_filters.motion(spec, torch.as_tensor(dt[:, step])))
        state = torch_filters.updated(spec, prior, *tensors(z[:, step], R[:, step]))
        pairs = [(state.x, expected.x), (state.P, expected.P), (state.mu, expected.mu)]
        pairs += zip(torch_filters.position_estimates(state), batch_filters.position_estimates(expected))
        for got, want in pairs:
            np.testing.assert_allclose(got.numpy(), want, rtol=1e-12, atol=1e-9, err_msg=f"step {step}")
    if kind == "imm":
        assert 0.01 < expected.mu.min() and expected.mu.max() < 0.99  # the models' probabilities did move


def test_torch_singer_equals_filterpy():
    """The torch singer filter, each track's manoeuvre frequency scaled by its own factor, gives at
    every step the positions and full covariances of a filterpy KalmanFilter stepped with
    motion_models' singer F and Q for tau / factor."""
    dt, z, R = local_sequence(seed=8, rows=3)
    factor = np.array([1.0, 0.3, 4.0])
    spec = singer_spec(20.0, 4.0)
    times = np.cumsum(dt, axis=1)
    valid, restart = np.ones(dt.shape, bool), np.arange(dt.shape[1]) == 0
    restart = np.broadcast_to(restart, dt.shape)
    filtered = torch_filters.filter_sequences(spec, *tensors(times, z, R, valid, restart),
                                              scales=Scales(manoeuvre=torch.as_tensor(np.repeat(factor[:, None],
                                                                                                dt.shape[1], 1))))
    measured = motion_models.measured_indices("singer")
    for row in range(3):
        kf = KalmanFilter(dim_x=9, dim_z=3)
        kf.x, kf.P = motion_models.initial_state("singer", z[row, 0], R[row, 0], 300.0, 20.0)
        kf.H = motion_models.measurement_matrix("singer")
        for step in range(1, dt.shape[1]):
            tau = 20.0 / factor[row]
            kf.predict(F=motion_models.transition("singer", dt[row, step], tau),
                       Q=motion_models.process_noise("singer", dt[row, step], 4.0, tau))
            kf.update(z[row, step], R=R[row, step])
            np.testing.assert_allclose(filtered.position[row, step].numpy(), kf.x[measured], rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(filtered.covariance[row, step].numpy(), kf.P[np.ix_(measured, measured)],
                                       rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(filtered.last.P[row, 0].numpy(), kf.P, rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("kind", ["cv", "ca", "imm"])
@pytest.mark.parametrize("unit_scales", [False, True])
def test_sequences_equal_the_numpy_filter_sequences(radar, kind, unit_scales):
    """torch_filters.filter_sequences gives batch_filters.filter_sequences' filtered positions,
    covariances and innovation distances (NaN at the same places) and last state on ECEF rows with a
    restart and padding inside and at the end, with no scales or with all scales 1 (Q per model)."""
    rows = realistic_rows(radar)
    kind_settings = settings(kind, NOISE[kind], velocity_std_mps=300.0)
    expected = batch_filters.filter_sequences(kind_settings, *rows)
    B, T = rows[0].shape
    M = len(kind_settings.models)
    scales = Scales(q=torch.ones(B, T, M, requires_grad=True, dtype=torch.float64),
                    r=torch.ones(B, T, dtype=torch.float64)) if unit_scales else None
    got = torch_filters.filter_sequences(FilterSpec.from_settings(kind_settings), *tensors(*rows), scales)
    valid = rows[3]
    for name, rtol in (("position", 1e-12), ("covariance", 1e-9), ("innovation_distance", 1e-8)):
        want, have = getattr(expected, name), getattr(got, name).detach().numpy()
        np.testing.assert_array_equal(np.isnan(have), np.isnan(want))
        np.testing.assert_allclose(have[~np.isnan(want)], want[~np.isnan(want)], rtol=rtol, atol=1e-6, err_msg=name)
    assert got.probabilities[~torch.as_tensor(valid)].isnan().all()
    for name in ("x", "P", "mu"):
        np.testing.assert_allclose(getattr(got.last, name).detach().numpy(), getattr(expected.last, name),
                                   rtol=1e-9, atol=1e-6)


def test_training_material_batches_give_the_numpy_error(material):
    """The tuner's material as tensors: rows of it filter as the NumPy core does, and the position
    error over the scored plots is the mean distance the NumPy filter gives."""
    kind_settings = settings("imm", NOISE["imm"])
    batch = SequenceBatch.from_sequences(material).rows(slice(1, None))
    error = batch.position_error(batch.filtered(FilterSpec.from_settings(kind_settings)))
    filtered = batch_filters.filter_sequences(kind_settings, material.times[1:], material.positions[1:],
                                              material.covariances[1:], material.valid[1:], material.restart[1:])
    scored = material.scored[1:]
    expected = np.linalg.norm(filtered.position[scored] - material.truth[1:][scored], axis=1).mean()
    assert float(error) == pytest.approx(expected, rel=1e-10)


# ----------------------------------------------------------------------------- gradients

def scaled_final_position(radar, kind: str, name: str, detach_every: int | None) -> tuple[torch.Tensor, torch.Tensor]:
    """Gradients of the sum of each row's final filtered position w.r.t. the scale `name` (B, T) at
    each step, for realistic rows (row 1 restarts at step 9; row 2 has padding at 6, 7 and the end)."""
    rows = tensors(*realistic_rows(radar))
    scale = torch.ones(rows[0].shape, dtype=torch.float64, requires_grad=True)
    spec = singer_spec() if kind == "singer" else FilterSpec.from_settings(settings(kind, NOISE[kind]))
    filtered = torch_filters.filter_sequences(spec, *rows, scales=Scales(**{name: scale}), detach_every=detach_every)
    final = filtered.position[:2, -1].sum() + filtered.position[2, -5].sum()  # row 2's last valid step is T - 5
    (gradient,) = torch.autograd.grad(final, scale)
    return gradient, rows[3]


@pytest.mark.parametrize("kind, name", [("singer", "q"), ("singer", "r"), ("singer", "manoeuvre"), ("imm", "q"),
                                        ("imm", "r")])
def test_gradients_reach_a_scale_only_within_the_truncation_window(radar, kind, name):
    """With detach_every = 5 over 20 steps (state cut before steps 5, 10, 15), a loss on each row's
    final position has a non-zero gradient w.r.t. the scale at each valid step from the last cut on
    (15-19; row 2, whose last plot is at 15, only there) and none before; without truncation at every
    valid step since the row's last restart (row 1 restarts at 9: nothing reaches back past it), R's
    at the restart too (a track starts with the plot's scaled covariance); never at padding."""
    truncated, valid = scaled_final_position(radar, kind, name, detach_every=5)
    full, _ = scaled_final_position(radar, kind, name, detach_every=None)
    steps = torch.arange(20)
    for row, (restart, last) in enumerate([(0, 19), (9, 19), (0, 15)]):
        reaching = valid[row] & (steps >= restart + (name != "r")) & (steps <= last)
        window = reaching & (steps >= 15)
        assert (truncated[row][window] != 0).all() and (truncated[row][~window] == 0).all(), truncated[row]
        assert (full[row][reaching] != 0).all() and (full[row][~reaching] == 0).all(), full[row]


def test_learning_the_measurement_noise_scale():
    """On synthetic CV flights (white-noise acceleration of the filter's own 2 m/s^2) measured with
    noise twice the nominal standard deviation, Adam on the log of one R scale, minimising the mean
    squared position error, moves it in 60 steps from 1 to near the true variance ratio 4 (within a factor 1.5)."""
    torch.manual_seed(0)
    B, T, dt, q, nominal = 256, 20, 5.0, 2.0, 100.0
    F = torch_filters.motion(FilterSpec("cv", (q,), 0.0, 0.0), torch.full((1,), dt))[0][0, 0, :2, :2]
    velocity_std = 150.0
    state = torch.cat([torch.zeros(B, 1, 3), velocity_std * torch.randn(B, 1, 3)], 1).to(torch.float64)  # [p; v]
    gain = torch.tensor([[dt ** 2 / 2], [dt]], dtype=torch.float64)  # Q = q^2 gain gain' (white-noise acceleration)
    truth = []
    for _ in range(T):
        truth.append(state[:, 0])
        state = F @ state + gain * q * torch.randn(B, 1, 3, dtype=torch.float64)
    truth = torch.stack(truth, 1)                                                   # (B, T, 3)
    positions = truth + 2 * nominal * torch.randn(B, T, 3, dtype=torch.float64)
    covariances = (nominal ** 2 * torch.eye(3, dtype=torch.float64)).expand(B, T, 3, 3)
    times = dt * torch.arange(T, dtype=torch.float64).expand(B, T)
    valid, restart = torch.ones(B, T, dtype=torch.bool), torch.zeros(B, T, dtype=torch.bool)
    restart[:, 0] = True
    spec = FilterSpec("cv", (q,), velocity_std, 0.0)
    log_scale = torch.zeros((), dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([log_scale], lr=0.1)
    for _ in range(60):
        optimiser.zero_grad()
        filtered = torch_filters.filter_sequences(spec, times, positions, covariances, valid, restart,
                                                  Scales(r=log_scale.exp().expand(B, T)), detach_every=10)
        loss = ((filtered.position[:, 3:] - truth[:, 3:]) ** 2).sum(-1).mean()
        loss.backward()
        optimiser.step()
    assert 4.0 / 1.5 < float(log_scale.detach().exp()) < 4.0 * 1.5


# ----------------------------------------------------------------------------- bad input

def test_bad_input_is_refused_by_name(radar):
    rows = tensors(*realistic_rows(radar))
    cv = FilterSpec.from_settings(settings("cv", NOISE["cv"]))
    with pytest.raises(ValueError, match="detach_every = 0"):
        torch_filters.filter_sequences(cv, *rows, detach_every=0)
    with pytest.raises(ValueError, match=r"scales\.r: shape \(3, 19\)"):
        torch_filters.filter_sequences(cv, *rows, scales=Scales(r=torch.ones(3, 19, dtype=torch.float64)))
    with pytest.raises(ValueError, match="cv: a manoeuvre scale only applies to singer"):
        torch_filters.filter_sequences(cv, *rows, scales=Scales(manoeuvre=torch.ones(3, 20, dtype=torch.float64)))
    with pytest.raises(ValueError, match="singer: needs manoeuvre_time_s"):
        FilterSpec("singer", (1.0,), 300.0, 20.0)
    with pytest.raises(ValueError, match="imm: needs 2 process-noise values"):
        FilterSpec("imm", (1.0,), 300.0, 20.0, switch_probability=0.05, initial_cv_probability=0.9)
    with pytest.raises(ValueError, match="filter kind 'jerk'"):
        FilterSpec("jerk", (1.0,), 300.0, 20.0)

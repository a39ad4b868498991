"""The LSTM update on a Kalman prediction (`pipeline.learning.lstm_update`, issue 18): the prediction it starts
from, its MC-dropout spread, a straight track, and bad params."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from pipeline.filters import motion_models
from pipeline.filters.torch_filters import SequenceBatch
from pipeline.learning import lstm_update
from pipeline.learning.lstm_update import LSTMUpdate, LSTMUpdateConfig
from pipeline.params import ParamError
from pipeline.settings import parse_params

pytestmark = pytest.mark.usefixtures("one_torch_thread")

CONFIG = LSTMUpdateConfig(hidden=8, dropout=0.0, mc_samples=8, detach_prediction=True, position_scale_m=1000.0,
                          velocity_scale_mps=400.0, acceleration_scale_mps2=10.0, time_scale_s=6.0, initial_alpha=0.5,
                          initial_beta=0.2, floor_m=1.0, start_velocity_std_mps=150.0,
                          calibration_ages=4, calibration_gaps=3)
SIGMA_M = 60.0  # plot noise per axis


def straight_flights(rows: int, steps: int, seed: int) -> SequenceBatch:
    """Constant-velocity flights at 150-250 m/s, 6 s scans, 50-150 km from the Earth's centre's
    direction of a radar at 52 N 5 E (ECEF), plots with SIGMA_M on each axis; the last plot scored."""
    rng = np.random.default_rng(seed)
    start = np.array([3.92e6, 0.34e6, 5.01e6]) + rng.uniform(-1e5, 1e5, (rows, 1, 3))
    heading = rng.uniform(0, 2 * np.pi, rows)
    speed = rng.uniform(150.0, 250.0, rows)
    east, north = np.array([-0.087, 0.996, 0.0]), np.array([-0.784, -0.069, 0.616])
    velocity = speed[:, None] * (np.cos(heading)[:, None] * east + np.sin(heading)[:, None] * north)
    times = np.arange(steps) * 6.0
    truth = start + times[None, :, None] * velocity[:, None]
    positions = truth + rng.normal(0.0, SIGMA_M, truth.shape)
    covariances = np.broadcast_to(SIGMA_M ** 2 * np.eye(3), (rows, steps, 3, 3)).copy()
    restart, scored = np.zeros((rows, steps), bool), np.zeros((rows, steps), bool)
    restart[:, 0], scored[:, steps // 2:] = True, True
    tensor = lambda values: torch.as_tensor(np.ascontiguousarray(values))  # noqa: E731
    return SequenceBatch(tensor(np.broadcast_to(times, (rows, steps))), tensor(positions), tensor(covariances),
                         tensor(truth), torch.ones((rows, steps), dtype=torch.bool), tensor(restart), tensor(scored))


def test_zeroed_lstm_contribution_gives_the_kalman_prediction():
    """Output weights and bias zero: the new state is F x, F the CA filter's (motion_models), whatever the plot."""
    model = LSTMUpdate(replace(CONFIG, dropout=0.3))
    with torch.no_grad():
        model.output.weight.zero_()
        model.output.bias.zero_()
    rng = np.random.default_rng(3)
    x = torch.as_tensor(rng.normal(0.0, 100.0, (4, 2, 9)) + np.tile([4e6, 200.0, 1.0, 3e5, -50.0, 0.0, 4.9e6, 0, 0], 1))
    memory = torch.zeros(4, 2, 8, dtype=x.dtype)
    ensemble = lstm_update.Ensemble(x, memory, memory, torch.ones(4, dtype=torch.long))
    dt = torch.tensor([1.0, 4.0, 6.0, 12.0])
    z = torch.as_tensor(rng.normal(0.0, 1e5, (4, 3)))
    after, prior = model.step(ensemble, z, torch.eye(3, dtype=x.dtype).expand(4, 3, 3) * 1e4, dt, sample=True)
    expected = np.einsum("bij,bnj->bni", np.stack([motion_models.transition("ca", d) for d in dt.tolist()]),
                         x.numpy())
    np.testing.assert_allclose(after.x.detach().numpy(), expected, rtol=1e-12)
    np.testing.assert_allclose(prior.detach().numpy(), expected, rtol=1e-12)


def position_spread(model: LSTMUpdate, batch: SequenceBatch) -> float:
    """Mean trace (m^2) of the MC-dropout position covariance over the scored plots, the floor taken out."""
    with torch.no_grad():
        covariance = model.eval()(batch).covariance[batch.scored]
    return float(torch.diagonal(covariance, dim1=-2, dim2=-1).sum(-1).mean()) - 3 * model.config.floor_m ** 2


def test_mc_dropout_spread_is_zero_without_dropout_and_grows_with_it():
    batch = straight_flights(6, 12, seed=1)
    torch.manual_seed(0)
    weights = LSTMUpdate(CONFIG).state_dict()
    spreads = []
    for dropout in (0.0, 0.1, 0.4):
        model = LSTMUpdate(replace(CONFIG, dropout=dropout, start_velocity_std_mps=1e-6))
        model.load_state_dict(weights)
        torch.manual_seed(1)
        spreads.append(position_spread(model, batch))
    assert spreads[0] == pytest.approx(0.0, abs=1e-9)
    assert 0.0 < spreads[1] < spreads[2]


def test_straight_track_is_estimated_within_the_plot_noise():
    """The untrained estimator (an alpha-beta filter by construction) on constant-velocity flights: after
    half the plots its mean error is below the plots' own."""
    batch = straight_flights(20, 16, seed=2)
    with torch.no_grad():
        filtered = LSTMUpdate(CONFIG).eval()(batch)
    estimate_error = (filtered.position[batch.scored] - batch.truth[batch.scored]).norm(dim=-1).mean()
    plot_error = (batch.positions[batch.scored] - batch.truth[batch.scored]).norm(dim=-1).mean()
    assert estimate_error < 0.8 * plot_error


@pytest.mark.parametrize("key, value, message", [
    ("dropout", 1.0, r"lstm_update.dropout = 1.0: must be in \[0.0, 1.0\)"),
    ("dropout", -0.1, r"lstm_update.dropout = -0.1"),
    ("mc_samples", 0, r"lstm_update.mc_samples = 0: must be an integer >= 1"),
    ("segment_plots", 8, r"lstm_update.segment_plots = 8: shorter than the hold-out windows it is scored on "
                         r"\(windows.filter_length = 10\)"),
    ("truncation_steps", 40, r"lstm_update.truncation_steps = 40: longer than the training sequences"),
    ("detach_prediction", "yes", r"lstm_update.detach_prediction = 'yes': must be true or false"),
])
def test_bad_params_are_named(params_tree, key, value, message):
    params_tree["lstm_update"][key] = value
    with pytest.raises(ParamError, match=message):
        parse_params(params_tree)


def test_bad_config_is_refused_before_training():
    with pytest.raises(ValueError, match="lstm_update.mc_samples = 0"):
        replace(CONFIG, mc_samples=0)


def test_tracker_estimator_follows_the_sequence_run_and_gates_far_plots_out():
    """The tracker's estimator on one track, plot by plot (dropout off), gives the positions of the
    whole sequence run in one batch; with MC dropout its predictions carry a positive definite
    covariance with which the chi-square gate rejects plots 5 km off the track's own."""
    from pipeline.tracker.gate import ChiSquareGate
    from pipeline.tracker.lstm_update_estimator import LSTMUpdateEstimator
    from pipeline.tracker.management import ThesisWeights
    from pipeline.tracker.tracks import LiveTracks
    from tests import tracker_fixtures as tf
    from tests.test_kalman_tracker import moved_east, noisy_turning_flight

    params = tf.make_params()
    flight = noisy_turning_flight(params, np.random.default_rng(5))
    far = moved_east(flight, params, 5000.0)
    plots = tf.plots_of(np.concatenate([flight, far]), np.arange(2 * len(flight)), params.radar)
    n = len(flight)
    restart = np.zeros((1, n), bool)
    restart[0, 0] = True
    tensor = lambda values: torch.as_tensor(np.ascontiguousarray(values))[None]  # noqa: E731
    batch = SequenceBatch(tensor(plots.time[:n]), tensor(plots.position[:n]), tensor(plots.covariance[:n]),
                          tensor(plots.position[:n]), torch.ones((1, n), dtype=torch.bool), torch.as_tensor(restart),
                          torch.ones((1, n), dtype=torch.bool))
    torch.manual_seed(0)
    weights = LSTMUpdate(CONFIG).state_dict()
    for dropout in (0.0, 0.3):
        model = LSTMUpdate(replace(CONFIG, dropout=dropout))
        model.load_state_dict(weights)
        with torch.no_grad():
            expected = model.eval()(batch).position[0].numpy()
        estimator = LSTMUpdateEstimator(model, 0)
        gate = ChiSquareGate(params.tracker.association.kalman_gate_probability)
        live = LiveTracks(plots, ThesisWeights.from_params(params.tracker.management),
                          latest_plots=estimator.latest_plots)
        slot = live.start(0)
        estimator.start(live, slot)
        rejected = 0
        for row in range(1, n):
            prediction = estimator.predict(live, np.array([slot]), plots.time[row])
            assert np.all(np.linalg.eigvalsh(prediction.covariances[0]) > 0)
            if dropout:
                rejected += np.isinf(gate(live, np.array([slot]), row + n, prediction).errors[0])
            position, covariance = estimator.update(live, slot, row, prediction, 0)
            live.associate(slot, row, position)
            if not dropout:
                np.testing.assert_allclose(position, expected[row], rtol=1e-12)
        assert rejected >= (n - 4 if dropout else 0)


def test_stage_runs_in_the_tiny_pipeline(tiny_pipeline, tmp_path):
    """`dvc repro train_lstm_update` in a copy of the tiny pipeline (made there for `evaluate` already, run
    again into a store of the copy's own): the estimator loads with its
    calibration, the report compares it with the tuned CA and IMM on the hold-out, one MLflow run."""
    import json
    import shutil
    import sqlite3

    from tests.servers import dvc
    repository = shutil.copytree(tiny_pipeline, tmp_path / "copy", symlinks=True)
    (repository / "mlflow.db").unlink()  # its runs keep artifacts in the original's folder: a store of its own
    dvc(repository, "repro", "--force", "--single-item", "train_lstm_update")  # evaluate's input: it ran already
    model = lstm_update.load(repository / "models" / "lstm_update.pt")
    assert model.config.mc_samples == 4 and torch.all(model.calibration > 0)
    assert model.calibration.shape == (2, model.config.calibration_ages)
    assert model.gap_calibration.shape == (model.config.calibration_gaps,) and torch.all(model.gap_calibration > 0)
    report = json.loads((repository / "reports" / "lstm_update.json").read_text())
    assert len(report["epoch_losses_m"]) == 1
    scored = report["holdout"]["filters"]
    assert {"LSTM update", "Kalman CA, Nelder-Mead tuned",
            "IMM (CV + CA), Nelder-Mead tuned"} <= set(scored)
    assert all(values["anees_bounds"][0] < 3 < values["anees_bounds"][1] for values in scored.values())
    with sqlite3.connect(repository / "mlflow.db") as store:
        names = [row[0] for row in store.execute("SELECT name FROM runs WHERE status = 'FINISHED'")]
    assert names.count("train_lstm_update") == 1


def test_gate_factor_lets_through_the_gate_probability_of_gaussian_innovations():
    """Innovations drawn from N(0, 4 C + R): the factor fitted for a 99 % gate is about 4."""
    rng = np.random.default_rng(6)
    factor = rng.normal(size=(20000, 3, 3)) * 30.0
    C = torch.as_tensor(factor @ factor.transpose(0, 2, 1) + 100.0 * np.eye(3))
    R = torch.as_tensor(np.broadcast_to(2500.0 * np.eye(3), (20000, 3, 3)).copy())
    innovation = torch.as_tensor(np.einsum("nij,nj->ni", np.linalg.cholesky((4 * C + R).numpy()),
                                           rng.normal(size=(20000, 3))))
    assert lstm_update._gate_factor(innovation, C, R, 0.99) == pytest.approx(4.0, rel=0.15)


def test_estimate_factors_recover_the_spread_and_plot_shares_of_gaussian_errors():
    """Errors drawn from N(0, 2 C + 0.5 R): the maximum-likelihood factors are about 2 and 0.5, and
    their mean NEES is exactly 3, the dimension."""
    rng = np.random.default_rng(7)
    factor = rng.normal(size=(20000, 3, 3)) * 30.0
    C = torch.as_tensor(factor @ factor.transpose(0, 2, 1))
    R = torch.as_tensor(np.diag([2500.0, 40000.0, 90000.0])[None] * rng.uniform(0.5, 2.0, (20000, 1, 1)))
    floor = torch.eye(3, dtype=torch.float64)
    error = torch.as_tensor(np.einsum("nij,nj->ni", np.linalg.cholesky((2 * C + 0.5 * R + floor).numpy()),
                                      rng.normal(size=(20000, 3))))
    a, b = lstm_update._estimate_factors(error, C, R, floor)
    assert a == pytest.approx(2.0, rel=0.1) and b == pytest.approx(0.5, rel=0.1)
    assert float(lstm_update._distance(error, a * C + b * R + floor).mean()) == pytest.approx(3.0, rel=1e-4)


def test_compare_puts_the_lstm_update_in_the_estimator_table_with_every_column():
    """The compare stage's hold-out table: one row per estimator, best first, with turns, straight
    flight, ANEES (marked when inside its bounds) and the share within each share of the range."""
    from pipeline.reports.comparison_tables import estimator_table

    def scored(mean: float, anees: float) -> dict:
        return {"mean_error_m": mean, "rmse_m": mean * 1.3, "p95_error_m": mean * 2.7, "anees": anees,
                "anees_bounds": [2.94, 3.06], "anees_inside": 2.94 <= anees <= 3.06, "turn_mean_error_m": mean * 1.1,
                "straight_mean_error_m": mean * 0.9, "turn_windows": 7, "within_range_share": {"0.05": 1.0, "0.001": 0.6}}
    table = estimator_table({"windows": 70, "filters": {"IMM (CV + CA), Nelder-Mead tuned": scored(156.3, 3.71),
                                                        "LSTM update": scored(144.5, 3.01)}}).splitlines()
    assert table[0] == ("| estimator | mean error (m) | RMSE (m) | 95th percentile (m) | turns (m) | straight (m) | "
                        "ANEES (95 % bounds 2.94-3.06) | within 5.0% of range | within 0.1% of range |")
    assert table[2] == "| LSTM update | 144.5 | 187.8 | 390.2 | 159.0 | 130.1 | 3.01 in | 100.0% | 60.0% |"
    assert table[3].startswith("| IMM (CV + CA), Nelder-Mead tuned | 156.3 |") and "| 3.71 |" in table[3]


def test_bounded_gate_rejects_a_plot_beyond_the_window_however_wide_the_covariance():
    """The LSTM update's gate: with a covariance of 100 km per axis the chi-square gate alone takes a
    plot 5 km off the prediction; bounded by a 4 km window it does not, and a plot 1 km off stays in."""
    from pipeline.tracker.estimator import Prediction
    from pipeline.tracker.gate import BoundedChiSquareGate, ChiSquareGate
    from pipeline.tracker.management import ThesisWeights
    from pipeline.tracker.tracks import LiveTracks
    from tests import tracker_fixtures as tf

    params = tf.make_params()
    from pipeline.geometry import geodesy
    site = geodesy.radar_site_ecef(params.radar)
    offsets = np.array([[100e3, 0.0, 0.0], [100e3, 5000.0, 0.0], [100e3, 1000.0, 0.0]])
    features = np.column_stack([np.arange(3) * 6.0, site + offsets, np.linalg.norm(offsets, axis=1)])
    plots = tf.plots_of(features, np.arange(3), params.radar)
    live = LiveTracks(plots, ThesisWeights.from_params(params.tracker.management), latest_plots=0)
    slots = np.array([live.start(0)])
    wide = Prediction(plots.position[:1], np.eye(3)[None] * 1e10, None)
    assert np.isfinite(ChiSquareGate(0.999)(live, slots, 1, wide).errors[0])
    bounded = BoundedChiSquareGate(0.999, 4000.0)
    assert np.isinf(bounded(live, slots, 1, wide).errors[0])
    assert np.isfinite(bounded(live, slots, 2, wide).errors[0])

"""The network-scaled Kalman filter (`pipeline.learning.kalman_net`) and the gradient-tuned filters (`pipeline.filters.gradient_tuning`).

Pinned to scales of 1 the network-scaled filter is its base Kalman filter; gradients reach the
network through the whole truncated window and stop at its start; a gradient-tuned R scale learns
the true noise ratio through the stage's Lightning loop; bad params and material are refused by name.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pyarrow as pa
import pytest
import torch

from pipeline import io
from pipeline.filters import batch_filters
from pipeline.filters.classical_filters import FilterSettings
from pipeline.filters.gradient_tuning import TunedFilter
from pipeline.filters.torch_filters import FilterSpec, SequenceBatch, filter_sequences
from pipeline.io import InputError
from pipeline.learning import kalman_net
from pipeline.learning.filter_training import descent
from pipeline.learning.fit import fit
from pipeline.learning.kalman_net import KalmanNet, KalmanNetConfig
from pipeline.learning.kalman_net_training import training_material
from pipeline.learning.model_store import save_network
from pipeline.params import ParamError
from pipeline.settings import parse_params
from tests.test_classical import plots_table, radar_plots, random_flight, realistic_rows
from tests.test_torch_filters import tensors

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def radar(make_params):
    return make_params(1).radar


def config(base: str = "singer", cell: str = "gru") -> KalmanNetConfig:
    return KalmanNetConfig(base, cell, hidden=6, noise_std=4.0, manoeuvre_time_s=20.0, velocity_std_mps=300.0,
                           acceleration_std_mps2=20.0, r0_scale=1.5, q_amplitude=50.0, r_amplitude=4.0,
                           manoeuvre_amplitude=10.0, velocity_scale_mps=400.0, nis_scale=10.0)


def batch_of(rows: tuple[np.ndarray, ...]) -> SequenceBatch:
    times, positions, covariances, valid, restart = tensors(*rows)
    return SequenceBatch(times, positions, covariances, positions.clone(), valid, restart, valid.clone())


@pytest.mark.parametrize("base", ["cv", "ca", "singer"])
@pytest.mark.parametrize("cell", ["gru", "mlp"])
def test_scales_pinned_to_one_give_the_kalman_filter(radar, base, cell):
    """With the output layer's weights zero and its bias at logit(1 / amplitude) (as built: an untrained
    network) every scale is 1 whatever the features, and the network-scaled filter gives its base
    filter's positions, covariances and innovation distances with Q0 and R0 = covariance x r0_scale on
    rows with a restart and padding; for cv and ca those of the NumPy core."""
    torch.manual_seed(1)
    model = KalmanNet(config(base, cell))
    with torch.no_grad():
        for parameter in model.network.body.parameters():
            parameter.normal_()  # the features do reach the network, only the head is pinned
    rows = realistic_rows(radar)
    got = model(batch_of(rows))
    times, positions, covariances, valid, restart = tensors(*rows)
    want = filter_sequences(model.base, times, positions, covariances * 1.5, valid, restart)
    for name in ("position", "covariance", "innovation_distance"):
        np.testing.assert_allclose(getattr(got, name).detach().numpy(), getattr(want, name).numpy(), rtol=1e-12,
                                   atol=1e-9, err_msg=name)
    if base != "singer":
        settings = FilterSettings(base, (4.0,), 300.0, 20.0, 0.05, 0.9)
        numpy = batch_filters.filter_sequences(settings, rows[0], rows[1], rows[2] * 1.5, rows[3], rows[4])
        np.testing.assert_allclose(got.position.detach().numpy(), numpy.position, rtol=1e-12, atol=1e-6)


def head_output_gradients(radar, detach_every: int | None) -> tuple[torch.Tensor, torch.Tensor, KalmanNet]:
    """Gradients (B, T) of each row's final filtered position (row 2's last valid plot is at T - 5)
    w.r.t. the network's outputs at each step (summed over the outputs), for a network with random
    weights on the realistic rows; and the rows' valid mask."""
    torch.manual_seed(2)
    model = KalmanNet(config("singer", "gru"))
    with torch.no_grad():
        for parameter in model.network.parameters():
            parameter.normal_(0.0, 0.3)
    outputs: list[torch.Tensor] = []

    def keep(module, inputs, output):
        output.retain_grad()
        outputs.append(output)
    model.network.head.register_forward_hook(keep)
    rows = realistic_rows(radar)
    filtered = model(batch_of(rows), detach_every)
    final = filtered.position[:2, -1].sum() + filtered.position[2, -5].sum()
    final.backward()
    gradient = torch.stack([output.grad.abs().sum(1) for output in outputs], 1)
    assert all(parameter.grad is not None and parameter.grad.abs().sum() > 0 for parameter in model.parameters())
    return gradient, torch.as_tensor(rows[3]), model


def test_gradients_reach_the_network_through_the_whole_truncated_window_and_not_beyond(radar):
    """Truncated every 5 of 20 steps (filter state and network memory cut before steps 5, 10, 15), the
    final positions' gradient reaches the network's outputs at every valid step of the last window
    (15 to each row's last plot) and at none before; every weight gets a gradient. Untruncated it
    reaches back to each row's (re)start (row 1 restarts at 9)."""
    truncated, valid, _ = head_output_gradients(radar, detach_every=5)
    full, _, _ = head_output_gradients(radar, detach_every=None)
    steps = torch.arange(20)
    for row, (restart, last) in enumerate([(0, 19), (9, 19), (0, 15)]):
        window = valid[row] & (steps >= 15) & (steps <= last)
        assert (truncated[row][window] > 0).all() and (truncated[row][~window] == 0).all(), truncated[row]
        reaching = valid[row] & (steps >= restart) & (steps <= last)
        assert (full[row][reaching] > 0).all() and (full[row][~reaching] == 0).all(), full[row]


def synthetic_cv_flights(rows: int, steps: int, noise_ratio: float, seed: int) -> tuple[SequenceBatch, float]:
    """CV flights with white-noise acceleration (2 m/s^2, 5 s steps) measured with noise `noise_ratio`
    times the nominal 100 m standard deviation that the covariances say; the filter's true q."""
    generator = torch.Generator().manual_seed(seed)
    dt, q, nominal = 5.0, 2.0, 100.0
    normal = lambda *shape: torch.randn(*shape, generator=generator, dtype=torch.float64)  # noqa: E731
    position, velocity = torch.zeros(rows, 3, dtype=torch.float64), 150.0 * normal(rows, 3)
    truth = []
    for _ in range(steps):
        truth.append(position)
        acceleration = q * normal(rows, 3)
        position, velocity = position + velocity * dt + acceleration * dt ** 2 / 2, velocity + acceleration * dt
    truth = torch.stack(truth, 1)
    shape = (rows, steps)
    restart, scored = torch.zeros(shape, dtype=torch.bool), torch.zeros(shape, dtype=torch.bool)
    restart[:, 0], scored[:, 3:] = True, True
    return SequenceBatch(dt * torch.arange(steps, dtype=torch.float64).expand(shape),
                         truth + noise_ratio * nominal * normal(rows, steps, 3),
                         (nominal ** 2 * torch.eye(3, dtype=torch.float64)).expand(*shape, 3, 3), truth,
                         torch.ones(shape, dtype=torch.bool), restart, scored), q


def test_gradient_tuned_r_scale_converges_near_the_true_noise_ratio():
    """A CV filter with the flights' own process noise, its R scale started at 1 while the plots' noise
    is twice what their covariances say: the stage's training loop (Lightning, Adam on the mean
    position error, truncated every 10 steps) moves the scale to near the true variance ratio 4.
    The process noise is held at its true value: the steady-state gain, hence the error, depends on
    Q and R through their ratio only, so the loss cannot tell their scales apart."""
    material, q = synthetic_cv_flights(256, 20, 2.0, seed=0)
    model = TunedFilter(FilterSpec("cv", (q,), 150.0 * np.sqrt(3), 0.0))
    model.logs["noise_std"].requires_grad_(False)
    knobs = SimpleNamespace(epochs=15, batch_segments=64, learning_rate=0.1, truncation_steps=10, seed=0)
    losses = fit(*descent(model, "synthetic", material, knobs, deterministic=True)).train_loss
    assert losses[-1] < losses[0]
    assert 4.0 / 1.3 < model.to_dict()["r_scale"] < 4.0 * 1.3


def test_a_gradient_tuned_filter_whose_loss_goes_nan_stops_its_training():
    """Learning rate 1e30 on the stage's training loop: the filter's logarithms overflow at the first
    step and the loss of the next batch is NaN; the training stops there, naming the filter."""
    material, q = synthetic_cv_flights(64, 20, 2.0, seed=0)
    model = TunedFilter(FilterSpec("cv", (q,), 150.0 * np.sqrt(3), 0.0))
    with pytest.raises(io.TrainingDiverged, match=r"training of gradient_cv stopped: the training loss became nan "
                                                   r"at epoch 1 of 3, batch 2"):
        fit(*descent(model, "gradient_cv", material, SimpleNamespace(epochs=3, batch_segments=16, learning_rate=1e30,
                                                                     truncation_steps=10, seed=0), deterministic=True))


def test_a_saved_network_with_a_nan_weight_is_refused(tmp_path):
    """`kalman_net.load` (the shared `model_store.load_network`) names the file and the tensor."""
    model = KalmanNet(config("singer", "mlp"))
    with torch.no_grad():
        model.network.head.weight[0, 0] = float("nan")
    save_network(tmp_path / "kalman_net.pt", model)
    with pytest.raises(io.InputError, match="kalman_net.pt: weight tensor 'network.head.weight' has 1 non-finite"):
        kalman_net.load(tmp_path / "kalman_net.pt")


def test_saved_model_loads_and_gives_per_step_scales(tmp_path, radar):
    """`kalman_net.load` gives the saved network, and `step_scales` the scales of one step of a track
    from its filter state (what a tracker's estimator calls), each within (0, amplitude)."""
    torch.manual_seed(3)
    model = KalmanNet(config("singer", "mlp"))
    with torch.no_grad():
        model.network.head.weight.normal_()
    save_network(tmp_path / "kalman_net.pt", model)
    loaded = kalman_net.load(tmp_path / "kalman_net.pt")
    rows = realistic_rows(radar)
    np.testing.assert_array_equal(loaded(batch_of(rows)).position.detach().numpy(),
                                  model(batch_of(rows)).position.detach().numpy())
    from pipeline.filters import torch_filters
    times, positions, covariances, _, _ = tensors(*rows)
    state = torch_filters.start(loaded.base, positions[:1, 0], covariances[:1, 0])
    step = torch_filters.Step(1, state, positions[:1, 1], covariances[:1, 1], times[:1, 1] - times[:1, 0])
    memory = loaded.memory(1)
    _, memory = loaded.step_scales(memory, torch_filters.Step(0, state, positions[:1, 0], covariances[:1, 0],
                                                              torch.zeros(1, dtype=torch.float64)),
                                   torch.ones(1, dtype=torch.bool), torch.zeros(1, dtype=torch.bool))
    scales, memory = loaded.step_scales(memory, step, torch.zeros(1, dtype=torch.bool), torch.ones(1, dtype=torch.bool))
    for name in ("manoeuvre", "q", "r"):
        value = float(getattr(scales, name).detach())
        assert 0.0 < value < loaded.config.amplitude(name)
    assert int(memory.age) == 2


@pytest.mark.parametrize("key, value, message", [
    ("noise_std", 0.0, r"kalman_net.noise_std = 0.0: Q0 must be positive definite"),
    ("manoeuvre_time_s", -3.0, r"kalman_net.manoeuvre_time_s = -3.0: Q0 must be positive definite"),
    ("r0_scale", 0, r"kalman_net.r0_scale = 0: R0 must be positive definite"),
    ("q_amplitude", 0.0, r"kalman_net.q_amplitude = 0.0: must be above 1"),
    ("r_amplitude", -2.0, r"kalman_net.r_amplitude = -2.0: must be above 1"),
    ("manoeuvre_amplitude", 1.0, r"kalman_net.manoeuvre_amplitude = 1.0: must be above 1"),
    ("truncation_steps", 65, r"kalman_net.truncation_steps = 65: longer than the training segments "
                             r"\(segment_plots = 64\)"),
    ("base", "imm", r"kalman_net.base = 'imm'"),
    ("baselines", ["cv", "jerk"], r"kalman_net.baselines"),
])
def test_bad_params_are_named(params_tree, key, value, message):
    params_tree["kalman_net"][key] = value
    with pytest.raises(ParamError, match=message):
        parse_params(params_tree)


def test_material_shorter_than_the_truncation_is_refused(make_params):
    """Routes of 12 plots cannot feed a truncation of 16 steps: InputError before training."""
    params = make_params(1, {"kalman_net.truncation_steps": 16})
    rng = np.random.default_rng(4)
    rows = []
    for route in range(3):
        times, truth = random_flight(rng, params.radar, 12)
        plots, _ = radar_plots(truth, params.radar, rng)
        rows += [(route, t, tuple(p), tuple(e)) for t, p, e in zip(times, plots, truth)]
    table = plots_table(rows)
    table = table.append_column("plot_id", pa.array(np.arange(table.num_rows), pa.int64()))
    with pytest.raises(InputError, match="longest training segment has 12 plots, fewer than "
                                         "kalman_net.truncation_steps = 16"):
        training_material(params, table, table.slice(0, 0))


def test_stage_runs_in_the_tiny_pipeline(tiny_pipeline, tmp_path):
    """`dvc repro train_kalman_net` in a copy of the tiny pipeline (made there for `evaluate` already, run again
    into a store of the copy's own): the network loads, the
    four gradient-tuned filters are saved, the report has one loss per epoch, one MLflow run is logged."""
    import json
    import shutil
    import sqlite3

    from tests.servers import dvc
    repository = shutil.copytree(tiny_pipeline, tmp_path / "copy", symlinks=True)
    (repository / "mlflow.db").unlink()  # its runs keep artifacts in the original's folder: a store of its own
    dvc(repository, "repro", "--force", "--single-item", "train_kalman_net")  # evaluate's input: it ran already
    model = kalman_net.load(repository / "models" / "kalman_net.pt")
    assert model.config.base == "cv"
    gradient = json.loads((repository / "models" / "kalman_gradient.json").read_text())
    assert sorted(gradient) == ["ca", "cv", "imm", "singer"]
    assert all(TunedFilter.from_dict(values).to_dict()["r_scale"] > 0 for values in gradient.values())
    report = json.loads((repository / "reports" / "kalman_net.json").read_text())
    assert len(report["kalman_net"]["epoch_losses_m"]) == 1
    with sqlite3.connect(repository / "mlflow.db") as store:
        names = [row[0] for row in store.execute("SELECT name FROM runs WHERE status = 'FINISHED'")]
    assert names.count("train_kalman_net") == 1

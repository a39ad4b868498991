"""The learned estimators' runtimes and devices (issue 29): the TorchScript-traced steps
(`pipeline.learning.step_runtime`) give PyTorch's numbers on random inputs at batch sizes other than
the one traced; `tracker.device` names cpu, cuda or cuda:N, a CUDA device this machine lacks is a
ParamError naming the key and value (exit 2 from `track`), and where a GPU exists a tiny tracking
on it follows the CPU's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from pipeline.filters import torch_filters
from pipeline.learning import devices, step_runtime
from pipeline.learning.kalman_net import KalmanNet, KalmanNetConfig
from pipeline.learning.lstm_update import LSTMUpdate
from pipeline.learning.model_store import save_network
from pipeline.params import ParamError
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.models import Models
from pipeline.tracker.run import track
from tests import tracker_fixtures as tf
from tests.test_kalman_tracker import crossing_flights_among_clutter
from tests.test_learned_scans import lstm_update, scaling_network
from tests.test_track_command import track_command, two_radar_recording

pytestmark = pytest.mark.usefixtures("one_torch_thread")
ROUNDING = 1e-12  # float64 rounding, relative to an output's largest magnitude
SIZES = (4, 16, 37, 300)  # traced at step_runtime.TRACE_ROWS = 16


@pytest.fixture(scope="module")
def params():
    return tf.make_params()


def noise(generator: torch.Generator, *shape: int, scale: float = 1.0) -> torch.Tensor:
    return torch.randn(*shape, generator=generator, dtype=torch.float64) * scale


def kalman_net(base: str, cell: str) -> KalmanNet:
    """A network-scaled filter whose network's weights are all random (scales that differ by row)."""
    torch.manual_seed(3)
    model = KalmanNet(KalmanNetConfig(base, cell, 8, 5.0, 30.0, 400.0, 10.0, 1.0, 100.0, 4.0, 10.0, 400.0, 10.0))
    with torch.no_grad():
        for parameter in model.network.parameters():
            parameter.normal_(0.0, 0.5)
    return model.eval()


def kalman_net_inputs(model: KalmanNet, rows: int, generator: torch.Generator) -> tuple[torch.Tensor, ...]:
    """Tracks started near the Earth's surface with random velocities, random memory, their next plots
    after 2-6 s; every third track fresh, the others moving."""
    z0 = torch.tensor([6.4e6, 0.0, 0.0], dtype=torch.float64) + noise(generator, rows, 3, scale=5e4)
    R0 = torch.diag_embed(1e4 + noise(generator, rows, 3).abs() * 1e4)
    state = torch_filters.start(model.base, z0, R0)
    x = state.x + noise(generator, *state.x.shape, scale=100.0)
    fresh = torch.arange(rows) % 3 == 0
    return (x, state.P, state.mu, torch.tanh(noise(generator, rows, model.config.hidden)),
            z0 + noise(generator, rows, 3, scale=1e3), z0 + noise(generator, rows, 3, scale=500.0),
            4.0 + noise(generator, rows).abs(), torch.randint(0, 5, (rows,), generator=generator),
            z0 + noise(generator, rows, 3, scale=800.0), R0, 2.0 + 4.0 * torch.rand(rows, generator=generator,
                                                                                   dtype=torch.float64),
            fresh, ~fresh)


def lstm_inputs(model: LSTMUpdate, rows: int, generator: torch.Generator, masked: bool) -> tuple[torch.Tensor, ...]:
    """Ensembles of random copies and memory, their next plots after 2-6 s and (masked) their dropout masks."""
    samples, _ = model.ensemble()
    z0 = torch.tensor([6.4e6, 0.0, 0.0], dtype=torch.float64) + noise(generator, rows, 3, scale=5e4)
    ensemble = model.started(z0, samples)
    hidden = model.config.hidden
    R = torch.diag_embed(1e4 + noise(generator, rows, 3).abs() * 1e4)
    inputs = (ensemble.x + noise(generator, *ensemble.x.shape, scale=50.0),
              torch.tanh(noise(generator, rows, samples, hidden)), noise(generator, rows, samples, hidden),
              torch.randint(1, 6, (rows,), generator=generator), z0 + noise(generator, rows, 3, scale=800.0), R,
              2.0 + 4.0 * torch.rand(rows, generator=generator, dtype=torch.float64))
    if masked:
        inputs += (torch.stack([model.dropout_masks(samples, generator) for _ in range(rows)]),)
    return inputs


def assert_as_pytorch(function: type[torch.nn.Module], model: torch.nn.Module, inputs) -> None:
    """`function` traced (`step_runtime.traced`, at TRACE_ROWS rows) gives what the module gives eagerly at
    every size of SIZES, to float64 rounding relative to each output's magnitude."""
    generator = torch.Generator().manual_seed(11)
    script = step_runtime.traced(model, function, "script", lambda rows: inputs(rows, generator))
    eager = step_runtime.traced(model, function, "eager", lambda rows: inputs(rows, generator))
    assert isinstance(script, step_runtime.Unoptimised) and isinstance(script.module, torch.jit.ScriptModule)
    assert not isinstance(eager, (step_runtime.Unoptimised, torch.jit.ScriptModule))
    for rows in SIZES:
        given = inputs(rows, generator)
        with torch.no_grad():
            ours, theirs = script(*given), eager(*given)
        assert len(ours) == len(theirs)
        for index, (value, expected) in enumerate(zip(ours, theirs)):
            assert value.shape == expected.shape and value.dtype == expected.dtype, (rows, index)
            magnitude = max(1.0, float(expected.abs().max()))
            torch.testing.assert_close(value, expected, rtol=0.0, atol=ROUNDING * magnitude, msg=f"{rows} {index}")


@pytest.mark.parametrize("base, cell", [("cv", "gru"), ("ca", "mlp"), ("singer", "gru")])
def test_the_traced_kalman_net_steps_give_pytorchs_numbers(base, cell):
    """The network-scaled filter's plot step (scales, memory, prior) and update, traced at 16 rows, equal
    the eager modules' on random tracks and plots at 4 to 300 rows."""
    model = kalman_net(base, cell)
    assert_as_pytorch(step_runtime.KalmanNetPlotStep, model, lambda rows, g: kalman_net_inputs(model, rows, g))

    def update_inputs(rows, generator):
        x, P, mu, *_, z, R0, _, _, _ = kalman_net_inputs(model, rows, generator)
        return x, P, mu, z, R0 * 2.0
    assert_as_pytorch(step_runtime.KalmanNetUpdate, model, update_inputs)


@pytest.mark.parametrize("copies", [8, 2])
def test_the_traced_lstm_update_steps_give_pytorchs_numbers(copies):
    """The LSTM update's prediction and its step with given MC-dropout masks, traced at 16 rows, equal
    the eager modules' on random ensembles and plots at 4 to 300 rows; a model of dropout 0 too."""
    model = lstm_update(copies, 1.0)
    assert_as_pytorch(step_runtime.LSTMStep, model, lambda rows, g: lstm_inputs(model, rows, g, True))
    assert_as_pytorch(step_runtime.LSTMPredict, model, lambda rows, g: lstm_inputs(model, rows, g, False)[::3])
    still = LSTMUpdate(replace(model.config, dropout=0.0)).eval()
    still.load_state_dict(model.state_dict())
    assert_as_pytorch(step_runtime.LSTMStepUnmasked, still, lambda rows, g: lstm_inputs(still, rows, g, False))


def test_a_traced_step_is_kept_per_model_and_an_unknown_runtime_is_refused():
    model = kalman_net("cv", "gru")
    generator = torch.Generator().manual_seed(0)

    def example(rows):
        return kalman_net_inputs(model, rows, generator)
    first = step_runtime.traced(model, step_runtime.KalmanNetPlotStep, "script", example)
    assert step_runtime.traced(model, step_runtime.KalmanNetPlotStep, "script", example) is first
    assert step_runtime.traced(kalman_net("cv", "gru"), step_runtime.KalmanNetPlotStep, "script", example) is not first
    with pytest.raises(ValueError, match="tracker.learned_runtime = 'compile': must be one of"):
        step_runtime.traced(model, step_runtime.KalmanNetPlotStep, "compile", example)


@pytest.mark.parametrize("value", ["gpu", "cuda:", "cuda:x", "cpu:1", "mps"])
def test_a_device_not_cpu_or_cuda_is_a_param_error_naming_the_key(value):
    with pytest.raises(ParamError, match=rf"tracker.device = '{value}': must be cpu, cuda or cuda:N"):
        tf.make_params({"tracker.device": value})
    with pytest.raises(ParamError, match=rf"tracker.device = '{value}': must be cpu, cuda or cuda:N"):
        devices.resolve(value)


def test_cuda_without_a_cuda_device_is_a_param_error_and_track_exits_2(params, tmp_path, monkeypatch, caplog):
    """On a machine where torch sees no CUDA device (made so here where one exists) `tracker.device: cuda`
    is refused naming the key and value: by the estimators, by `load_models` before any file is read,
    and by `track` with exit 2 and no output; cpu is the device of the default params."""
    assert params.tracker.device == "cpu" and devices.resolve("cpu") == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    message = r"tracker.device = 'cuda:1': torch .* sees no CUDA device on this machine"
    with pytest.raises(ParamError, match=message):
        devices.resolve("cuda:1")
    cuda = tf.make_params({"tracker.device": "cuda"})
    with pytest.raises(ParamError, match=r"tracker.device = 'cuda': torch"):
        registry.compose("kalman_net", Models({"kalman_net": kalman_net("cv", "gru")}), cuda.tracker, 4000.0, 0)
    with pytest.raises(ParamError, match=r"tracker.device = 'cuda': torch"):
        load_models(tmp_path / "nothing_here", cuda, ["lstm_update"])
    models = tf.write_tuned_filters(tmp_path / "models", params)
    save_network(models / "kalman_net.pt", kalman_net("cv", "gru"))
    plots, radars, _ = two_radar_recording(params, np.random.default_rng(2))
    assert track_command(tmp_path, models, "kalman_net", plots, radars, {"tracker.device": "cuda"}) == 2
    assert "tracker.device = 'cuda': torch" in caplog.text
    assert not (tmp_path / "tracks.parquet").exists()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device here (torch.cuda.is_available() is "
                                                          "False): tracker.device: cuda is not exercised")
@pytest.mark.parametrize("method", ["kalman_net_gnn", "lstm_update"])
def test_a_tiny_tracking_on_cuda_follows_the_cpus(params, method):
    """Crossing flights among clutter tracked with the batched steps on the GPU: the same tracks as on the
    CPU, positions to 1 mm (other kernels: other last bits), the loaded model left on the CPU."""
    plots = crossing_flights_among_clutter(params)
    piece, network = (("kalman_net", scaling_network(params)) if method == "kalman_net_gnn"
                      else ("lstm_update", lstm_update(8, 1.0)))
    models = Models({piece: network})
    tables = [track(plots, registry.compose(method, models, replace(params.tracker, device=device), 4000.0, 0))
              for device in ("cpu", "cuda")]
    for column in ("track_id", "plot_id", "association"):
        np.testing.assert_array_equal(tables[1][column], tables[0][column], err_msg=column)
    for column in ("x_ecef_m", "y_ecef_m", "z_ecef_m"):
        np.testing.assert_allclose(tables[1][column], tables[0][column], rtol=0.0, atol=1e-3, err_msg=column)
    assert next(network.parameters()).device.type == "cpu"

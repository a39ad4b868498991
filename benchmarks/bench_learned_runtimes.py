"""The learned estimators' batched step under each inference runtime (issue 29, deliverable 2).

The tracker steps a scan's (track, plot) pairs through the network-scaled Kalman filter
(`KalmanNet.step_scales` then the scaled filter step: `torch_filters.motion`, `predicted`, `updated`)
and through the LSTM update (`LSTMUpdate.step`, its MC-dropout masks given, then
`estimate_covariance`) in one call per scan. This times one such call at 1, 8, 64 and 512 rows
(pairs; an LSTM row is a track's 1 + mc_samples copies) under
- eager: PyTorch as the estimators run it (float64, no gradients);
- onnx-net: the network part alone (the GRU cell and head; the LSTM cell, dropout and output layer)
  exported to ONNX and run by ONNX Runtime (float64, one thread), the features and filter in eager;
- script: the whole step traced to TorchScript (`torch.jit.trace`, as `pipeline.learning.step_runtime`
  traces the estimators' steps);
- compile: the whole step through `torch.compile` (inductor, dynamic shapes), where this machine
  can compile it.
Untrained models of the default params.yaml sizes (speed does not depend on the weights), on one
thread. Each runtime's largest difference from eager over the rows (relative to the outputs'
magnitude) is printed beside its time, and whether its rows depend on the batch: `rows` is `same`
when the first row of a 512-row call equals, to the bit, that row run in a call of its own
(`batch_rows.padding` rows), as the estimators' scan-at-once check needs.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_learned_runtimes.py [--calls 200] [--no-compile]
"""

from __future__ import annotations

import argparse
import io as bytes_io
import time
import warnings
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor, nn

from pipeline.filters import torch_filters
from pipeline.filters.torch_filters import State, Step
from pipeline.learning import batch_rows
from pipeline.learning.kalman_net import KalmanNet, KalmanNetConfig, Memory
from pipeline.learning.lstm_update import Ensemble, LSTMUpdate, LSTMUpdateConfig
from pipeline.learning.step_runtime import LSTMStep
from pipeline.sections import subset
from pipeline.settings import load_params

BATCHES = (1, 8, 64, 512)
EARTH_M = 6.4e6


class KalmanNetStep(nn.Module):
    """`KalmanNet.step_scales` and the scaled filter step of B mature tracks as a function of tensors:
    (x, P, mu, hidden, estimate, measurement, last dt, age, z, R0, dt) -> (x, P, scales, hidden)."""

    def __init__(self, model: KalmanNet, network: Callable | None = None) -> None:
        super().__init__()
        self.model = model
        self.network = network  # the network part's replacement (ONNX Runtime), or the model's own

    def forward(self, x: Tensor, P: Tensor, mu: Tensor, hidden: Tensor, estimate: Tensor, measurement: Tensor,
                last_dt: Tensor, age: Tensor, z: Tensor, R0: Tensor, dt: Tensor) -> tuple[Tensor, ...]:
        model, spec = self.model, self.model.base
        memory = Memory(hidden, estimate, measurement, last_dt, age)
        state = State(x, P, mu)
        moving = torch.ones_like(age, dtype=torch.bool)
        if self.network is None:
            scales, memory = model.step_scales(memory, Step(0, state, z, R0, dt), ~moving, moving)
            q, r = scales.q, scales.r
        else:
            raw, hidden = self.network(model.features(memory, state, z, R0, dt), memory.hidden)
            q, r = (torch.sigmoid(raw) * model.amplitudes).unbind(1)
        prior = torch_filters.predicted(spec, state, *torch_filters.motion(spec, dt, q))
        posterior = torch_filters.updated(spec, prior, z, R0 * r[:, None, None])
        return posterior.x, posterior.P, q, r, memory.hidden if self.network is None else hidden


class LSTMNetwork(nn.Module):
    """The LSTM update's network part: features f (B N, 16), memory h, c (B N, H) and masks (B N, 16 + H)
    -> the output layer's correction (B N, 9) in the frame and the new h, c; row 0 of every N undropped."""

    def __init__(self, model: LSTMUpdate, copies: int) -> None:
        super().__init__()
        self.model, self.copies = model, copies

    def forward(self, f: Tensor, h: Tensor, c: Tensor, masks: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        h, c = self.model.cell(f, (h, c))
        read = torch.cat([f, h], 1)
        dropped = (read * masks).reshape(-1, self.copies, read.shape[1])
        kept = read.reshape(-1, self.copies, read.shape[1])[:, :1]
        read = torch.cat([kept, dropped[:, 1:]], 1).reshape(read.shape)
        return self.model.output(read) * self.model.output_scale, h, c


class LSTMStepOnnx(nn.Module):
    """`LSTMStep` with the network part on ONNX Runtime (`LSTMNetwork`)."""

    def __init__(self, model: LSTMUpdate, session) -> None:
        super().__init__()
        self.model, self.session = model, session

    def forward(self, x, h, c, age, z, R, dt, masks):
        model = self.model
        prior = model.predicted(x, dt)
        f, frame = model.features(prior, z, R, dt)
        B, N, _ = f.shape
        out, h, c = (torch.from_numpy(a) for a in self.session.run(None, {
            "f": f.reshape(B * N, -1).numpy(), "h": h.reshape(B * N, -1).numpy(), "c": c.reshape(B * N, -1).numpy(),
            "masks": masks.reshape(B * N, -1).numpy()}))
        correction = (frame.transpose(-1, -2) @ out.reshape(B, N, 3, 3)).reshape(B, N, 9)
        x = prior + correction
        position, covariance = model.estimate_covariance(x[..., ::3], age + 1, R)
        return x, h.reshape(B, N, -1), c.reshape(B, N, -1), age + 1, position, covariance


def session(network: nn.Module, example: tuple[Tensor, ...], names: list[str], outputs: list[str]):
    """An ONNX Runtime session (one thread) of `network` exported at `example`, the first axis dynamic."""
    import onnxruntime

    buffer = bytes_io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(network, example, buffer, input_names=names, output_names=outputs, dynamo=False,
                          dynamic_axes={name: {0: "rows"} for name in names + outputs})
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    return onnxruntime.InferenceSession(buffer.getvalue(), options, providers=["CPUExecutionProvider"])


class OnnxScaleNetwork:
    """The KalmanNet's `ScaleNetwork` on ONNX Runtime: (features, hidden) -> (raw, hidden) tensors."""

    def __init__(self, model: KalmanNet) -> None:
        example = (torch.rand(4, 4, dtype=torch.float64), torch.rand(4, model.config.hidden, dtype=torch.float64))
        self.session = session(model.network, example, ["features", "hidden"], ["raw", "next"])

    def __call__(self, features: Tensor, hidden: Tensor) -> tuple[Tensor, Tensor]:
        raw, hidden = self.session.run(None, {"features": features.numpy(), "hidden": hidden.numpy()})
        return torch.from_numpy(raw), torch.from_numpy(hidden)


def kalman_net_inputs(model: KalmanNet, rows: int, generator: torch.Generator) -> tuple[Tensor, ...]:
    """B mature tracks (three plots in) near the radar's height above ground, and their next plots."""
    def noise(*shape: int, scale: float = 1.0) -> Tensor:
        return torch.randn(*shape, generator=generator, dtype=torch.float64) * scale
    spec, H = model.base, model.config.hidden
    z0 = torch.tensor([EARTH_M, 0.0, 0.0], dtype=torch.float64) + noise(rows, 3, scale=5e4)
    R0 = torch.diag_embed(1e4 + noise(rows, 3).abs() * 1e4)
    state = torch_filters.start(spec, z0, R0)
    x = state.x.clone()
    x[..., 1::2] = noise(rows, 1, 3, scale=200.0)  # velocities
    return (x, state.P, state.mu, torch.tanh(noise(rows, H)), z0 - noise(rows, 3, scale=1e3),
            z0 - noise(rows, 3, scale=500.0),
            torch.full((rows,), 4.0, dtype=torch.float64), torch.full((rows,), 3, dtype=torch.long),
            z0 + x[:, 0, 1::2] * 4.0 + noise(rows, 3, scale=100.0), R0, 4.0 + noise(rows).abs())


def lstm_inputs(model: LSTMUpdate, rows: int, generator: torch.Generator) -> tuple[Tensor, ...]:
    """B tracks' ensembles a few plots in (`started`, copies spread), their next plots and masks."""
    def noise(*shape: int, scale: float = 1.0) -> Tensor:
        return torch.randn(*shape, generator=generator, dtype=torch.float64) * scale
    samples, _ = model.ensemble()
    H = model.config.hidden
    z0 = torch.tensor([EARTH_M, 0.0, 0.0], dtype=torch.float64) + noise(rows, 3, scale=5e4)
    ensemble = model.started(z0, samples)
    x = ensemble.x + noise(*ensemble.x.shape, scale=50.0)
    masks = torch.stack([model.dropout_masks(samples, generator) for _ in range(rows)])
    R = torch.diag_embed(1e4 + noise(rows, 3).abs() * 1e4)
    return (x, torch.tanh(noise(rows, samples, H)), noise(rows, samples, H), torch.full((rows,), 3, dtype=torch.long),
            z0 + noise(rows, 3, scale=800.0), R, 4.0 + noise(rows).abs(), masks)


def seconds_per_call(step: Callable, inputs: tuple[Tensor, ...], calls: int) -> float:
    """The best of three rounds of `calls` calls, per call."""
    with torch.inference_mode():
        for _ in range(3):
            step(*inputs)
        best = float("inf")
        for _ in range(3):
            start = time.perf_counter()
            for _ in range(calls):
                step(*inputs)
            best = min(best, (time.perf_counter() - start) / calls)
    return best


def rows_of(inputs: tuple[Tensor, ...], index: np.ndarray) -> tuple[Tensor, ...]:
    return tuple(value[torch.from_numpy(index)] for value in inputs)


def compare(step: Callable, eager: Callable, inputs: tuple[Tensor, ...], rows_each: int, elements_each: int
            ) -> tuple[float, str]:
    """The largest |runtime - eager| over all outputs relative to the output's largest magnitude, and
    whether row 0 of a call of all `inputs`' rows equals row 0 of its own padded call."""
    with torch.inference_mode():
        ours, theirs = step(*inputs), eager(*inputs)
        error = max(float((a - b).abs().max() / b.abs().max().clamp(min=1e-300)) for a, b in zip(ours, theirs))
        alone = step(*rows_of(inputs, batch_rows.padding(1, rows_each, elements_each)))
        same = all(torch.equal(a[:1], b[:1]) for a, b in zip(ours, alone))
    return error, "same" if same else "DIFFER"


def runtimes(module: nn.Module, onnx_step: Callable | None, example: tuple[Tensor, ...], check: tuple[Tensor, ...],
             compiled: bool) -> dict[str, Callable | str]:
    """Each runtime's step, or why it is not available."""
    steps: dict[str, Callable | str] = {"eager": module}
    steps["onnx-net"] = onnx_step if onnx_step is not None else "no export"
    try:
        with torch.inference_mode(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            traced = torch.jit.trace(module, example, check_trace=False)
            traced(*check)  # another batch size: a shape taken for a constant fails here
        steps["script"] = traced
    except Exception as error:  # noqa: BLE001 - reported in the table
        steps["script"] = f"trace failed: {type(error).__name__}: {str(error).splitlines()[0][:60]}"
    if compiled:
        try:
            function = torch.compile(module, dynamic=True)
            with torch.inference_mode():
                function(*example)
            steps["compile"] = function
        except Exception as error:  # noqa: BLE001 - reported in the table
            steps["compile"] = f"failed: {type(error).__name__}: {str(error).splitlines()[0][:60]}"
    return steps


def table(name: str, module: nn.Module, onnx_step: Callable | None, make_inputs: Callable, rows_each: int,
          elements_each: int, calls: int, compiled: bool) -> None:
    generator = torch.Generator().manual_seed(0)
    inputs = {rows: make_inputs(rows, generator) for rows in BATCHES}
    start = time.perf_counter()
    steps = runtimes(module, onnx_step, inputs[8], inputs[64], compiled)
    print(f"\n{name} (runtimes prepared in {time.perf_counter() - start:.1f} s)")
    print(f"{'runtime':10s} {'rows':>5s} {'us/call':>10s} {'us/row':>9s} {'x eager':>8s} {'rel. diff':>10s} rows")
    eager_times = {}
    for runtime, step in steps.items():
        if isinstance(step, str):
            print(f"{runtime:10s} {step}")
            continue
        error, verdict = compare(step, module, inputs[512], rows_each, elements_each)
        for rows in BATCHES:
            seconds = seconds_per_call(step, inputs[rows], max(calls // max(rows // 64, 1), 5))
            eager_times.setdefault(rows, seconds)
            print(f"{runtime:10s} {rows:5d} {seconds * 1e6:10.1f} {seconds * 1e6 / rows:9.2f} "
                  f"{eager_times[rows] / seconds:8.2f} {error:10.1e} {verdict}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--calls", type=int, default=200, help="calls per timing round at up to 64 rows")
    parser.add_argument("--no-compile", action="store_true", help="leave torch.compile out")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    params = load_params(args.params)
    kalman_net = KalmanNet(subset(KalmanNetConfig, params.kalman_net)).eval()
    lstm = LSTMUpdate(subset(LSTMUpdateConfig, params.lstm_update)).eval()
    samples, _ = lstm.ensemble()
    print(f"torch {torch.__version__}, {args.threads} thread(s), float64; kalman_net {kalman_net.config.base} "
          f"{kalman_net.config.cell} hidden {kalman_net.config.hidden}; lstm_update hidden {lstm.config.hidden}, "
          f"{samples} copies per row")
    for parameter in list(kalman_net.parameters()) + list(lstm.parameters()):  # weights that do something
        parameter.requires_grad_(False)
    with torch.no_grad():
        kalman_net.network.head.weight.normal_(0.0, 0.5)
    kalman_step = KalmanNetStep(kalman_net).eval()
    onnx_kalman = KalmanNetStep(kalman_net, OnnxScaleNetwork(kalman_net)).eval()
    table("kalman_net: step_scales + filter step", kalman_step, onnx_kalman,
          lambda rows, g: kalman_net_inputs(kalman_net, rows, g), 1, len(kalman_net.config.outputs), args.calls,
          not args.no_compile)
    width = 16 + lstm.config.hidden
    example = (torch.rand(2 * samples, 16, dtype=torch.float64), *(torch.rand(2 * samples, lstm.config.hidden,
                                                                              dtype=torch.float64),) * 2,
               torch.rand(2 * samples, width, dtype=torch.float64))
    onnx_lstm = LSTMStepOnnx(lstm, session(LSTMNetwork(lstm, samples), example, ["f", "h", "c", "masks"],
                                           ["out", "h_next", "c_next"])).eval()
    table(f"lstm_update: step ({samples} copies, masks given) + estimate_covariance", LSTMStep(lstm), onnx_lstm,
          lambda rows, g: lstm_inputs(lstm, rows, g), samples, batch_rows.VECTOR_STEP, args.calls, not args.no_compile)


if __name__ == "__main__":
    main()

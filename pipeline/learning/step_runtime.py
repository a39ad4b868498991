"""The learned estimators' batched steps as functions of tensors, run in eager PyTorch or as TorchScript (issue 29).

The tracker's network-scaled Kalman filter and LSTM update (`pipeline.tracker.kalman_net_estimator`,
`lstm_update_estimator`) step a scan's (track, plot) pairs in one call per role. Each call is a
hundred to two hundred small tensor operations (features, network, filter), so on the test split's
few pairs a call costs its Python dispatch: 1.0-2.0 ms eager at 1 to 8 rows, one thread. The
modules here wrap each step as a function of tensors, so that it can be traced once to TorchScript
(`torch.jit.trace`), whose interpreter runs the same ATen kernels with less dispatch: measured
(`benchmarks/bench_learned_runtimes.py`, 2 shared cores, one thread, default params' sizes) the
network-scaled filter's step 2.6x faster than eager at 1-8 rows, 2.0x at 64, 1.3x at 512; the LSTM
update's (17 copies a row) 1.9x at 1 row, 1.6x at 8, 1.1x at 64-512; and to the bit the numbers of
eager, so that the tracks are unchanged and a row still does not depend on the rows beside it
(`batch_rows`). The runtimes (`tracker.learned_runtime`):

- `script`: the traced function (not frozen: `torch.jit.freeze` would fold the weights into
  constants, which gains nothing measurable here), run with TorchScript's graph optimisation off
  (`Unoptimised`: its profiling and compiling cost the first calls of every process and gain nothing
  on the CPU);
- `eager`: the modules called as they are.

The benchmark prints two others beside these. ONNX Runtime of the network part alone (the GRU cell
and head; the LSTM cell, dropout and output layer) gained little or lost (0.7-1.6x eager: the
network is a few of the call's operations, and the rest stays eager). `torch.compile` (inductor,
dynamic shapes) was up to 1.3x faster than TorchScript on the filter's step at 1-8 rows and 1.3-1.6x
on the LSTM's at 64-512 rows, with rows that did not depend on the batch in the scan tests; it is
not adopted because it gives other last bits than eager (every tracker metric would have to be
measured again), it compiles for 36 s (cached) to 85 s (cold) per step and process on this machine,
which the test split's calls do not win back, and past its recompilation limit it runs eager, other
bits mid-run. TorchScript is deprecated in torch 2.13 (it still runs; its warnings are silenced at
the trace).

A traced function takes the batch size from its inputs (sizes are traced as such; a `len()` would
have been taken for a constant) and runs on the device of the inputs it was traced with
(`tracker.device`): it is traced per (model, runtime, device) on first use and kept (`traced`).
Every function runs under `torch.no_grad()` by its caller.
"""

from __future__ import annotations

import warnings
import weakref
from collections.abc import Callable

import torch
from torch import Tensor, nn

from pipeline.filters import torch_filters
from pipeline.filters.torch_filters import State, Step
from pipeline.learning import batch_rows
from pipeline.learning.kalman_net import KalmanNet, Memory
from pipeline.learning.lstm_update import Ensemble, LSTMUpdate

RUNTIMES = ("script", "eager")
TRACE_ROWS = 16  # rows of the example a function is traced with (any size runs after)


class KalmanNetPlotStep(nn.Module):
    """`KalmanNet.step_scales` and the prediction with its scales of B tracks towards their plots:
    (posterior x (B, M, n), P (B, M, n, n), mu (B, M); memory hidden (B, H), estimate (B, 3),
    measurement (B, 3), dt (B,), age (B,); plot z (B, 3), R0 (B, 3, 3), dt (B,) s; fresh, moving (B,)
    bool) -> (scales (B, K) in `config.outputs` order, the memory after the step (its five fields),
    the prior x, P, mu)."""

    def __init__(self, model: KalmanNet) -> None:
        super().__init__()
        self.model = model

    def forward(self, x: Tensor, P: Tensor, mu: Tensor, hidden: Tensor, estimate: Tensor, measurement: Tensor,
                last_dt: Tensor, age: Tensor, z: Tensor, R0: Tensor, dt: Tensor, fresh: Tensor, moving: Tensor
                ) -> tuple[Tensor, ...]:
        model, spec = self.model, self.model.base
        state = State(x, P, mu)
        scales, memory = model.step_scales(Memory(hidden, estimate, measurement, last_dt, age),
                                           Step(0, state, z, R0, dt), fresh, moving)
        prior = torch_filters.predicted(spec, state, *torch_filters.motion(spec, dt, scales.q, scales.manoeuvre))
        named = {"q": scales.q, "r": scales.r, "manoeuvre": scales.manoeuvre}
        return (torch.stack([named[name] for name in model.config.outputs], 1), memory.hidden, memory.estimate,
                memory.measurement, memory.dt, memory.age, prior.x, prior.P, prior.mu)


class KalmanNetUpdate(nn.Module):
    """The filter update of B priors x, P, mu with plots z (B, 3) of scaled covariance R (B, 3, 3):
    (posterior x, P, mu, its position (B, 3) and position covariance (B, 3, 3))."""

    def __init__(self, model: KalmanNet) -> None:
        super().__init__()
        self.model = model

    def forward(self, x: Tensor, P: Tensor, mu: Tensor, z: Tensor, R: Tensor) -> tuple[Tensor, ...]:
        posterior = torch_filters.updated(self.model.base, State(x, P, mu), z, R)
        return (posterior.x, posterior.P, posterior.mu, *torch_filters.position_estimates(posterior))


class LSTMPredict(nn.Module):
    """The LSTM update's prediction of B tracks' N copies x (B, N, 9) of `age` (B,) over dt (B,) s: the
    point prediction (B, 3) and its calibrated covariance (B, 3, 3) (`LSTMUpdate.prediction_covariance`)."""

    def __init__(self, model: LSTMUpdate) -> None:
        super().__init__()
        self.model = model

    def forward(self, x: Tensor, age: Tensor, dt: Tensor) -> tuple[Tensor, Tensor]:
        return self.model.prediction_covariance(self.model.predicted(x, dt)[..., ::3], age, dt)


class LSTMStep(nn.Module):
    """`LSTMUpdate.step` of B tracks' N copies (x (B, N, 9), h, c (B, N, H), age (B,)) with plots z (B, 3)
    of covariance R (B, 3, 3) after dt (B,) s, the dropout masks (B, N, 16 + H) given (MC dropout on),
    and `estimate_covariance`: (the new x, h, c, age, the point estimate (B, 3) and its calibrated
    covariance (B, 3, 3))."""

    def __init__(self, model: LSTMUpdate) -> None:
        super().__init__()
        self.model = model

    def forward(self, x: Tensor, h: Tensor, c: Tensor, age: Tensor, z: Tensor, R: Tensor, dt: Tensor, masks: Tensor
                ) -> tuple[Tensor, ...]:
        after, _ = self.model.step(Ensemble(x, h, c, age), z, R, dt, True, masks)
        return (after.x, after.h, after.c, after.age, *self.model.estimate_covariance(after.x[..., ::3], after.age, R))


class LSTMStepAlone(LSTMStep):
    """`LSTMStep` of B tracks, each track's numbers those of a call of that track alone (the young tracks of
    a scan, which plot by plot step one call each: `pipeline.tracker.lstm_update_estimator`).

    MKL's dgemm computes a call's last rows, its row count modulo `batch_rows.GEMM_ROWS`, with another
    kernel than the others, in other last bits: a track's N copies alone (N = 17: one such row, its last
    copy) are not the same rows as in a call of several tracks. Each of the step's matrix products (the
    LSTM cell's two, the output layer) is therefore split: the copies that a call of one track computes
    in whole blocks of rows go through one product for all B tracks, each track's padded with zero rows
    to whole blocks (the padding depends on the model alone, so the trace holds for any B); its last
    `tail` copies go through a batched product (`baddbmm`) of one item per track, a block of zero rows
    and then the track's tail copies, so that they are again a product's last rows (one row alone, or
    a pair, is computed by other kernels still, which depend on the product's sizes: measured with
    torch 2.13 and MKL 2024.2). The cell is `nn.LSTMCell`'s CPU formula (ATen's `LSTMCell`: the hidden
    product plus the input product, then the gates), the rest `LSTMUpdate.step`'s; the tests compare
    it with one-track `LSTMStep` calls to the bit (`tests/test_learned_scans.py`)."""

    def __init__(self, model: LSTMUpdate) -> None:
        super().__init__(model)
        samples, _ = model.ensemble()
        alone = len(batch_rows.padding(1, samples)) * samples  # rows of a call of one track (padded)
        self.tail = alone % batch_rows.GEMM_ROWS if alone == samples else 0  # padded: the padding is the tail
        self.padding = -(samples - self.tail) % batch_rows.GEMM_ROWS  # zero rows after each track's block copies

    def _linear(self, rows: Tensor, weight: Tensor, bias: Tensor) -> Tensor:
        """`nn.functional.linear` of rows (B, N, K) -> (B, N, O), each track's as in a call of it alone."""
        tracks, block = rows.shape[0], rows.shape[1] - self.tail
        head = rows[:, :block]
        if self.padding:  # whole blocks per track, whatever the number of tracks (a constant in the trace)
            head = torch.cat([head, head.new_zeros(tracks, self.padding, rows.shape[2])], 1)
        out = nn.functional.linear(head.reshape(-1, rows.shape[2]), weight, bias).reshape(tracks, -1, bias.shape[0])
        out = out[:, :block]
        if not self.tail:
            return out
        lead = batch_rows.GEMM_ROWS
        items = torch.cat([rows.new_zeros(tracks, lead, rows.shape[2]), rows[:, block:]], 1)
        last = torch.baddbmm(bias.expand(tracks, lead + self.tail, bias.shape[0]), items,
                             weight.t().expand(tracks, weight.shape[1], weight.shape[0]))
        return torch.cat([out, last[:, lead:]], 1)

    def forward(self, x: Tensor, h: Tensor, c: Tensor, age: Tensor, z: Tensor, R: Tensor, dt: Tensor, masks: Tensor
                ) -> tuple[Tensor, ...]:
        model = self.model
        cell = model.cell
        prior = model.predicted(x, dt)
        f, frame = model.features(prior, z, R, dt)
        gates = self._linear(h, cell.weight_hh, cell.bias_hh) + self._linear(f, cell.weight_ih, cell.bias_ih)
        ingate, forgetgate, cellgate, outgate = gates.chunk(4, 2)
        c_after = forgetgate.sigmoid() * c + ingate.sigmoid() * cellgate.tanh()
        h_after = outgate.sigmoid() * c_after.tanh()
        read = torch.cat([f, h_after], 2)
        dropped = read * masks
        if read.shape[1] > 1:  # copy 0: the point estimate
            dropped = torch.cat([read[:, :1], dropped[:, 1:]], 1)
        correction = self._linear(dropped, model.output.weight, model.output.bias) * model.output_scale
        correction = (frame.transpose(-1, -2) @ correction.reshape(*correction.shape[:2], 3, 3)
                      ).reshape(prior.shape)
        after = Ensemble(prior + correction, h_after, c_after, age + 1)
        return (after.x, after.h, after.c, after.age, *model.estimate_covariance(after.x[..., ::3], after.age, R))


class LSTMStepUnmasked(LSTMStep):
    """`LSTMStep` without dropout (a model of dropout 0: one copy, no masks): the same outputs."""

    def forward(self, x: Tensor, h: Tensor, c: Tensor, age: Tensor, z: Tensor, R: Tensor, dt: Tensor
                ) -> tuple[Tensor, ...]:
        after, _ = self.model.step(Ensemble(x, h, c, age), z, R, dt, False)
        return (after.x, after.h, after.c, after.age, *self.model.estimate_covariance(after.x[..., ::3], after.age, R))


_TRACED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # model -> {(function, runtime, device): traced}


def traced(model: nn.Module, function: type[nn.Module], runtime: str, example: Callable[[int], tuple[Tensor, ...]]
           ) -> Callable[..., tuple[Tensor, ...]]:
    """`function(model)` (one of this module's steps) on `runtime` (`RUNTIMES`), traced on first use with
    `example(TRACE_ROWS)` (inputs on the device it is to run on), run `Unoptimised`, and kept while `model` lives.
    ValueError naming `tracker.learned_runtime` for another runtime."""
    if runtime not in RUNTIMES:
        raise ValueError(f"tracker.learned_runtime = {runtime!r}: must be one of {RUNTIMES}")
    step = function(model).eval()
    if runtime == "eager":
        return step
    inputs = example(TRACE_ROWS)
    key = (function, runtime, str(inputs[0].device))
    kept = _TRACED.setdefault(model, {})
    if key not in kept:
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # TorchScript's deprecation, and the tracer's on Python values
            kept[key] = Unoptimised(torch.jit.trace(step, inputs, check_trace=False))
    return kept[key]


class Unoptimised:
    """A traced step (`module`, a `torch.jit.ScriptModule`) called with TorchScript's graph optimisation off
    (`torch.jit.optimized_execution(False)`): the interpreter runs the traced graph as it is. The profiling
    executor's optimisation would first run a call or two profiling and then compile each step, 60-80 ms of
    the first calls of every step in every process (more than the whole tracking of a one-minute
    recording), and then run no faster on the CPU (no CPU fusion): measured with torch 2.13, one thread,
    the LSTM update's step at 1, 20 and 100 tracks, the same per call within the noise, the same bits."""

    def __init__(self, module: torch.jit.ScriptModule) -> None:
        self.module = module

    def __call__(self, *inputs: Tensor) -> tuple[Tensor, ...]:
        with torch.jit.optimized_execution(False):
            return self.module(*inputs)

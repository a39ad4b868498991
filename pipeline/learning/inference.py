"""Fast batch inference for the tracker's per-plot network calls.

The tracker calls a network for a handful of windows at a time, tens of thousands of times
per scenario. At that size PyTorch's per-call overhead dominates (about 200 us for the
predictor), while ONNX Runtime runs the same graph in about 35 us. So the tracker exports
each trained network to ONNX once, in memory, when it loads it, and runs it with ONNX
Runtime on one thread; `tracker.inference: torch` runs the PyTorch module instead. Both
give the same outputs to float32 rounding (checked at load).
"""

from __future__ import annotations

import io as bytes_io
import warnings

import numpy as np
import torch
from torch import nn

BACKENDS = ("onnx", "torch")
EXPORT_CHECK_TOLERANCE = 1e-4  # relative to the outputs' largest magnitude (at least 1): float32 rounding


class BatchNetwork:
    """A trained network as a function of float arrays (N x steps x features) -> numpy outputs."""

    def __init__(self, network: nn.Module, input_steps: int, input_features: int, backend: str = "onnx") -> None:
        if backend not in BACKENDS:
            raise ValueError(f"inference backend {backend!r}: must be one of {BACKENDS}")
        self.network = network.eval()
        self.backend = backend
        example = torch.zeros(2, input_steps, input_features)
        if backend == "onnx":
            self._session = _onnx_session(self.network, example)
            probe = torch.linspace(-1.0, 1.0, example.numel()).reshape(example.shape)
            expected = self._torch(probe.numpy())
            difference = np.abs(self(probe.numpy()) - expected).max()
            if difference > EXPORT_CHECK_TOLERANCE * max(1.0, float(np.abs(expected).max())):
                raise RuntimeError(f"ONNX export of the {type(network).__name__} differs from PyTorch by {difference}"
                                   f" (its outputs reach {np.abs(expected).max():.4g})")

    @torch.inference_mode()
    def _torch(self, windows: np.ndarray) -> np.ndarray:
        return self.network(torch.as_tensor(windows, dtype=torch.float32)).numpy()

    def __call__(self, windows: np.ndarray) -> np.ndarray:
        if self.backend == "torch":
            return self._torch(windows)
        return self._session.run(None, {"windows": np.ascontiguousarray(windows, dtype=np.float32)})[0]


def _onnx_session(network: nn.Module, example: torch.Tensor) -> object:
    import onnxruntime

    buffer = bytes_io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript-based exporter warns about its own deprecation
        torch.onnx.export(network, (example,), buffer, input_names=["windows"], output_names=["outputs"],
                          dynamic_axes={"windows": {0: "batch"}, "outputs": {0: "batch"}}, dynamo=False)
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    return onnxruntime.InferenceSession(buffer.getvalue(), options, providers=["CPUExecutionProvider"])

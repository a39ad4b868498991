"""Trained models on disk: one file per network with its weights, config and extras (`save_network`).

Two layouts, both kept as they are so that the bundles already on disk still load, with the same bytes:
- a thesis network (`pipeline.learning.networks`) also keeps the scaler of its windows, and a format
  version: `load_model(path)` is the one way to get it back usable. It refuses a file whose weights do
  not fit the architecture recorded with them, and the tracker compares the recorded scaler with the
  windows' scaler so a model is never fed differently scaled data;
- every other network (the network-scaled filter, the LSTM update, the association network) keeps its
  config dataclass, weights (buffers included) and extras: `load_network(path, build, stage)`.
The file holds only tensors and plain values, so it loads with `weights_only=True`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any, Callable

import torch
from torch import nn

from pipeline import io
from pipeline.learning.networks import NetworkConfig, build_network
from pipeline.learning.scaling import WindowScaler

FORMAT_VERSION = 1


@dataclass
class LoadedModel:
    network: nn.Module
    config: NetworkConfig
    scaler: WindowScaler
    extras: dict[str, Any] = field(default_factory=dict)

    @torch.no_grad()
    def predict(self, scaled_windows: torch.Tensor) -> torch.Tensor:
        return self.network(scaled_windows)


def first_non_finite(tensors: Mapping[str, Any]) -> str | None:
    """The name of the first floating-point tensor of `tensors` (a state dict) holding a NaN or an infinity,
    None when every one is finite (other values are skipped). One check over all of them, then the search."""
    floating = {name: value for name, value in tensors.items()
                if isinstance(value, torch.Tensor) and value.is_floating_point()}
    if not floating or bool(torch.stack([torch.isfinite(value).all() for value in floating.values()]).all()):
        return None
    return next(name for name, value in floating.items() if not bool(torch.isfinite(value).all()))


def _finite_weights(path: Path, state_dict: Mapping[str, Any], stage: str) -> None:
    """InputError naming the file and the tensor when a saved network's weights are not all finite: a training
    that diverged (before its stage refused to save one), or a damaged file; the network would give NaN."""
    tensor = first_non_finite(state_dict)
    if tensor is not None:
        values = state_dict[tensor]
        bad = int((~torch.isfinite(values)).sum())
        raise io.InputError(f"{path}: weight tensor '{tensor}' has {bad} non-finite values (NaN or infinite) of "
                            f"{values.numel()}: its training diverged; train it again (`dvc repro {stage}`, "
                            "with a lower learning rate)")


def write_bundle(bundle: dict[str, Any], path: str | Path) -> None:
    """Write a dict of tensors and plain values atomically; the same values give the same bytes.

    torch.save names the records of its zip archive after the file it writes to, so saving to
    the temporary file made the bytes differ from run to run; the bundle is serialised in
    memory (archive name `bundle`) and written as bytes."""
    buffer = BytesIO()
    torch.save(bundle, buffer)
    io.write_bytes(buffer.getvalue(), path)


def read_bundle(path: str | Path) -> dict[str, Any]:
    """A dict written by `write_bundle` (tensors and plain values only: `weights_only`); InputError naming the
    file when it is missing or not such a file."""
    path = Path(path)
    if not path.is_file():
        raise io.InputError(f"{path}: model file not found (run `dvc repro` to train it)")
    try:
        bundle = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many types for a corrupt or foreign file
        raise io.InputError(f"{path}: not a readable model file ({type(error).__name__}: {error})") from None
    if not isinstance(bundle, dict):
        raise io.InputError(f"{path}: not a model bundle")
    return bundle


def load_network(path: str | Path, build: Callable[[dict[str, Any]], nn.Module], stage: str) -> nn.Module:
    """A network saved by `save_network` without a scaler (the network-scaled filter, the LSTM update, the
    association network), built by `build(config)`, given its weights, in eval mode.

    InputError naming the file and the `dvc repro` stage that makes it when the file is missing or unreadable,
    or its config or weights do not fit `build`'s network (another network's file, or one saved by another
    version of the code): torch and the configs raise TypeError, ValueError, KeyError or RuntimeError; and
    naming the tensor when a weight is not finite."""
    path = Path(path)
    bundle = read_bundle(path)
    if not isinstance(bundle.get("config"), dict) or "state_dict" not in bundle:
        raise io.InputError(f"{path}: not a saved network (no config and weights); make it again with "
                            f"`dvc repro {stage}`")
    try:
        network = build(bundle["config"])
        network.load_state_dict(bundle["state_dict"])
    except (TypeError, ValueError, KeyError, RuntimeError) as error:
        raise io.InputError(f"{path}: its config or weights do not fit the network `dvc repro {stage}` makes "
                            f"(another network's file, or an older one?): {type(error).__name__}: "
                            f"{str(error).splitlines()[0] if str(error) else ''}") from None
    _finite_weights(path, bundle["state_dict"], stage)
    return network.eval()


def save_network(path: str | Path, network: nn.Module, extras: dict[str, Any] | None = None,
                 scaler: WindowScaler | None = None) -> None:
    """Write `network` (its dataclass `config`, its weights) and `extras` as one bundle, atomically
    (`write_bundle`); the same weights give the same bytes. With the `scaler` of its windows: a thesis
    network's bundle (`load_model`), else another network's (`load_network`)."""
    if scaler is None:
        bundle = {"config": asdict(network.config), "state_dict": network.state_dict(), "extras": extras or {}}
    else:
        bundle = {"format_version": FORMAT_VERSION, "config": asdict(network.config), "scaler": scaler.to_dict(),
                  "extras": extras or {},
                  "state_dict": {name: tensor.detach().cpu() for name, tensor in network.state_dict().items()}}
    write_bundle(bundle, path)


def load_model(path: str | Path, expected_kind: str | None = None,
               expected_scaler: WindowScaler | None = None) -> LoadedModel:
    """Load a thesis network's bundle (`save_network` with a scaler); InputError naming the file and what is
    wrong: missing or unreadable, another kind, weights that do not fit the architecture or are not all finite,
    a scaler other than `expected_scaler` (the network would be fed differently scaled windows)."""
    path = Path(path)
    bundle = read_bundle(path)
    if bundle.get("format_version") != FORMAT_VERSION:
        raise io.InputError(f"{path}: not a model bundle of format {FORMAT_VERSION}")
    config = NetworkConfig.from_dict(bundle["config"])
    if expected_kind is not None and config.kind != expected_kind:
        raise io.InputError(f"{path}: holds a {config.kind} network, expected a {expected_kind}")
    network = build_network(config)
    try:
        network.load_state_dict(bundle["state_dict"])
    except RuntimeError as error:
        raise io.InputError(f"{path}: weights do not fit the {config.kind} architecture recorded in the file "
                            f"({str(error).splitlines()[0]})") from None
    _finite_weights(path, bundle["state_dict"], f"train_{config.kind}")
    network.eval()
    scaler = WindowScaler.from_dict(bundle["scaler"])
    if expected_scaler is not None and scaler != expected_scaler:
        raise io.InputError(f"{path}: built with the scaler {scaler}, but params give {expected_scaler}; "
                            f"retrain it (dvc repro train_{config.kind})")
    return LoadedModel(network, config, scaler, dict(bundle["extras"]))

"""Trained models on disk: one file per network with its weights, config, scaler and extras.

`load_model(path)` is the one way to get a usable network back. It refuses a file whose
weights do not fit the architecture recorded with them, and the tracker compares the
recorded scaler with the windows' scaler so a model is never fed differently scaled data.
The file holds only tensors and plain values, so it loads with `weights_only=True`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any

import torch
from torch import nn

from pipeline import io
from pipeline.networks import NetworkConfig, build_network
from pipeline.scaling import WindowScaler

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


def save_model(path: str | Path, network: nn.Module, config: NetworkConfig, scaler: WindowScaler,
               extras: dict[str, Any] | None = None) -> None:
    """Write the bundle atomically (`write_bundle`); the same weights give the same bytes."""
    write_bundle({
        "format_version": FORMAT_VERSION,
        "config": config.to_dict(),
        "scaler": scaler.to_dict(),
        "extras": extras or {},
        "state_dict": {name: tensor.detach().cpu() for name, tensor in network.state_dict().items()},
    }, path)


def load_model(path: str | Path, expected_kind: str | None = None) -> LoadedModel:
    """Load a bundle written by `save_model`; errors name the file and what is wrong."""
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
    network.eval()
    return LoadedModel(network, config, WindowScaler.from_dict(bundle["scaler"]), dict(bundle["extras"]))

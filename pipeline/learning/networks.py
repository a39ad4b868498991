"""The thesis's three recurrent networks (spec section 6), as plain torch modules.

PyTorch's GRU uses tanh and sigmoid gates and applies the reset gate after the recurrent
matrix product, which is Keras's default GRU (reset_after=True), so these are the thesis's
layers. Output layers are linear: bounded activations broke the thesis's models.

Layer sizes are lists, so a deeper or wider variant is a params change, not a code change.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from torch import nn

KINDS = ("filter", "predictor", "autoencoder")


@dataclass(frozen=True)
class NetworkConfig:
    """Everything needed to rebuild a network: its kind, sizes and window shape."""

    kind: str
    hidden: tuple[int, ...]
    input_steps: int
    input_features: int
    output_steps: int
    output_features: int
    decoder_hidden: tuple[int, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "NetworkConfig":
        return cls(kind=data["kind"], hidden=tuple(data["hidden"]), input_steps=int(data["input_steps"]),
                   input_features=int(data["input_features"]), output_steps=int(data["output_steps"]),
                   output_features=int(data["output_features"]), decoder_hidden=tuple(data["decoder_hidden"]))


class StackedGRU(nn.Module):
    """GRU layers of different widths in sequence (Keras-style stacking), batch first."""

    def __init__(self, input_size: int, hidden: tuple[int, ...]) -> None:
        super().__init__()
        sizes = (input_size, *hidden)
        self.layers = nn.ModuleList(nn.GRU(a, b, batch_first=True) for a, b in zip(sizes[:-1], sizes[1:]))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.layers:
            x, _ = layer(x)
        return x


class FilterNetwork(nn.Module):
    """Last N plots -> the last M plots denoised (GRU 8 -> GRU 16 -> dense M*F in the thesis)."""

    def __init__(self, config: NetworkConfig) -> None:
        super().__init__()
        self.config = config
        self.recurrent = StackedGRU(config.input_features, config.hidden)
        self.head = nn.Linear(config.hidden[-1], config.output_steps * config.output_features)

    def forward(self, plots: torch.Tensor) -> torch.Tensor:
        last = self.recurrent(plots)[:, -1]
        return self.head(last).view(-1, self.config.output_steps, self.config.output_features)


class PredictorNetwork(nn.Module):
    """States s0..s4 -> s2..s5: at each input step from the second on, the next state
    (GRU 32 -> GRU 32 -> dense 5 per step in the thesis). The last output is the prediction."""

    def __init__(self, config: NetworkConfig) -> None:
        super().__init__()
        self.config = config
        self.recurrent = StackedGRU(config.input_features, config.hidden)
        self.head = nn.Linear(config.hidden[-1], config.output_features)

    def forward(self, states: torch.Tensor) -> torch.Tensor:
        return self.head(self.recurrent(states)[:, -self.config.output_steps:])


class Autoencoder(nn.Module):
    """Plots -> code (last output of GRU 12 -> GRU 10) -> code repeated per step ->
    GRU 12 -> GRU 10 -> dense 5 per step: the plots reconstructed."""

    def __init__(self, config: NetworkConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = StackedGRU(config.input_features, config.hidden)
        self.decoder = StackedGRU(config.hidden[-1], config.decoder_hidden)
        self.head = nn.Linear(config.decoder_hidden[-1], config.output_features)

    def forward(self, plots: torch.Tensor) -> torch.Tensor:
        code = self.encoder(plots)[:, -1]
        repeated = code.unsqueeze(1).expand(-1, self.config.output_steps, -1)
        return self.head(self.decoder(repeated))


def build_network(config: NetworkConfig) -> nn.Module:
    if config.kind == "filter":
        return FilterNetwork(config)
    if config.kind == "predictor":
        return PredictorNetwork(config)
    if config.kind == "autoencoder":
        return Autoencoder(config)
    raise ValueError(f"network kind {config.kind!r}: must be one of {KINDS}")

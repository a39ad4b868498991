"""What a tracker runs: the trained networks, each ready for fast batch inference, and the
tuned classical filters (by kind: cv, ca, imm)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from pipeline.classical_filters import FilterSettings
from pipeline.inference import BatchNetwork
from pipeline.model_store import LoadedModel


@dataclass
class Models:
    predictor: LoadedModel
    filter: LoadedModel
    autoencoder: LoadedModel | None = None
    backend: str = "onnx"
    filters: Mapping[str, FilterSettings] = field(default_factory=dict)
    runnable: dict[str, BatchNetwork] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        loaded = {"predictor": self.predictor, "filter": self.filter, "autoencoder": self.autoencoder}
        self.runnable = {kind: BatchNetwork(model.network, model.config.input_steps, model.config.input_features,
                                            self.backend)
                         for kind, model in loaded.items() if model is not None}

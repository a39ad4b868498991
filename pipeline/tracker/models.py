"""What a run's trackers need, loaded by need (`pipeline.tracker.loading`): the pieces by name, as
`pipeline.learning.kinds.PIECES` names them (`models["predictor"]`, `models["kalman_tuned"]`, the
tuned classical filters by kind, `models["lstm_update"]`, `models["kalman_net"]`, ...), each ready to use,
and the thesis's networks also as batch functions for fast inference."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pipeline.learning.inference import BatchNetwork


@dataclass
class Models:
    """`pieces`: the loaded pieces by name; a method's `needs` name the ones it reads (`models[piece]`).
    `runnable` holds each thesis network (a `model_store.LoadedModel`) as a batch function
    (`pipeline.learning.inference`, on `backend`)."""

    pieces: Mapping[str, Any] = field(default_factory=dict)
    backend: str = "onnx"
    runnable: dict[str, BatchNetwork] = field(init=False, repr=False)

    def __getitem__(self, piece: str) -> Any:
        if piece not in self.pieces:
            raise KeyError(f"{piece}: not loaded (no method of the run needs it)")
        return self.pieces[piece]

    def __post_init__(self) -> None:
        networks = {name: model for name, model in self.pieces.items() if hasattr(model, "scaler")}
        self.runnable = {}
        if networks:
            import torch

            from pipeline.learning.inference import BatchNetwork  # imports torch: only when a network is loaded
            torch.set_num_threads(1)  # the tracker's batches are a few windows: threads only add contention
            self.runnable = {name: BatchNetwork(model.network, model.config.input_steps, model.config.input_features,
                                                self.backend) for name, model in networks.items()}

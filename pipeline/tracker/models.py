"""What a run's trackers need, loaded by need (`pipeline.tracker.loading`): the trained networks,
each ready for fast batch inference, the tuned classical filters by kind (cv, ca, imm), the
LSTM-update estimator (`pipeline.learning.lstm_update`) and the network-scaled filter (`pipeline.learning.kalman_net`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Mapping

from pipeline.filters.classical_filters import FilterSettings

if TYPE_CHECKING:
    from pipeline.learning.inference import BatchNetwork
    from pipeline.learning.kalman_net import KalmanNet
    from pipeline.learning.lstm_update import LSTMUpdate
    from pipeline.learning.model_store import LoadedModel


@dataclass
class Models:
    """Each piece is None (the networks) or empty (the filters) when no method of the run needs it.
    `runnable` holds each loaded network as a batch function (`pipeline.learning.inference`, on `backend`)."""

    predictor: LoadedModel | None = None
    filter: LoadedModel | None = None
    autoencoder: LoadedModel | None = None
    filters: Mapping[str, FilterSettings] = field(default_factory=dict)
    backend: str = "onnx"
    lstm_update: LSTMUpdate | None = None
    kalman_net: KalmanNet | None = None  # the network-scaled filter (issue 17), in eval mode
    runnable: dict[str, BatchNetwork] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        loaded = {kind: model for kind, model in (("predictor", self.predictor), ("filter", self.filter),
                                                  ("autoencoder", self.autoencoder)) if model is not None}
        self.runnable = {}
        if loaded or self.lstm_update is not None:
            import torch

            torch.set_num_threads(1)  # the tracker's batches are a few windows: threads only add contention
        if loaded:
            from pipeline.learning.inference import BatchNetwork  # imports torch: only when a network is loaded
            self.runnable = {kind: BatchNetwork(model.network, model.config.input_steps, model.config.input_features,
                                                self.backend) for kind, model in loaded.items()}

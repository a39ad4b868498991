"""The confirmation network's Lightning task (`pipeline.learning.confirmation`): binary cross-entropy of each
association's logit against its label, Adam, the associations in seeded random batches."""

from __future__ import annotations

from typing import Any

import lightning as L
import numpy as np
import torch
from torch import Tensor, nn
from torch.utils.data import BatchSampler, DataLoader, RandomSampler

from pipeline.learning.confirmation import HitScorer
from pipeline.learning.fit import FitConfig, Task
from pipeline.learning.training import TensorBatches
from pipeline.sections import subset


class CandidateBatches(L.LightningDataModule):
    """The associations in random batches of `batch_size` (a sampler seeded with `seed`), each cut by fancy
    indexing from in-memory tensors (`training.TensorBatches`)."""

    def __init__(self, inputs: np.ndarray, labels: np.ndarray, batch_size: int, seed: int) -> None:
        super().__init__()
        self.batches = TensorBatches(torch.from_numpy(inputs), torch.from_numpy(labels))
        self.batch_size, self.seed = batch_size, seed

    def train_dataloader(self) -> DataLoader:
        sampler = RandomSampler(self.batches, generator=torch.Generator().manual_seed(self.seed))
        return DataLoader(self.batches, sampler=BatchSampler(sampler, self.batch_size, drop_last=False),
                          batch_size=None)


class ConfirmationTraining(L.LightningModule):
    """Binary cross-entropy of the associations' logits, Adam."""

    def __init__(self, model: HitScorer, learning_rate: float) -> None:
        super().__init__()
        self.model, self.learning_rate = model, learning_rate
        self.loss = nn.BCEWithLogitsLoss()

    def training_step(self, batch: tuple[Tensor, Tensor], batch_index: int) -> dict:
        inputs, labels = batch
        return {"loss": self.loss(self.model(inputs), labels), "weight": len(labels)}

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(self.model.parameters(), lr=self.learning_rate)


def training_task(network: HitScorer, inputs: np.ndarray, labels: np.ndarray, knobs: Any, deterministic: bool
                  ) -> Task:
    """`network` trained on associations' features (N, 5) float32 and 0/1 labels (N,) float32, by `knobs`: params'
    `confirmation` section (epochs, batch_size, learning_rate, seed)."""
    config = subset(FitConfig, knobs, label="the confirmation network", loss_name="confirmation.train_loss",
                    deterministic=deterministic)
    return Task(ConfirmationTraining(network, knobs.learning_rate),
                CandidateBatches(inputs, labels, knobs.batch_size, knobs.seed), config)

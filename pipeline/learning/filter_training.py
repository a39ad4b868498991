"""Gradient descent on a filter over training segments with Lightning: the network-scaled filter and the
gradient-tuned classical filters share this loop, loss, data and truncation.

Material: the target plots of a split (their own radar noise: each epoch sees the same noisy
plots, as the Nelder-Mead tuner does; drawing fresh noise every epoch as the seed paper does
would need the plots re-simulated from the truth each epoch), in time order per route, the filter
restarted at gaps and every `segment_plots` plots (`tuning.target_sequences`), packed into rows of
at most `segment_plots` steps. A batch is `batch_segments` rows; the filter runs over them with its
state (and the network's memory) cut from the graph every `truncation_steps` steps (truncated
BPTT: a step's error reaches back at most that many steps), and Adam takes one step per batch, its
learning rate annealed to 0 over the epochs on a cosine (the seed's schedule).

Loss: the mean distance (m) of the filtered positions from the truth over the scored plots (past
each restart's burn-in), `SequenceBatch.position_error`: the seed trains on the L1 error, and the
hold-out comparison's headline is the mean error. With Gaussian noise the Kalman gain minimises the
error covariance, hence the mean distance too, so a gradient-tuned R scale still goes to the true
noise ratio (tests/test_kalman_net.py).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, fields

import lightning as L
import pyarrow as pa
import pyarrow.compute as pc
import torch
from torch import Tensor, nn
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler

from pipeline import io
from pipeline.filters import tuning
from pipeline.filters.torch_filters import SequenceBatch
from pipeline.learning import training  # training: Lightning's logging set up as for the other networks
from pipeline.params import Radar

log = logging.getLogger("pipeline")


@dataclass(frozen=True)
class DescentConfig:
    """How one filter is trained (params.yaml `kalman_net`)."""

    epochs: int
    batch_segments: int
    learning_rate: float
    truncation_steps: int
    seed: int
    deterministic: bool


def training_segments(plots: pa.Table, holdout: pa.Table | None, radar: Radar, restart_gap_s: float,
                      burn_in_updates: int, gate_probability: float, gated_from: int, segment_plots: int,
                      truncation_steps: int, key: str) -> SequenceBatch:
    """Training segments (B, segment_plots) of a split's target plots (`tuning.target_sequences`), the
    plots of `holdout` (the windows stage's hold-out segments, when the split is theirs) left out.
    InputError naming the param `key` (its truncation) when the longest segment is shorter."""
    if holdout is not None:
        plots = plots.filter(pc.invert(pc.is_in(plots.column("plot_id"), holdout.column("plot_id"))))
    material = tuning.target_sequences(plots, radar, restart_gap_s, burn_in_updates, gate_probability, gated_from,
                                       segment_plots=segment_plots)
    longest = material.times.shape[1]
    if longest < truncation_steps:
        raise io.InputError(f"the longest training segment has {longest} plots, fewer than "
                            f"{key}.truncation_steps = {truncation_steps}")
    return SequenceBatch.from_sequences(material)


class Segments(Dataset):
    """Rows of a SequenceBatch, indexed by a whole batch of row indices at once (batch_size=None)."""

    def __init__(self, material: SequenceBatch) -> None:
        self.material = material

    def __len__(self) -> int:
        return len(self.material.times)

    def __getitem__(self, indices: list[int]) -> tuple[Tensor, ...]:
        rows = self.material.rows(torch.as_tensor(indices))
        return tuple(getattr(rows, field.name) for field in fields(rows))


class SegmentData(L.LightningDataModule):
    """The training segments in random batches (seeded)."""

    def __init__(self, material: SequenceBatch, batch_segments: int, seed: int) -> None:
        super().__init__()
        self.segments, self.batch_segments, self.seed = Segments(material), batch_segments, seed

    def train_dataloader(self) -> DataLoader:
        sampler = RandomSampler(self.segments, generator=torch.Generator().manual_seed(self.seed))
        return DataLoader(self.segments, sampler=BatchSampler(sampler, self.batch_segments, drop_last=False),
                          batch_size=None)


class FilterDescent(L.LightningModule):
    """A filter module (`forward(batch, detach_every) -> Filtered`) trained on the mean position error."""

    def __init__(self, model: nn.Module, label: str, config: DescentConfig) -> None:
        super().__init__()
        self.model, self.label, self.config = model, label, config
        self.epoch_losses: list[float] = []
        self._began = 0.0

    def on_train_start(self) -> None:
        self._began = time.monotonic()

    def on_train_epoch_start(self) -> None:
        self._error_sum, self._scored = 0.0, 0

    def training_step(self, tensors: tuple[Tensor, ...], batch_index: int) -> Tensor:
        batch = SequenceBatch(*tensors)
        loss = batch.position_error(self.model(batch, self.config.truncation_steps))
        scored = int(batch.scored.sum())
        self._error_sum += float(loss.detach()) * scored
        self._scored += scored
        return loss

    def epoch_train_loss(self) -> float:
        """The epoch's mean position error so far (m)."""
        return self._error_sum / max(self._scored, 1)

    def on_train_epoch_end(self) -> None:
        loss = self.epoch_train_loss()
        self.epoch_losses.append(loss)
        self.log(f"{self.label}.train_loss", loss)
        log.info("%s: epoch %d/%d, mean position error %.2f m, %.0f s", self.label,
                 len(self.epoch_losses), self.config.epochs, loss, time.monotonic() - self._began)

    def configure_optimizers(self) -> dict:
        optimizer = torch.optim.Adam(self.model.parameters(), lr=self.config.learning_rate)
        cosine = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=self.config.epochs)
        return {"optimizer": optimizer, "lr_scheduler": cosine}


def descend(model: nn.Module, label: str, material: SequenceBatch, config: DescentConfig,
            logger: L.pytorch.loggers.Logger | bool = False) -> tuple[list[float], float]:
    """Train `model` in place (Lightning's Trainer, CPU: the recursion is a loop of small operations);
    its per-epoch mean position errors (m) and the seconds it took. Deterministic for a seed.
    TrainingDiverged naming `label` when the loss or a weight goes non-finite (`training.FiniteTraining`)."""
    L.seed_everything(config.seed, workers=True, verbose=False)
    module = FilterDescent(model, label, config)
    trainer = L.Trainer(max_epochs=config.epochs, accelerator="cpu", devices=1, logger=logger,
                        callbacks=[training.FiniteTraining(label, config.learning_rate, every_batch=True)],
                        deterministic=config.deterministic, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0)
    began = time.perf_counter()
    trainer.fit(module, datamodule=SegmentData(material, config.batch_segments, config.seed))
    model.eval()
    return module.epoch_losses, time.perf_counter() - began

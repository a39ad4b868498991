"""Gradient descent on a filter over training segments with Lightning: the network-scaled filter, the
gradient-tuned classical filters and the LSTM update share this task, loss, data and truncation (fitted by
`fit.fit`).

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

from dataclasses import fields
from typing import Any

import lightning as L
import pyarrow as pa
import pyarrow.compute as pc
import torch
from torch import Tensor, nn
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler

from pipeline import io
from pipeline.filters import tuning
from pipeline.filters.torch_filters import SequenceBatch
from pipeline.learning.fit import FitConfig, Task
from pipeline.params import Radar
from pipeline.sections import subset


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
    """A filter module (`forward(batch, detach_every)`: its estimates, a `Filtered` or anything with their
    `position` (B, T, 3) m) trained on the mean position error over the scored plots, truncated every
    `truncation_steps` steps, Adam's rate annealed over `epochs`."""

    def __init__(self, model: nn.Module, truncation_steps: int, learning_rate: float, epochs: int) -> None:
        super().__init__()
        self.model, self.truncation_steps = model, truncation_steps
        self.learning_rate, self.epochs = learning_rate, epochs

    def training_step(self, tensors: tuple[Tensor, ...], batch_index: int) -> dict[str, Any]:
        batch = SequenceBatch(*tensors)
        loss = batch.position_error(self.model(batch, self.truncation_steps))
        return {"loss": loss, "weight": int(batch.scored.sum())}

    def configure_optimizers(self) -> dict:
        optimizer = torch.optim.Adam(self.model.parameters(), lr=self.learning_rate)
        cosine = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=self.epochs)
        return {"optimizer": optimizer, "lr_scheduler": cosine}


def descent(model: nn.Module, label: str, material: SequenceBatch, knobs: Any, deterministic: bool) -> Task:
    """`model` trained on `material` (Lightning, on the CPU: the recursion is a loop of small operations) by
    `knobs`: params' `kalman_net` or `lstm_update` section, or any with its `epochs`, `batch_segments`,
    `learning_rate`, `truncation_steps` and `seed`. Logged as `<label>.train_loss`, the epoch's mean
    position error (m); `label` also names it when its loss or a weight goes non-finite."""
    config = subset(FitConfig, knobs, label=label, loss_name=f"{label}.train_loss", deterministic=deterministic)
    return Task(FilterDescent(model, knobs.truncation_steps, config.learning_rate, config.epochs),
                SegmentData(material, knobs.batch_segments, config.seed), config)

"""Training with Lightning: a LightningModule around each network and a DataModule of in-memory tensors.

The windows are small (tens of thousands of 5-10 step sequences), so the whole material
lives in memory as tensors and a batch is one fancy-indexing operation, not 128 calls to
a Dataset and a collate: with networks this small the per-batch overhead would otherwise
dominate. Lightning's Trainer takes `accelerator`, `devices` and `strategy` from params,
so the same stage runs on a GPU or several.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass

import lightning as L
import numpy as np
import torch
from torch import nn
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler, SequentialSampler

from pipeline.io import TrainingDiverged
from pipeline.learning.model_store import first_non_finite
from pipeline.learning.networks import NetworkConfig, build_network

log = logging.getLogger("pipeline")


class _DropAdvertising(logging.Filter):
    """Lightning logs tips for its paid services at every Trainer start; they are not ours to print."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "Tip:" not in record.getMessage()


def _lightning_logs_through_root() -> None:
    """Each Lightning line printed once, in the application's format.

    The `lightning` package adds a handler of its own to its logger and lets records propagate
    to the root logger too, so an application that configured logging printed every Lightning
    line twice. Its subpackages follow the convention this restores: when the root logger has
    handlers, records go there only."""
    if logging.getLogger().hasHandlers():
        package_logger = logging.getLogger("lightning")
        for handler in list(package_logger.handlers):
            package_logger.removeHandler(handler)
    logging.getLogger("lightning.pytorch.utilities.rank_zero").addFilter(_DropAdvertising())
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)")


_lightning_logs_through_root()

VALIDATION_BATCH = 4096


@dataclass(frozen=True)
class TrainingConfig:
    epochs: int
    batch_size: int
    learning_rate: float
    validation_fraction: float
    seed: int
    early_stopping_patience: int  # epochs without a better validation loss before stopping; 0 = off
    accelerator: str
    devices: int | str
    strategy: str
    threads: int
    deterministic: bool
    early_stopping_min_improvement: float = 0.0  # relative: better means below the best so far x (1 - this)
    lr_decay_factor: float = 0.5  # the learning rate is multiplied by this ...
    lr_decay_patience: int = 0    # ... after this many epochs without a better validation loss; 0 = off


class TensorBatches(Dataset):
    """A dataset indexed by a whole batch of indices at once (used with batch_size=None)."""

    def __init__(self, inputs: torch.Tensor, targets: torch.Tensor) -> None:
        self.inputs, self.targets = inputs, targets

    def __len__(self) -> int:
        return len(self.inputs)

    def __getitem__(self, indices: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
        return self.inputs[indices], self.targets[indices]


class WindowDataModule(L.LightningDataModule):
    """Training and validation windows, split at random (seeded) by `validation_fraction`."""

    def __init__(self, inputs: np.ndarray, targets: np.ndarray, batch_size: int, validation_fraction: float,
                 seed: int) -> None:
        super().__init__()
        inputs_t = torch.as_tensor(inputs, dtype=torch.float32)
        targets_t = torch.as_tensor(targets, dtype=torch.float32)
        order = torch.randperm(len(inputs_t), generator=torch.Generator().manual_seed(seed))
        validation = int(round(validation_fraction * len(order)))
        self.train_set = TensorBatches(inputs_t[order[validation:]], targets_t[order[validation:]])
        self.validation_set = TensorBatches(inputs_t[order[:validation]], targets_t[order[:validation]])
        self.batch_size, self.seed = batch_size, seed

    def train_dataloader(self) -> DataLoader:
        sampler = RandomSampler(self.train_set, generator=torch.Generator().manual_seed(self.seed))
        return DataLoader(self.train_set, sampler=BatchSampler(sampler, self.batch_size, drop_last=False),
                          batch_size=None)

    def val_dataloader(self) -> DataLoader:
        sampler = BatchSampler(SequentialSampler(self.validation_set), VALIDATION_BATCH, drop_last=False)
        return DataLoader(self.validation_set, sampler=sampler, batch_size=None)


class NetworkModule(L.LightningModule):
    """One of the thesis's networks, trained on MSE with Adam."""

    def __init__(self, config: dict, learning_rate: float, lr_decay_factor: float = 1.0,
                 lr_decay_patience: int = 0, min_improvement: float = 0.0) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.network = build_network(NetworkConfig.from_dict(config))
        self.learning_rate = learning_rate
        self.loss = nn.MSELoss()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.network(x)

    def on_train_epoch_start(self) -> None:
        self._loss_sum = torch.zeros((), device=self.device)
        self._loss_count = 0

    def training_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_index: int) -> torch.Tensor:
        # The epoch mean is accumulated here and logged once per epoch: self.log on every step
        # costs more than a whole step of these small networks.
        inputs, targets = batch
        loss = self.loss(self.network(inputs), targets)
        self._loss_sum += loss.detach() * len(inputs)
        self._loss_count += len(inputs)
        return loss

    def epoch_train_loss(self) -> torch.Tensor:
        return self._loss_sum / max(self._loss_count, 1)

    def on_train_epoch_end(self) -> None:
        self.log("train_loss", self.epoch_train_loss(), sync_dist=True)

    def validation_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_index: int) -> None:
        inputs, targets = batch
        self.log("val_loss", self.loss(self.network(inputs), targets), on_step=False, on_epoch=True,
                 batch_size=len(inputs), sync_dist=True)

    def configure_optimizers(self) -> torch.optim.Optimizer | dict:
        optimizer = torch.optim.Adam(self.parameters(), lr=self.learning_rate)
        if not self.hparams.get("lr_decay_patience"):
            return optimizer
        # Keras's ReduceLROnPlateau, as Lightning schedules it: checked on val_loss after each epoch.
        plateau = torch.optim.lr_scheduler.ReduceLROnPlateau(optimizer, factor=self.hparams["lr_decay_factor"],
                                                             patience=self.hparams["lr_decay_patience"] - 1,
                                                             threshold=self.hparams["min_improvement"])
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": plateau, "monitor": "val_loss"}}


class EpochLog(L.Callback):
    """Keeps the per-epoch losses and logs a progress line every few seconds."""

    def __init__(self, label: str, every_s: float = 10.0) -> None:
        self.label, self.every_s = label, every_s
        self.train_loss: list[float] = []
        self.validation_loss: list[float] = []
        self.kept_epoch = 0  # the epoch whose weights the model keeps (1-based), set when training ends
        self._last = 0.0
        self._start = 0.0

    def on_train_start(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self._start = time.monotonic()

    def on_train_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        # Callbacks run before the module's own epoch-end hook, so ask the module directly.
        self.train_loss.append(float(module.epoch_train_loss()))
        self.validation_loss.append(float(trainer.callback_metrics.get("val_loss", float("nan"))))
        now = time.monotonic()
        epoch = trainer.current_epoch + 1
        if now - self._last >= self.every_s or epoch == trainer.max_epochs:
            self._last = now
            log.info("train %s: epoch %d/%d, train loss %.3g, validation loss %.3g, %.0f s", self.label, epoch,
                     trainer.max_epochs, self.train_loss[-1], self.validation_loss[-1], now - self._start)


class BestValidation(L.Callback):
    """Early stopping on the validation loss that also keeps the best epoch's weights.

    Lightning's EarlyStopping stops but leaves the last epoch's weights, and measures
    improvement in absolute loss units, which differ by a factor of ten between these
    networks; here an epoch improves when its validation loss is below the best so far
    times (1 - min_improvement), and the weights of the best epoch are restored when
    training ends. With patience 0 the run goes to its last epoch and keeps its weights
    (the thesis's schedule)."""

    def __init__(self, patience: int, min_improvement: float) -> None:
        self.patience, self.min_improvement = patience, min_improvement
        self.best_loss = float("inf")
        self.best_epoch = 0
        self._best_state: dict[str, torch.Tensor] | None = None

    def on_validation_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if trainer.sanity_checking or "val_loss" not in trainer.callback_metrics:
            return
        loss = float(trainer.callback_metrics["val_loss"])
        epoch = trainer.current_epoch + 1
        if loss < self.best_loss * (1.0 - self.min_improvement):
            self.best_loss, self.best_epoch = loss, epoch
            if self.patience:
                self._best_state = {name: value.detach().clone() for name, value in module.state_dict().items()}
        elif self.patience and epoch - self.best_epoch >= self.patience:
            trainer.should_stop = True

    def on_fit_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if self._best_state is not None:
            module.load_state_dict(self._best_state)


class FiniteTraining(L.Callback):
    """Stops a training, raising TrainingDiverged, as soon as its loss or its weights are not finite.

    One NaN or infinite loss (too high a learning rate, an overflow) makes every later Adam step NaN:
    the weights stay NaN for good, and the run would end as usual with a model of NaN weights written
    and registered. Lightning's EarlyStopping(check_finite=True) only stops, keeping those weights,
    and its `detect_anomaly` traces every backward pass. Checked, for the network `network` trained at
    `learning_rate` (named in the message):
    - the module's `epoch_train_loss()` (the epoch's mean so far) after every batch when `every_batch`
      (the filter and association modules, which read their loss on the CPU at every step anyway),
      else after each validation and at each epoch's end (one read per epoch: no sync per step);
    - the validation loss `val_loss` after each validation;
    - every floating-point tensor of the module's state at each epoch's end (the Adam step after the
      last loss of an epoch may overflow).
    The exception goes through Lightning's interrupt handling (its loggers finalized "failed") to the
    stage, which writes nothing, ends its MLflow run FAILED and registers nothing; the command exits 2."""

    def __init__(self, network: str, learning_rate: float, every_batch: bool = False) -> None:
        self.network, self.learning_rate, self.every_batch = network, learning_rate, every_batch

    def _stop(self, trainer: L.Trainer, what: str, batch: int | None = None) -> None:
        where = f"epoch {trainer.current_epoch + 1} of {trainer.max_epochs}"
        if batch is not None:
            where += f", batch {batch + 1}"
        raise TrainingDiverged(f"training of {self.network} stopped: {what} at {where} (learning rate "
                               f"{self.learning_rate:g}); no model written (a lower learning rate may help)")

    def _check_train_loss(self, trainer: L.Trainer, module: L.LightningModule, batch: int | None = None) -> None:
        loss = float(module.epoch_train_loss())
        if not math.isfinite(loss):
            self._stop(trainer, f"the training loss became {loss}", batch)

    def on_train_batch_end(self, trainer: L.Trainer, module: L.LightningModule, outputs: object, batch: object,
                           batch_index: int) -> None:
        if self.every_batch:
            self._check_train_loss(trainer, module, batch_index)

    def on_validation_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if trainer.sanity_checking or "val_loss" not in trainer.callback_metrics:
            return
        self._check_train_loss(trainer, module)  # validation follows the epoch's batches: name the first to go
        loss = float(trainer.callback_metrics["val_loss"])
        if not math.isfinite(loss):
            self._stop(trainer, f"the validation loss became {loss}")

    def on_train_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self._check_train_loss(trainer, module)
        tensor = first_non_finite(module.state_dict())
        if tensor is not None:
            self._stop(trainer, f"the weight tensor '{tensor}' became non-finite")


def train(config: NetworkConfig, inputs: np.ndarray, targets: np.ndarray, training: TrainingConfig,
          logger: L.pytorch.loggers.Logger | bool = False) -> tuple[NetworkModule, EpochLog]:
    """Train one network from scratch; deterministic for a given seed on the same machine.

    Returns the module in eval mode (with the best epoch's weights under early stopping) and
    the per-epoch losses with the epoch whose weights it kept. TrainingDiverged when a loss or
    a weight goes non-finite (`FiniteTraining`)."""
    torch.set_num_threads(training.threads)
    L.seed_everything(training.seed, workers=True, verbose=False)
    data = WindowDataModule(inputs, targets, training.batch_size, training.validation_fraction, training.seed)
    module = NetworkModule(config.to_dict(), training.learning_rate, training.lr_decay_factor,
                           training.lr_decay_patience, training.early_stopping_min_improvement)
    history = EpochLog(config.kind)
    best = BestValidation(training.early_stopping_patience, training.early_stopping_min_improvement)
    callbacks: list[L.Callback] = [history, FiniteTraining(f"the {config.kind} network", training.learning_rate), best]
    trainer = L.Trainer(max_epochs=training.epochs, accelerator=training.accelerator, devices=training.devices,
                        strategy=training.strategy, logger=logger, callbacks=callbacks, deterministic=training.deterministic,
                        enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                        num_sanity_val_steps=0, **({} if len(data.validation_set) else {"limit_val_batches": 0}))
    trainer.fit(module, datamodule=data)
    module.eval()
    history.kept_epoch = best.best_epoch if training.early_stopping_patience else len(history.train_loss)
    return module, history

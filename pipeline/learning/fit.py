"""The one way a network is fitted: Lightning's Trainer built once, with the flags every training shares.

A training is a task (a LightningModule whose `training_step` returns its batch's loss and what the
batch counts, `{"loss": loss, "weight": n}`), its data (a LightningDataModule) and a `FitConfig`.
`fit` seeds, builds the Trainer (no checkpoints, progress bar, model summary or sanity validation:
the stage writes its own outputs and logs), adds the two callbacks every training has, runs it, and
leaves the module in eval mode:
- `EpochMean`: the epoch's mean training loss, weighted by what each batch counts (windows, scored
  plots, pairs), logged once per epoch as `FitConfig.loss_name` and kept per epoch, with a progress
  line: logging the loss at every step would cost more than a step of these small networks;
- `FiniteTraining`: TrainingDiverged as soon as a loss or a weight is not finite, or the loss diverges.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import lightning as L
import torch

from pipeline.io import TrainingDiverged
from pipeline.learning.model_store import first_non_finite

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


@dataclass(frozen=True)
class FitConfig:
    """How one training runs. `label` names it in progress lines and errors ("the filter network",
    "kalman_net"); `loss_name` is the MLflow metric of its epoch-mean loss; `learning_rate` is named
    when it diverges (the module's optimiser takes its own).

    `loss_on_device`: the epoch's loss summed on the device in the loss's dtype and read once per epoch
    (the windows networks, which may train on a GPU: a read per step is a sync per step); otherwise summed
    on the host in double precision and checked after every batch (the sequence trainings read their loss
    on the CPU at every step anyway). `validation`: the data module gives validation batches
    (`val_loss` each epoch); `fresh_data_every_epoch`: its training batches are made again each epoch."""

    label: str
    loss_name: str
    epochs: int
    learning_rate: float
    seed: int
    deterministic: bool
    accelerator: str = "cpu"
    devices: int | str = 1
    strategy: str = "auto"
    num_nodes: int = 1
    validation: bool = False
    fresh_data_every_epoch: bool = False
    loss_on_device: bool = False
    report_every_s: float = 0.0  # progress lines at most this often (and at the last epoch); 0: every epoch


class Task(NamedTuple):
    """What `fit` trains: the module, its data, the config and the task's own callbacks (`fit(*task)`)."""

    module: L.LightningModule
    data: L.LightningDataModule
    config: FitConfig
    callbacks: tuple[L.Callback, ...] = ()


@dataclass
class Fitted:
    """Per-epoch mean training losses and validation losses (nan without validation), the seconds
    Lightning's fit took, and the epoch whose weights the module kept (1-based: the last, unless a
    callback restored another)."""

    train_loss: list[float] = field(default_factory=list)
    validation_loss: list[float] = field(default_factory=list)
    seconds: float = 0.0
    kept_epoch: int = 0


class EpochMean(L.Callback):
    """The epoch's mean training loss (module docstring), from each batch's `{"loss", "weight"}`."""

    def __init__(self, config: FitConfig, fitted: Fitted) -> None:
        self.config, self.fitted = config, fitted
        self._sum: torch.Tensor | float = 0.0
        self._count = 0
        self._began = self._reported = 0.0

    def on_train_start(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self._began = time.monotonic()

    def on_train_epoch_start(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self._sum = torch.zeros((), device=module.device) if self.config.loss_on_device else 0.0
        self._count = 0

    def on_train_batch_end(self, trainer: L.Trainer, module: L.LightningModule, outputs: Any, batch: Any,
                           batch_index: int) -> None:
        loss, weight = outputs["loss"], outputs["weight"]
        if self.config.loss_on_device:
            self._sum += loss * weight
        else:
            self._sum += float(loss) * weight
        self._count += weight

    def mean(self) -> torch.Tensor | float:
        """The epoch's mean loss so far (a tensor on the device with `loss_on_device`)."""
        return self._sum / max(self._count, 1)

    def on_train_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        mean = self.mean()
        self.fitted.train_loss.append(float(mean))
        self.fitted.validation_loss.append(float(trainer.callback_metrics.get("val_loss", math.nan)))
        module.log(self.config.loss_name, mean, sync_dist=True)
        now, epoch = time.monotonic(), trainer.current_epoch + 1
        if now - self._reported >= self.config.report_every_s or epoch == trainer.max_epochs:
            self._reported = now
            validation = f", validation loss {self.fitted.validation_loss[-1]:.4g}" if self.config.validation else ""
            log.info("%s: epoch %d/%d, %s %.4g%s, %.0f s", self.config.label, epoch, trainer.max_epochs,
                     self.config.loss_name, self.fitted.train_loss[-1], validation, now - self._began)


DIVERGED_FACTOR = 1000.0  # an epoch's mean loss over this many times the untrained network's: diverged


class FiniteTraining(L.Callback):
    """Stops a training, raising TrainingDiverged, as soon as its loss or its weights are not finite.

    One NaN or infinite loss (too high a learning rate, an overflow) makes every later Adam step NaN:
    the weights stay NaN for good, and the run would end as usual with a model of NaN weights written
    and registered. Lightning's EarlyStopping(check_finite=True) only stops, keeping those weights,
    and its `detect_anomaly` traces every backward pass. Checked, naming the training's label and
    learning rate:
    - the epoch's mean loss so far (`EpochMean`) after every batch, unless it is kept on the device
      (then after each validation and at each epoch's end: one read per epoch, no sync per step);
    - the validation loss `val_loss` after each validation;
    - every floating-point tensor of the module's state at each epoch's end (the Adam step after the
      last loss of an epoch may overflow);
    - a finite divergence: the epoch's mean loss above DIVERGED_FACTOR times the loss of the untrained
      network (the first batch's, read once), checked where the finite check is. A learning rate of 1e6
      keeps the predictor's loss finite while its hold-out error grows to 1e10 m (linear extrapolation:
      65 m; real-world case 33); a training that learns stays far below its first loss.
    The exception goes through Lightning's interrupt handling (its loggers finalized "failed") to the
    stage, which writes nothing, ends its MLflow run FAILED and registers nothing; the command exits 2."""

    def __init__(self, config: FitConfig, mean: EpochMean) -> None:
        self.config, self.epoch_mean = config, mean
        self.first_loss = math.nan  # the untrained network's: the first batch's loss

    def _stop(self, trainer: L.Trainer, what: str, batch: int | None = None) -> None:
        where = f"epoch {trainer.current_epoch + 1} of {trainer.max_epochs}"
        if batch is not None:
            where += f", batch {batch + 1}"
        raise TrainingDiverged(f"training of {self.config.label} stopped: {what} at {where} (learning rate "
                               f"{self.config.learning_rate:g}); no model written (a lower learning rate may help)")

    def _check_train_loss(self, trainer: L.Trainer, batch: int | None = None) -> None:
        loss = float(self.epoch_mean.mean())
        if not math.isfinite(loss):
            self._stop(trainer, f"the training loss became {loss}", batch)
        if self.first_loss > 0.0 and loss > DIVERGED_FACTOR * self.first_loss:
            self._stop(trainer, f"the training loss diverged to {loss:.4g}, over {DIVERGED_FACTOR:g} times the "
                                f"untrained network's {self.first_loss:.4g}", batch)

    def on_train_batch_end(self, trainer: L.Trainer, module: L.LightningModule, outputs: Any, batch: Any,
                           batch_index: int) -> None:
        if math.isnan(self.first_loss):
            self.first_loss = abs(float(outputs["loss"]))
        if not self.config.loss_on_device:
            self._check_train_loss(trainer, batch_index)

    def on_validation_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        if trainer.sanity_checking or "val_loss" not in trainer.callback_metrics:
            return
        self._check_train_loss(trainer)  # validation follows the epoch's batches: name the first to go
        loss = float(trainer.callback_metrics["val_loss"])
        if not math.isfinite(loss):
            self._stop(trainer, f"the validation loss became {loss}")

    def on_train_epoch_end(self, trainer: L.Trainer, module: L.LightningModule) -> None:
        self._check_train_loss(trainer)
        tensor = first_non_finite(module.state_dict())
        if tensor is not None:
            self._stop(trainer, f"the weight tensor '{tensor}' became non-finite")


def fit(module: L.LightningModule, data: L.LightningDataModule, config: FitConfig,
        callbacks: tuple[L.Callback, ...] = (), logger: L.pytorch.loggers.Logger | bool = False) -> Fitted:
    """Train `module` on `data` (module docstring), seeded with `config.seed` (Python, NumPy, torch), so
    deterministic for a seed on the same machine whatever ran before; `callbacks` after the two shared
    ones. The per-epoch losses and the seconds of the fit; the module in eval mode. TrainingDiverged when
    a loss or a weight goes non-finite (`FiniteTraining`)."""
    L.seed_everything(config.seed, workers=True, verbose=False)
    fitted = Fitted()
    mean = EpochMean(config, fitted)
    trainer = L.Trainer(max_epochs=config.epochs, accelerator=config.accelerator, devices=config.devices,
                        strategy=config.strategy, num_nodes=config.num_nodes, logger=logger,
                        callbacks=[mean, FiniteTraining(config, mean), *callbacks],
                        deterministic=config.deterministic, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, num_sanity_val_steps=0,
                        **({} if config.validation else {"limit_val_batches": 0}),
                        **({"reload_dataloaders_every_n_epochs": 1} if config.fresh_data_every_epoch else {}))
    began = time.perf_counter()
    trainer.fit(module, datamodule=data)
    fitted.seconds = time.perf_counter() - began
    fitted.kept_epoch = len(fitted.train_loss)
    module.eval()
    return fitted

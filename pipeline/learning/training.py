"""The thesis's three networks trained on their windows: the task, its data and its recipe (`kinds`).

The windows are small (tens of thousands of 5-10 step sequences), so the whole material
lives in memory as tensors and a batch is one fancy-indexing operation, not 128 calls to
a Dataset and a collate: with networks this small the per-batch overhead would otherwise
dominate. Lightning's Trainer takes `accelerator`, `devices`, `strategy` and `num_nodes` from params,
so the same stage runs on a GPU or several.

`WindowNetworkRecipe` is how `python -m pipeline train --kind <network>` trains one: the
windows stage's material of that network (its shape and scaler checked against params), MSE
with Adam (`NetworkModule`), early stopping that keeps the best epoch (`BestValidation`), then
its hold-out metrics (`model_eval`), its loss curve and its network registered as an MLflow
model (`pipeline.learning.mlflow_models`).
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch
from torch import nn
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler, SequentialSampler

from pipeline import io
from pipeline.learning import materials, model_eval
from pipeline.learning.fit import FitConfig, Fitted, Task, fit
from pipeline.learning.recipe import Folders, Inputs, Outcome, Trained
from pipeline.learning.model_store import LoadedModel
from pipeline.learning.networks import NetworkConfig, build_network
from pipeline.learning.scaling import PLOT_FEATURES, STATE_FEATURES, WindowScaler
from pipeline.learning.windows import window_arrays
from pipeline.params import Params
from pipeline.sections import subset

log = logging.getLogger("pipeline")

VALIDATION_BATCH = 4096


@dataclass(frozen=True)
class TrainingConfig:
    """A network's schedule: params `training.<network>` and the shared `training` keys, by name."""

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
    num_nodes: int = 1  # machines (Lightning's Trainer num_nodes)
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
    """One of the thesis's networks, trained on MSE with Adam. Its hyperparameters (logged by Lightning) are
    the network's config and the optimiser's schedule."""

    def __init__(self, network: nn.Module, learning_rate: float, lr_decay_factor: float = 1.0,
                 lr_decay_patience: int = 0, min_improvement: float = 0.0) -> None:
        super().__init__()
        self.save_hyperparameters({"config": network.config.to_dict(), "learning_rate": learning_rate,
                                   "lr_decay_factor": lr_decay_factor, "lr_decay_patience": lr_decay_patience,
                                   "min_improvement": min_improvement})
        self.network = network
        self.learning_rate = learning_rate
        self.loss = nn.MSELoss()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.network(x)

    def training_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_index: int) -> dict[str, Any]:
        inputs, targets = batch
        return {"loss": self.loss(self.network(inputs), targets), "weight": len(inputs)}

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


def network_task(network: nn.Module, inputs: np.ndarray, targets: np.ndarray, training: TrainingConfig) -> Task:
    """`network` trained on MSE over (inputs, targets) windows by the schedule `training`."""
    data = WindowDataModule(inputs, targets, training.batch_size, training.validation_fraction, training.seed)
    module = NetworkModule(network, training.learning_rate, training.lr_decay_factor, training.lr_decay_patience,
                           training.early_stopping_min_improvement)
    config = subset(FitConfig, training, label=f"the {network.config.kind} network", loss_name="train_loss",
                    validation=len(data.validation_set) > 0, loss_on_device=True, report_every_s=10.0)
    return Task(module, data, config, (BestValidation(training.early_stopping_patience,
                                                      training.early_stopping_min_improvement),))


def kept(task: Task, fitted: Fitted) -> Fitted:
    """`fitted` with the epoch whose weights the network kept: the best one under early stopping."""
    best = task.callbacks[0]
    if best.patience:
        fitted.kept_epoch = best.best_epoch
    return fitted


def train(config: NetworkConfig, inputs: np.ndarray, targets: np.ndarray, training: TrainingConfig,
          logger: L.pytorch.loggers.Logger | bool = False) -> tuple[NetworkModule, Fitted]:
    """Train one network from scratch (seeded, then built, then fitted: as the stage does); deterministic
    for a given seed on the same machine. The module in eval mode (with the best epoch's weights under early
    stopping) and its per-epoch losses. TrainingDiverged when a loss or a weight goes non-finite."""
    torch.set_num_threads(training.threads)
    L.seed_everything(training.seed, workers=True, verbose=False)
    task = network_task(build_network(config), inputs, targets, training)
    return task.module, kept(task, fit(*task, logger=logger))


def _read_material(path: Path) -> pa.Table:
    if not path.is_file():
        raise io.InputError(f"{path}: file not found (run the windows stage)")
    try:
        return pq.read_table(path)
    except (pa.ArrowInvalid, OSError) as error:
        raise io.InputError(f"{path}: not a readable Parquet file ({error})") from None


def _arrays(table: pa.Table, path: Path, prefix: str, features: tuple[str, ...], steps: int) -> np.ndarray:
    for name in ("window_id", "step", *(f"{prefix}_{f}" for f in features)):
        if name not in table.column_names:
            raise io.InputError(f"{path}: column '{name}' is missing")
    values = window_arrays(table, prefix, features) if table.num_rows else np.empty((0, steps, len(features)))
    if values.shape[1] != steps:
        raise io.InputError(f"{path}: windows of {values.shape[1]} steps, params expect {steps}; "
                            "rerun the windows stage")
    if not np.isfinite(values).all():
        raise io.InputError(f"{path}: non-finite values in the '{prefix}_*' columns")
    return values


def training_pairs(kind: str, path: Path, params: Params) -> tuple[np.ndarray, np.ndarray]:
    """Network inputs and targets of a material, shapes checked against params."""
    table = _read_material(path)
    cfg = params.windows
    if kind == "filter":
        inputs = _arrays(table, path, "in", PLOT_FEATURES, cfg.filter_length)
        outputs = _arrays(table, path, "out", PLOT_FEATURES, cfg.filter_length)
        return inputs, outputs[:, -params.training.networks["filter"].output_steps:]
    if kind == "predictor":
        states = _arrays(table, path, "state", STATE_FEATURES, cfg.predictor_inputs + 1)
        keep = [STATE_FEATURES.index(name) for name in PLOT_FEATURES]
        return states[:, :-1], states[:, 2:, keep]
    inputs = _arrays(table, path, "in", PLOT_FEATURES, cfg.autoencoder_length)
    return inputs, inputs


def network_config(kind: str, params: Params) -> NetworkConfig:
    """The network `kind` of params `training.<kind>` (its layers, `output_steps`) on the windows of params."""
    cfg = params.windows
    steps = {"filter": cfg.filter_length, "predictor": cfg.predictor_inputs, "autoencoder": cfg.autoencoder_length}
    features = len(STATE_FEATURES) if kind == "predictor" else len(PLOT_FEATURES)
    return subset(NetworkConfig, params.training.networks[kind], kind=kind, input_steps=steps[kind],
                  input_features=features, output_features=len(PLOT_FEATURES))


def training_config(kind: str, params: Params) -> TrainingConfig:
    return subset(TrainingConfig, params.training.networks[kind], params.training)


def window_scaler(layout: str, params: Params, scalers_path: Path) -> WindowScaler:
    """The scaler the windows were made with (`layout`: "plots" or "states"); it must be the one params describe
    now."""
    if not scalers_path.is_file():
        raise io.InputError(f"{scalers_path}: file not found (run the windows stage)")
    stored = WindowScaler.from_dict(json.loads(scalers_path.read_text())[layout])
    expected = materials.scalers(params.windows)[layout]
    if stored != expected:
        raise io.InputError(f"{scalers_path}: windows were scaled with {stored}, params now give {expected}; "
                            "rerun the windows stage")
    return stored


def _holdout_metrics(kind: str, model: LoadedModel, params: Params, windows_dir: Path) -> tuple[dict, dict]:
    """Hold-out metrics (for reports and MLflow) and the extras to store with the model."""
    kalman = model_eval.KalmanReference(params.training.kalman_acceleration_std_mps2,
                                        params.training.kalman_truth_sigma_m)
    if kind == "autoencoder":
        path = windows_dir / "autoencoder_calibration.parquet"
        table = _read_material(path)
        scaled = _arrays(table, path, "in", PLOT_FEATURES, params.windows.autoencoder_length)
        labels = table.filter(pa.compute.equal(table.column("step"), 0)).column("label").to_numpy(
            zero_copy_only=False).astype(bool)
        errors = model_eval.reconstruction_errors(model, scaled)
        threshold, rejected = model_eval.autoencoder_threshold(errors, labels)
        return (model_eval.evaluate_autoencoder(errors, labels, threshold, rejected),
                {"threshold": threshold, "false_windows_rejected": rejected})
    holdout = io.read_parquet(windows_dir / "holdout.parquet", materials.HOLDOUT_SCHEMA)
    plots = model_eval.holdout_plots(holdout, params.radar)
    if kind == "filter":
        return model_eval.evaluate_filter(model, plots, params.radar, kalman), {}
    return model_eval.evaluate_predictor(model, plots, kalman), {}


def loss_curve(train_loss: list[float], validation_loss: list[float], kind: str) -> bytes:
    """PNG: training and validation loss per epoch (MSE on scaled windows), log scale."""
    from pipeline.figure_png import png  # matplotlib: only when a stage draws the curve
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(6.4, 4.0))
    epochs = np.arange(1, len(train_loss) + 1)
    axis.plot(epochs, train_loss, label="training")
    if not np.all(np.isnan(validation_loss)):
        axis.plot(epochs, validation_loss, label="validation")
    axis.set_yscale("log")
    axis.set_xlabel("epoch")
    axis.set_ylabel("MSE (scaled)")
    axis.set_title(f"{kind} network")
    axis.legend()
    figure.tight_layout()
    return png(figure)


class WindowNetworkRecipe:
    """Stage `train_<network>` (`kinds.Recipe`): writes `models/<network>.pt` (`model_store.load_model`),
    `reports/models/<network>.json` (hold-out metrics and the epochs), `reports/loss/<network>.csv` and
    `reports/loss_<network>.png`. Everything that can fail on bad input (material shape, scaler mismatch,
    the hold-out's file) is checked before training."""

    def __init__(self, kind: str, scaler: str) -> None:
        self.kind, self.scaler = kind, scaler

    def knobs(self, params: Params) -> Any:
        return params.training.networks[self.kind]

    def logged(self, params: Params) -> dict[str, Any]:
        shared = {key: value for key, value in asdict(params.training).items() if key != "networks"}
        return {**{f"network.{k}": v for k, v in asdict(self.knobs(params)).items()},
                **{f"training.{k}": v for k, v in shared.items()},
                **{f"windows.{k}": v for k, v in asdict(params.windows).items()}}

    def data(self, params: Params, folders: Folders) -> Inputs:
        material = folders.windows / f"{self.kind}.parquet"
        inputs, targets = training_pairs(self.kind, material, params)
        evaluation = folders.windows / ("autoencoder_calibration.parquet" if self.kind == "autoencoder"
                                        else "holdout.parquet")
        if not evaluation.is_file():
            raise io.InputError(f"{evaluation}: file not found (run the windows stage)")
        scaler = window_scaler(self.scaler, params, folders.windows / "scalers.json")
        return Inputs(network_config(self.kind, params), f"{len(inputs)} windows", material, (inputs, targets), scaler)

    def build(self, params: Params, inputs: Inputs) -> nn.Module:
        return build_network(inputs.data)

    def task(self, network: nn.Module, inputs: Inputs, params: Params) -> Task:
        return network_task(network, *inputs.windows, training_config(self.kind, params))

    def holdout(self, trained: Trained) -> Outcome:
        history = kept(trained.task, trained.fitted)
        model = LoadedModel(trained.network, trained.network.config, trained.inputs.scaler)
        metrics, extras = _holdout_metrics(self.kind, model, trained.params, trained.folders.windows)
        metrics["epochs_trained"] = len(history.train_loss)
        metrics["kept_epoch"] = history.kept_epoch
        metrics["kept_validation_loss"] = history.validation_loss[history.kept_epoch - 1]
        metrics["final_train_loss"] = history.train_loss[-1]
        metrics["final_validation_loss"] = history.validation_loss[-1]
        loss_csv = "epoch,train_loss,validation_loss\n" + "".join(
            f"{epoch},{a:.8g},{b:.8g}\n" for epoch, (a, b) in
            enumerate(zip(history.train_loss, history.validation_loss), start=1))
        reports = trained.folders.reports
        figure, report = reports / f"loss_{self.kind}.png", reports / "models" / f"{self.kind}.json"
        return Outcome(extras, {figure: loss_curve(history.train_loss, history.validation_loss, self.kind),
                                reports / "loss" / f"{self.kind}.csv": loss_csv, report: metrics},
                       (figure, report), {key: float(value) for key, value in metrics.items()},
                       f"train {self.kind}: " + ", ".join(f"{k} {v:.4g}" for k, v in metrics.items()))

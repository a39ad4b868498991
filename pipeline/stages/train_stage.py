"""The training stages: material -> trained network -> hold-out metrics, one MLflow run each
(with the network logged and registered as an MLflow model: `pipeline.learning.mlflow_models`).

Everything that can fail on bad input (material shape, scaler mismatch, tracking store)
is checked before training starts, and the model file, metrics and pictures are written
only after training and evaluation succeed.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import io
from pipeline.learning import experiment_tracking, materials, mlflow_models, model_eval
from pipeline.learning.model_store import LoadedModel, save_model
from pipeline.learning.networks import NetworkConfig
from pipeline.learning.scaling import PLOT_FEATURES, STATE_FEATURES, WindowScaler
from pipeline.learning.training import TrainingConfig, train
from pipeline.learning.windows import window_arrays
from pipeline.params import Params
from pipeline.reports import figures

log = logging.getLogger("pipeline")

LAYOUT = {"filter": "plots", "predictor": "states", "autoencoder": "plots"}


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
    net, cfg = params.training.networks[kind], params.windows
    steps = {"filter": cfg.filter_length, "predictor": cfg.predictor_inputs, "autoencoder": cfg.autoencoder_length}
    features = len(STATE_FEATURES) if kind == "predictor" else len(PLOT_FEATURES)
    return NetworkConfig(kind=kind, hidden=net.hidden, input_steps=steps[kind], input_features=features,
                         output_steps=net.output_steps, output_features=len(PLOT_FEATURES),
                         decoder_hidden=net.decoder_hidden)


def window_scaler(kind: str, params: Params, scalers_path: Path) -> WindowScaler:
    """The scaler the windows were made with; it must be the one params describe now."""
    if not scalers_path.is_file():
        raise io.InputError(f"{scalers_path}: file not found (run the windows stage)")
    stored = WindowScaler.from_dict(json.loads(scalers_path.read_text())[LAYOUT[kind]])
    expected = materials.scalers(params.windows)[LAYOUT[kind]]
    if stored != expected:
        raise io.InputError(f"{scalers_path}: windows were scaled with {stored}, params now give {expected}; "
                            "rerun the windows stage")
    return stored


def training_config(kind: str, params: Params) -> TrainingConfig:
    net, cfg = params.training.networks[kind], params.training
    return TrainingConfig(epochs=net.epochs, batch_size=net.batch_size, learning_rate=net.learning_rate,
                          validation_fraction=net.validation_fraction, seed=net.seed,
                          early_stopping_patience=net.early_stopping_patience,
                          early_stopping_min_improvement=net.early_stopping_min_improvement,
                          lr_decay_factor=net.lr_decay_factor, lr_decay_patience=net.lr_decay_patience,
                          accelerator=cfg.accelerator,
                          devices=cfg.devices, strategy=cfg.strategy, threads=cfg.threads,
                          deterministic=cfg.deterministic)


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


def _flat_params(kind: str, params: Params) -> dict:
    net = asdict(params.training.networks[kind])
    shared = {key: value for key, value in asdict(params.training).items() if key != "networks"}
    return {**{f"network.{k}": v for k, v in net.items()}, **{f"training.{k}": v for k, v in shared.items()},
            **{f"windows.{k}": v for k, v in asdict(params.windows).items()}}


def run_train(params: Params, kind: str, windows_dir: Path, models_dir: Path, reports_dir: Path) -> None:
    """Stage `train_<kind>`: train one network, evaluate it on the hold-out, log one MLflow run
    with the training windows as its input and the network as a logged, registered model.

    TrainingDiverged (nothing written, the run FAILED, nothing registered) when a loss goes non-finite;
    TrackingError, after the model and reports are written, when the store failed during the run."""
    from pipeline.learning.tracking_logger import TrainingLogger

    material = windows_dir / f"{kind}.parquet"
    inputs, targets = training_pairs(kind, material, params)
    evaluation_input = windows_dir / ("autoencoder_calibration.parquet" if kind == "autoencoder" else "holdout.parquet")
    if not evaluation_input.is_file():
        raise io.InputError(f"{evaluation_input}: file not found (run the windows stage)")
    scaler = window_scaler(kind, params, windows_dir / "scalers.json")
    config = network_config(kind, params)
    uri = experiment_tracking.tracking_uri(params.training.tracking_uri)
    experiment = params.training.experiment
    experiment_tracking.check_tracking_store(uri, experiment, f"train_{kind}")
    with experiment_tracking.stage_run(uri, params, f"train_{kind}", "train",
                                       {"input_data_sha256": experiment_tracking.data_hash(material)}) as run:
        # Lightning logs the losses into the stage's run; at the end of fit it marks the run
        # FINISHED, and the stage's run ends it again (FAILED if anything after fit fails).
        logger = TrainingLogger(uri, experiment_name=experiment, run_id=run.info.run_id)
        log.info("train %s: %d windows, MLflow run %s in %s", kind, len(inputs), run.info.run_id, uri)
        logger.log_hyperparams(_flat_params(kind, params))
        logger.write("logging the training windows", mlflow_models.log_training_windows, kind, material, inputs,
                     targets)
        module, history = train(config, inputs, targets, training_config(kind, params), logger)
        model = LoadedModel(module.network, config, scaler)
        metrics, extras = _holdout_metrics(kind, model, params, windows_dir)
        metrics["epochs_trained"] = len(history.train_loss)
        metrics["kept_epoch"] = history.kept_epoch
        metrics["kept_validation_loss"] = history.validation_loss[history.kept_epoch - 1]
        metrics["final_train_loss"] = history.train_loss[-1]
        metrics["final_validation_loss"] = history.validation_loss[-1]
        loss_png = figures.loss_curve(history.train_loss, history.validation_loss, kind)
        loss_csv = "epoch,train_loss,validation_loss\n" + "".join(
            f"{epoch},{a:.8g},{b:.8g}\n" for epoch, (a, b) in
            enumerate(zip(history.train_loss, history.validation_loss), start=1))

        model_path = models_dir / f"{kind}.pt"
        save_model(model_path, module.network, config, scaler, extras)
        io.write_bytes(loss_png, reports_dir / f"loss_{kind}.png")
        io.write_text(loss_csv, reports_dir / "loss" / f"{kind}.csv")
        io.write_json(metrics, reports_dir / "models" / f"{kind}.json")
        logger.log_metrics({key: float(value) for key, value in metrics.items()})
        for artifact in (model_path, reports_dir / f"loss_{kind}.png", reports_dir / "models" / f"{kind}.json"):
            logger.log_artifact(artifact)
        logger.write("registering the network", mlflow_models.log_network, kind, module.network, inputs, experiment,
                     model_path, run.data.tags[experiment_tracking.SESSION_TAG])
        logger.raise_if_failed(f"{model_path} and the reports")
    log.info("train %s: %s", kind, ", ".join(f"{k} {v:.4g}" for k, v in metrics.items()))


def run_models_report(reports_dir: Path) -> None:
    """Stage `models_report`: the three networks' hold-out metrics in one file, beside the thesis's."""
    merged = {}
    for kind in ("filter", "predictor", "autoencoder"):
        path = reports_dir / "models" / f"{kind}.json"
        if not path.is_file():
            raise io.InputError(f"{path}: file not found (run train_{kind})")
        merged[kind] = json.loads(path.read_text())
    merged["thesis"] = model_eval.THESIS
    io.write_json(merged, reports_dir / "models.json")

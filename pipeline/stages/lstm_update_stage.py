"""Stage `train_lstm_update`: the LSTM update on a Kalman prediction (`pipeline.learning.lstm_update`), one MLflow run.

Trained by `filter_training.descend` (Lightning) on the material of the network-scaled filter's
stage: the split's target plots less the windows stage's hold-out segments and less the
validation segments (`validation_split`: `validation_fraction` of the others), restarted at gaps
and every `segment_plots` plots. Then the MC-dropout covariance is calibrated (for the estimate,
and for the prediction to the tracker's gate, `tracker.kalman_gate_probability`) on the validation
segments' windows of `segment_plots` plots (as long as the training sequences, so the oldest ages'
factors see old tracks), one started at every plot as the hold-out's are
(`lstm_update.calibrate`), and the estimator is scored on
the hold-out windows against the Nelder-Mead tuned CA filter it starts from and the tuned IMM
(`models/kalman_tuned.json`) with `filter_holdout.compare_detailed`. Everything that can fail on bad
input (params, material, the tuned filters, the tracking store) fails before training. Writes
`models/lstm_update.pt` (`lstm_update.load`) and `reports/lstm_update.json`.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.filters.classical_filters import load_settings
from pipeline.filters.torch_filters import FilterSpec
from pipeline.learning import (
    experiment_tracking,
    filter_holdout,
    kalman_net,
    lstm_update,
    materials,
    model_eval,
    validation_split,
)
from pipeline.learning.filter_training import DescentConfig, descend, training_segments
from pipeline.learning.lstm_update import LSTMUpdate, LSTMUpdateConfig
from pipeline.params import Params
from pipeline.simulation import simulate

log = logging.getLogger("pipeline")
BASELINES = {"ca": "Kalman CA, Nelder-Mead tuned", "imm": "IMM (CV + CA), Nelder-Mead tuned"}


def estimator_config(params: Params) -> LSTMUpdateConfig:
    u = params.lstm_update
    return LSTMUpdateConfig(u.hidden, u.dropout, u.mc_samples, u.detach_prediction, u.position_scale_m,
                            u.velocity_scale_mps, u.acceleration_scale_mps2, u.time_scale_s, u.initial_alpha,
                            u.initial_beta, u.floor_m, u.start_velocity_std_mps, u.calibration_ages,
                            u.calibration_gaps)


def run_train_lstm_update(params: Params, simulated_dir: Path, windows_dir: Path, models_dir: Path,
                          reports_dir: Path) -> None:
    import torch

    u = params.lstm_update
    plots_path = simulated_dir / u.split / "plots.parquet"
    holdout_table = io.read_parquet(windows_dir / "holdout.parquet", materials.HOLDOUT_SCHEMA)
    plots = io.read_parquet(plots_path, simulate.PLOT_SCHEMA)
    held = holdout_table if u.split == params.routes.split("train").name else None
    validation = validation_split.validation_plots(plots, held, params.radar, params.windows.segment_gap_s,
                                                   u.validation_fraction, u.seed, str(plots_path))
    batch = training_segments(plots, validation_split.without(held, validation), params.radar, u.restart_gap_s,
                              u.burn_in_updates, params.tracker.kalman_gate_probability,
                              params.tracker.young_track_plots, u.segment_plots, u.truncation_steps, "lstm_update")
    validation_windows = filter_holdout.window_batch(validation, params.radar, u.segment_plots)
    if not len(validation_windows.times):
        raise io.InputError(f"lstm_update.validation_fraction = {u.validation_fraction}: no validation segment has "
                            f"lstm_update.segment_plots = {u.segment_plots} plots")
    tuned_path = models_dir / "kalman_tuned.json"
    if not tuned_path.is_file():
        raise io.InputError(f"{tuned_path}: file not found (run `dvc repro tune_kalman`)")
    tuned = load_settings(tuned_path)
    holdout = model_eval.holdout_plots(holdout_table, params.radar)
    torch.set_num_threads(params.training.threads)
    described = (f"{len(batch.times)} segments of up to {batch.times.shape[1]} plots ({int(batch.scored.sum())} "
                 f"scored), {len(validation_windows.times)} validation windows")
    with experiment_tracking.filter_training_run(params, "train_lstm_update", "train-lstm-update", plots_path,
                                                 "lstm_update", u, described) as logger:
        torch.manual_seed(u.seed)
        model = LSTMUpdate(estimator_config(params))
        losses, seconds = descend(model, "lstm_update", batch,
                                  DescentConfig(u.epochs, u.batch_segments, u.learning_rate, u.truncation_steps, u.seed,
                                                params.training.deterministic), logger)
        torch.manual_seed(u.seed)  # the calibration's dropout masks
        factors, plot_factors, gap_factors = lstm_update.calibrate(model, validation_windows,
                                                                   params.tracker.kalman_gate_probability)
        runs: dict[str, filter_holdout.FilterRun] = {"LSTM update": model}
        for kind, label in BASELINES.items():
            runs[label] = lambda rows, spec=FilterSpec.from_settings(tuned[kind]): rows.filtered(spec)
        torch.manual_seed(u.seed)  # the hold-out's dropout masks
        holdout_scores = filter_holdout.compare_detailed(holdout, params.radar, params.windows.filter_length, runs,
                                                         u.turn_share, u.range_shares)
        report = {"epoch_losses_m": losses, "seconds": seconds, "detach_prediction": u.detach_prediction,
                  "validation_windows": len(validation_windows.times),
                  "calibration_by_age": {"estimate": factors[0].tolist(), "estimate_plot": plot_factors.tolist(),
                                         "prediction": factors[1].tolist()},
                  "prediction_calibration_by_scan_periods": gap_factors.tolist(),
                  "holdout": holdout_scores}
        kalman_net.save(model, models_dir / "lstm_update.pt", {"epoch_losses_m": losses})
        io.write_json(report, reports_dir / "lstm_update.json")
        ours = holdout_scores["filters"]["LSTM update"]
        logger.log_metrics({"lstm_update.seconds": seconds,
                            **{f"lstm_update.holdout_{key}": value for key, value in ours.items()
                               if isinstance(value, float)}})
        logger.log_artifact(models_dir / "lstm_update.pt")
        logger.log_artifact(reports_dir / "lstm_update.json")
    log.info("train_lstm_update: %.1f m on training after %d epochs (%.0f s); hold-out %s", losses[-1], u.epochs,
             seconds, ", ".join(f"{name} {v['mean_error_m']:.1f} m (turns {v['turn_mean_error_m']:.1f} m, ANEES "
                                f"{v['anees']:.2f})" for name, v in holdout_scores["filters"].items()))

"""Stage `train_lstm_update` (`kinds.Recipe`): the LSTM update on a Kalman prediction (`lstm_update`).

Trained by `filter_training.descent` (Lightning) on the material of the network-scaled filter's
stage: the split's target plots less the windows stage's hold-out segments and less the
validation segments (`validation_split`: `validation_fraction` of the others), restarted at gaps
and every `segment_plots` plots. Then the MC-dropout covariance is calibrated (for the estimate,
and for the prediction to the tracker's gate, `tracker.association.kalman_gate_probability`) on the
validation segments' windows of `segment_plots` plots (as long as the training sequences, so the oldest ages'
factors see old tracks), one started at every plot as the hold-out's are
(`lstm_update.calibrate`), and the estimator is scored on
the hold-out windows against the Nelder-Mead tuned CA filter it starts from and the tuned IMM
(`models/kalman_tuned.json`) with `filter_holdout.compare_detailed`. Everything that can fail on bad
input (params, material, the tuned filters) fails before training. Writes `models/lstm_update.pt`
(`lstm_update.load`) and `reports/lstm_update.json`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from pipeline import io
from pipeline.filters.classical_filters import FilterSettings, load_settings
from pipeline.filters.torch_filters import FilterSpec, SequenceBatch
from pipeline.learning import filter_holdout, lstm_update, materials, model_eval, validation_split, windows
from pipeline.learning.filter_training import descent, training_segments
from pipeline.learning.fit import Task
from pipeline.learning.recipe import Folders, Inputs, Outcome, SectionRecipe, Trained
from pipeline.learning.lstm_update import LSTMUpdate, LSTMUpdateConfig
from pipeline.params import Params
from pipeline.sections import subset
from pipeline.simulation import simulate

BASELINES = {"ca": "Kalman CA, Nelder-Mead tuned", "imm": "IMM (CV + CA), Nelder-Mead tuned"}


@dataclass
class Material:
    """The training segments, the validation windows the covariance is calibrated on, the hold-out's
    target plots and the tuned filters it is scored against."""

    batch: SequenceBatch
    validation_windows: SequenceBatch
    holdout: windows.TargetPlots
    tuned: dict[str, FilterSettings]


class LSTMUpdateRecipe(SectionRecipe):
    """The LSTM update's training, then its calibration and its hold-out against the tuned CA and IMM."""

    section = "lstm_update"

    def data(self, params: Params, folders: Folders) -> Inputs:
        u = params.lstm_update
        plots_path = folders.simulated / u.split / "plots.parquet"
        holdout_table = io.read_parquet(folders.windows / "holdout.parquet", materials.HOLDOUT_SCHEMA)
        plots = io.read_parquet(plots_path, simulate.PLOT_SCHEMA)
        held = holdout_table if u.split == params.routes.split("train").name else None
        validation = validation_split.validation_plots(plots, held, params.radar, params.windows.segment_gap_s,
                                                       u.validation_fraction, u.seed, str(plots_path))
        batch = training_segments(plots, validation_split.without(held, validation), params.radar, u.restart_gap_s,
                                  u.burn_in_updates, params.tracker.association.kalman_gate_probability,
                                  params.tracker.association.young_track_plots, u.segment_plots, u.truncation_steps,
                                  "lstm_update")
        validation_windows = filter_holdout.window_batch(validation, params.radar, u.segment_plots)
        if not len(validation_windows.times):
            raise io.InputError(f"lstm_update.validation_fraction = {u.validation_fraction}: no validation segment "
                                f"has lstm_update.segment_plots = {u.segment_plots} plots")
        tuned_path = folders.models / "kalman_tuned.json"
        if not tuned_path.is_file():
            raise io.InputError(f"{tuned_path}: file not found (run `dvc repro tune_kalman`)")
        material = Material(batch, validation_windows, model_eval.holdout_plots(holdout_table, params.radar),
                            load_settings(tuned_path))
        return Inputs(material, f"{len(batch.times)} segments of up to {batch.times.shape[1]} plots "
                                f"({int(batch.scored.sum())} scored), {len(validation_windows.times)} validation "
                                "windows", plots_path)

    def build(self, params: Params, inputs: Inputs) -> nn.Module:
        return LSTMUpdate(subset(LSTMUpdateConfig, params.lstm_update))

    def task(self, network: nn.Module, inputs: Inputs, params: Params) -> Task:
        return descent(network, "lstm_update", inputs.data.batch, params.lstm_update, params.training.deterministic)

    def holdout(self, trained: Trained) -> Outcome:
        """The covariance calibrated, then the hold-out scores; each draws its dropout masks from the seed."""
        u, params, material, model = trained.params.lstm_update, trained.params, trained.inputs.data, trained.network
        losses, seconds = trained.fitted.train_loss, trained.fitted.seconds
        torch.manual_seed(u.seed)  # the calibration's dropout masks
        factors, plot_factors, gap_factors = lstm_update.calibrate(model, material.validation_windows,
                                                                   params.tracker.association.kalman_gate_probability)
        runs: dict[str, filter_holdout.FilterRun] = {"LSTM update": model}
        for kind, label in BASELINES.items():
            runs[label] = lambda rows, spec=FilterSpec.from_settings(material.tuned[kind]): rows.filtered(spec)
        torch.manual_seed(u.seed)  # the hold-out's dropout masks
        scores = filter_holdout.compare_detailed(material.holdout, params.radar, params.windows.filter_length, runs,
                                                 u.turn_share, u.range_shares)
        report = {"epoch_losses_m": losses, "seconds": seconds, "detach_prediction": u.detach_prediction,
                  "validation_windows": len(material.validation_windows.times),
                  "calibration_by_age": {"estimate": factors[0].tolist(), "estimate_plot": plot_factors.tolist(),
                                         "prediction": factors[1].tolist()},
                  "prediction_calibration_by_scan_periods": gap_factors.tolist(),
                  "holdout": scores}
        ours = scores["filters"]["LSTM update"]
        report_path = trained.folders.reports / "lstm_update.json"
        summary = (f"train_lstm_update: {losses[-1]:.1f} m on training after {u.epochs} epochs ({seconds:.0f} s); "
                   "hold-out " + ", ".join(f"{name} {v['mean_error_m']:.1f} m (turns {v['turn_mean_error_m']:.1f} m, "
                                           f"ANEES {v['anees']:.2f})" for name, v in scores["filters"].items()))
        return Outcome({"epoch_losses_m": losses}, {report_path: report}, (report_path,),
                       {"lstm_update.seconds": seconds,
                        **{f"lstm_update.holdout_{key}": value for key, value in ours.items()
                           if isinstance(value, float)}}, summary)

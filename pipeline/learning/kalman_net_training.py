"""Stage `train_kalman_net` (`kinds.Recipe`): the network-scaled filter and the gradient-tuned classical filters.

Both are trained by `filter_training.descent` on the same material: the target plots of
`kalman_net.split` less the windows stage's hold-out segments (the comparison scores them there),
restarted at gaps and every `segment_plots` plots. Everything that can fail on bad input (params,
material too short for the truncation) fails before training. Writes `models/kalman_net.pt`
(`kalman_net.load`), `models/kalman_gradient.json` (`TunedFilter.from_dict`) and
`reports/kalman_net.json` (per-epoch losses, learned values, seconds).
"""

from __future__ import annotations

import logging
from dataclasses import replace

import pyarrow as pa
from torch import nn

from pipeline import io
from pipeline.filters.classical_filters import FilterSettings
from pipeline.filters.gradient_tuning import TunedFilter
from pipeline.filters.torch_filters import FilterSpec, SequenceBatch
from pipeline.learning import materials
from pipeline.learning.filter_training import descent, training_segments
from pipeline.learning.fit import Task, fit
from pipeline.learning.kalman_net import KalmanNet, KalmanNetConfig
from pipeline.learning.recipe import Folders, Inputs, Outcome, SectionRecipe, Trained
from pipeline.params import Params
from pipeline.sections import subset
from pipeline.simulation import simulate

log = logging.getLogger("pipeline")


def baseline_start(kind: str, params: Params) -> FilterSpec:
    """A gradient-tuned filter's start: the Nelder-Mead tuner's start values (`kalman`); singer, which
    it does not tune, the network's base values."""
    k = params.kalman
    if kind == "singer":
        return FilterSpec("singer", (params.kalman_net.noise_std,), k.velocity_std_mps, k.acceleration_std_mps2,
                          manoeuvre_time_s=params.kalman_net.manoeuvre_time_s)
    return FilterSpec.from_settings(FilterSettings(kind, k.noise_std[kind], k.velocity_std_mps, k.acceleration_std_mps2,
                                                   k.imm_switch_probability, k.imm_initial_cv_probability))


def training_material(params: Params, plots: pa.Table, holdout: pa.Table) -> SequenceBatch:
    """Training segments (B, segment_plots) of the split's target plots, hold-out plots left out
    (they are the windows stage's train split's: only that split has them)."""
    k, gating = params.kalman_net, params.tracker.association
    return training_segments(plots, holdout if k.split == params.routes.split("train").name else None,
                             params.radar, k.restart_gap_s, k.burn_in_updates, gating.kalman_gate_probability,
                             gating.young_track_plots, k.segment_plots, k.truncation_steps, "kalman_net")


class KalmanNetRecipe(SectionRecipe):
    """The network-scaled filter's training, then its gradient-tuned baselines on the same segments."""

    section = "kalman_net"

    def data(self, params: Params, folders: Folders) -> Inputs:
        plots_path = folders.simulated / params.kalman_net.split / "plots.parquet"
        batch = training_material(params, io.read_parquet(plots_path, simulate.PLOT_SCHEMA),
                                  io.read_parquet(folders.windows / "holdout.parquet", materials.HOLDOUT_SCHEMA))
        return Inputs(batch, f"{len(batch.times)} segments of up to {batch.times.shape[1]} plots "
                             f"({int(batch.scored.sum())} scored)", plots_path)

    def build(self, params: Params, inputs: Inputs) -> nn.Module:
        return KalmanNet(subset(KalmanNetConfig, params.kalman_net))

    def task(self, network: nn.Module, inputs: Inputs, params: Params) -> Task:
        return descent(network, "kalman_net", inputs.data, params.kalman_net, params.training.deterministic)

    def holdout(self, trained: Trained) -> Outcome:
        """The gradient-tuned filters (`kalman_net.baselines`) trained on the same segments, and the report."""
        k, deterministic = trained.params.kalman_net, trained.params.training.deterministic
        losses = trained.fitted.train_loss
        report = {"kalman_net": {"base": k.base, "epoch_losses_m": losses, "seconds": trained.fitted.seconds},
                  "gradient": {}}
        baseline_knobs = replace(k, epochs=k.baseline_epochs, learning_rate=k.baseline_learning_rate)
        tuned = {}
        for kind in k.baselines:
            tuned[kind] = TunedFilter(baseline_start(kind, trained.params))
            fitted = fit(*descent(tuned[kind], f"gradient_{kind}", trained.inputs.data, baseline_knobs, deterministic),
                         logger=trained.logger)
            report["gradient"][kind] = {**tuned[kind].to_dict(), "epoch_losses_m": fitted.train_loss,
                                        "seconds": fitted.seconds}
            log.info("train_kalman_net gradient_%s: %s", kind, tuned[kind].to_dict())
        gradient_path = trained.folders.models / "kalman_gradient.json"
        report_path = trained.folders.reports / "kalman_net.json"
        metrics = {"kalman_net.seconds": trained.fitted.seconds,
                   **{f"gradient_{kind}.seconds": v["seconds"] for kind, v in report["gradient"].items()},
                   **{f"gradient_{kind}.r_scale": v["r_scale"] for kind, v in report["gradient"].items()}}
        summary = (f"train_kalman_net: network {losses[-1]:.1f} m after {k.epochs} epochs "
                   f"({trained.fitted.seconds:.0f} s); " + ", ".join(
                       f"gradient {kind} {v['epoch_losses_m'][-1]:.1f} m" for kind, v in report["gradient"].items()))
        return Outcome({"epoch_losses_m": losses},
                       {gradient_path: {kind: model.to_dict() for kind, model in tuned.items()}, report_path: report},
                       (gradient_path, report_path), metrics, summary)

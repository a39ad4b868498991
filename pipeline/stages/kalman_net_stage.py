"""Stage `train_kalman_net`: the network-scaled filter and the gradient-tuned classical filters, one MLflow run.

Both are trained by `filter_training.descend` on the same material: the target plots of
`kalman_net.split` less the windows stage's hold-out segments (the comparison scores them there),
restarted at gaps and every `segment_plots` plots. Everything that can fail on bad input (params,
material too short for the truncation, the tracking store) fails before training. Writes
`models/kalman_net.pt` (`kalman_net.load`), `models/kalman_gradient.json` (`TunedFilter.from_dict`)
and `reports/kalman_net.json` (per-epoch losses, learned values, seconds).
"""

from __future__ import annotations

import logging
from pathlib import Path

import pyarrow as pa

from pipeline import io
from pipeline.filters.classical_filters import FilterSettings
from pipeline.filters.gradient_tuning import TunedFilter
from pipeline.filters.torch_filters import FilterSpec, SequenceBatch
from pipeline.learning import experiment_tracking, kalman_net, materials
from pipeline.learning.filter_training import DescentConfig, descend, training_segments
from pipeline.learning.kalman_net import KalmanNet, KalmanNetConfig
from pipeline.params import Params
from pipeline.simulation import simulate

log = logging.getLogger("pipeline")


def network_config(params: Params) -> KalmanNetConfig:
    k = params.kalman_net
    return KalmanNetConfig(k.base, k.cell, k.hidden, k.noise_std, k.manoeuvre_time_s, k.velocity_std_mps,
                           k.acceleration_std_mps2, k.r0_scale, k.q_amplitude, k.r_amplitude, k.manoeuvre_amplitude,
                           k.velocity_scale_mps, k.nis_scale)


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
    k = params.kalman_net
    return training_segments(plots, holdout if k.split == params.routes.split("train").name else None,
                             params.radar, k.restart_gap_s, k.burn_in_updates, params.tracker.kalman_gate_probability,
                             params.tracker.young_track_plots, k.segment_plots, k.truncation_steps, "kalman_net")


def run_train_kalman_net(params: Params, simulated_dir: Path, windows_dir: Path, models_dir: Path,
                         reports_dir: Path) -> None:
    import torch

    k = params.kalman_net
    plots_path = simulated_dir / k.split / "plots.parquet"
    batch = training_material(params, io.read_parquet(plots_path, simulate.PLOT_SCHEMA),
                              io.read_parquet(windows_dir / "holdout.parquet", materials.HOLDOUT_SCHEMA))
    torch.set_num_threads(params.training.threads)
    described = f"{len(batch.times)} segments of up to {batch.times.shape[1]} plots ({int(batch.scored.sum())} scored)"
    with experiment_tracking.filter_training_run(params, "train_kalman_net", "train-kalman-net", plots_path,
                                                 "kalman_net", k, described) as logger:
        torch.manual_seed(k.seed)  # the initial weights: the same for a seed, whatever ran before in the process
        network = KalmanNet(network_config(params))
        common = dict(batch_segments=k.batch_segments, truncation_steps=k.truncation_steps, seed=k.seed,
                      deterministic=params.training.deterministic)
        losses, seconds = descend(network, "kalman_net", batch,
                                  DescentConfig(k.epochs, learning_rate=k.learning_rate, **common), logger)
        report = {"kalman_net": {"base": k.base, "epoch_losses_m": losses, "seconds": seconds}, "gradient": {}}
        tuned = {}
        for kind in k.baselines:
            tuned[kind] = TunedFilter(baseline_start(kind, params))
            losses, seconds = descend(tuned[kind], f"gradient_{kind}", batch,
                                      DescentConfig(k.baseline_epochs, learning_rate=k.baseline_learning_rate,
                                                    **common), logger)
            report["gradient"][kind] = {**tuned[kind].to_dict(), "epoch_losses_m": losses, "seconds": seconds}
            log.info("train_kalman_net gradient_%s: %s", kind, tuned[kind].to_dict())
        kalman_net.save(network, models_dir / "kalman_net.pt", {"epoch_losses_m": report["kalman_net"]["epoch_losses_m"]})
        io.write_json({kind: model.to_dict() for kind, model in tuned.items()}, models_dir / "kalman_gradient.json")
        io.write_json(report, reports_dir / "kalman_net.json")
        logger.log_metrics({"kalman_net.seconds": report["kalman_net"]["seconds"],
                            **{f"gradient_{kind}.seconds": v["seconds"] for kind, v in report["gradient"].items()},
                            **{f"gradient_{kind}.r_scale": v["r_scale"] for kind, v in report["gradient"].items()}})
        for artifact in ("kalman_net.pt", "kalman_gradient.json"):
            logger.log_artifact(models_dir / artifact)
        logger.log_artifact(reports_dir / "kalman_net.json")
    log.info("train_kalman_net: network %.1f m after %d epochs (%.0f s); %s", report["kalman_net"]["epoch_losses_m"][-1],
             k.epochs, report["kalman_net"]["seconds"],
             ", ".join(f"gradient {kind} {v['epoch_losses_m'][-1]:.1f} m" for kind, v in report["gradient"].items()))


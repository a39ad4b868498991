"""Stage `tune_kalman`: tune the classical filters (CV, CA, IMM) on a split's target plots.

Writes `models/kalman_tuned.json` (what the tracker and the comparison load) only when every
filter tuned; `reports/kalman_tuning.json` has each filter's cost, error and NEES before and
after. One MLflow run records the same.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from pipeline import experiment_tracking, io, simulate, tuning
from pipeline.classical_filters import KINDS, FilterSettings
from pipeline.params import Params

log = logging.getLogger("pipeline")


def start_settings(kind: str, params: Params) -> FilterSettings:
    """The filter as params describe it before tuning."""
    k = params.kalman
    return FilterSettings(kind, k.noise_std[kind], k.velocity_std_mps, k.acceleration_std_mps2,
                          k.imm_switch_probability, k.imm_initial_cv_probability)


def run_tune(params: Params, simulated_dir: Path, models_dir: Path, reports_dir: Path) -> None:
    import mlflow

    plots_path = simulated_dir / params.kalman.split / "plots.parquet"
    plots = io.read_parquet(plots_path, simulate.PLOT_SCHEMA)
    material = tuning.target_sequences(plots, params.radar, params.kalman.restart_gap_s, params.kalman.burn_in_updates)
    uri = experiment_tracking.tracking_uri(params.training.tracking_uri)
    experiment_tracking.check_tracking_store(uri, params.training.experiment)
    log.info("tune_kalman: %d target plots of %s, %d scored, cost %s", int(material.valid.sum()), plots_path,
             int(material.scored.sum()), params.kalman.cost)

    tuned, report = {}, {"cost": params.kalman.cost, "split": params.kalman.split, "filters": {}}
    for kind in KINDS:
        start = time.perf_counter()
        settings, before, after, evaluations = tuning.tune(start_settings(kind, params), material,
                                                           params.kalman.cost, params.kalman.max_iterations)
        tuned[kind] = settings
        report["filters"][kind] = {
            "noise_std": list(settings.noise_std), "velocity_std_mps": settings.velocity_std_mps,
            "at_search_bound": tuning.at_bounds(start_settings(kind, params), settings),
            "cost_before": before.cost(params.kalman.cost), "cost_after": after.cost(params.kalman.cost),
            "before": before.to_dict(), "after": after.to_dict(), "cost_evaluations": evaluations,
            "seconds": time.perf_counter() - start}
        log.info("tune_kalman %s: cost %.4g -> %.4g, RMSE %.1f m (plots %.1f m), ANEES %.3f (95 %% bounds %.3f-%.3f), "
                 "noise %s, velocity spread %.1f m/s, %d evaluations", kind, before.cost(params.kalman.cost),
                 after.cost(params.kalman.cost), after.rmse_m, after.plot_rmse_m, after.anees, *after.anees_bounds,
                 [round(v, 4) for v in settings.noise_std], settings.velocity_std_mps, evaluations)

    io.write_json({"cost": params.kalman.cost, "filters": {kind: s.to_dict() for kind, s in tuned.items()}},
                  models_dir / "kalman_tuned.json")
    io.write_json(report, reports_dir / "kalman_tuning.json")

    mlflow.set_tracking_uri(uri)
    mlflow.set_experiment(params.training.experiment)
    with mlflow.start_run(run_name="tune_kalman", tags={"stage": "tune_kalman",
                                                          "git_commit": experiment_tracking.git_commit(),
                                                          "input_data_sha256": experiment_tracking.data_hash(plots_path)}):
        mlflow.log_params({f"kalman.{key}": value for key, value in vars(params.kalman).items()})
        mlflow.log_metrics({f"{kind}.{name}": float(values[name]) for kind, values in report["filters"].items()
                            for name in ("cost_before", "cost_after")})
        mlflow.log_metrics({f"{kind}.{stage}.{name}": float(values[stage][name])
                            for kind, values in report["filters"].items() for stage in ("before", "after")
                            for name in ("rmse_m", "anees", "nees_in_95_interval")})
        mlflow.log_artifact(str(models_dir / "kalman_tuned.json"))
        mlflow.log_artifact(str(reports_dir / "kalman_tuning.json"))

"""Stage `tune_kalman`: tune the classical filters of `kalman.filters` (CV, CA, IMM always; the IMMs with
turns where listed) on a split's target plots.

Writes `models/kalman_tuned.json` (what the tracker and the comparison load) only when every
filter tuned; `reports/kalman_tuning.json` has each filter's cost, error and NEES before and
after. One MLflow run records the same.

The filters tune independently, so with `compute.workers` > 1 (or a Dask scheduler named
by DASK_SCHEDULER_ADDRESS) they run on the bench's engine (`pipeline.bench.engine`), the IMMs first
because each takes longer than the other two together. Every filter gets the same inputs
wherever it runs and the results are gathered by kind, so the outputs do not depend on it (only
the `seconds` in the report do). The workers' log lines go through the stage's logging.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from pipeline import io
from pipeline.bench import engine
from pipeline.filters import tuning
from pipeline.filters.classical_filters import KINDS, TURNING_KINDS, FilterSettings
from pipeline.learning import experiment_tracking
from pipeline.params import Params
from pipeline.simulation import simulate

log = logging.getLogger("pipeline")

LONGEST_FIRST = ("imm_ca_ct", "imm_ct", "imm", "ca", "cv")  # submission order: each worker takes the next when it is free


def start_settings(kind: str, params: Params) -> FilterSettings:
    """The filter as params describe it before tuning."""
    k = params.kalman
    return FilterSettings(kind, k.noise_std[kind], k.velocity_std_mps, k.acceleration_std_mps2,
                          k.imm_switch_probability, k.imm_initial_cv_probability,
                          k.imm_ct_turn_rate_dps if kind in TURNING_KINDS else 0.0)


def tune_filter(start: FilterSettings, material: tuning.Sequences, cost: str, max_iterations: int
                ) -> tuple[FilterSettings, dict]:
    """One filter tuned (`tuning.tune`): the tuned settings and its entry of reports/kalman_tuning.json,
    with the seconds it took. Runs in a worker process or in the stage's own."""
    began = time.perf_counter()
    settings, before, after, evaluations = tuning.tune(start, material, cost, max_iterations)
    return settings, {
        "noise_std": list(settings.noise_std), "velocity_std_mps": settings.velocity_std_mps,
        "switch_probability": settings.switch_probability, "turn_rate_dps": settings.turn_rate_dps,
        "at_search_bound": tuning.at_bounds(start, settings),
        "cost_before": before.cost(cost), "cost_after": after.cost(cost),
        "before": before.to_dict(), "after": after.to_dict(), "cost_evaluations": evaluations,
        "seconds": time.perf_counter() - began}


def _log_tuned(kind: str, entry: dict) -> None:
    after = entry["after"]
    log.info("tune_kalman %s: cost %.4g -> %.4g, RMSE %.1f m (plots %.1f m), ANEES %.3f (95 %% bounds %.3f-%.3f), "
             "noise %s, velocity spread %.1f m/s, switch probability %.4g, turn rate %.3g deg/s, %d evaluations, "
             "%.1f s",
             kind, entry["cost_before"], entry["cost_after"], after["rmse_m"], after["plot_rmse_m"], after["anees"],
             *after["anees_bounds"], [round(v, 4) for v in entry["noise_std"]], entry["velocity_std_mps"],
             entry["switch_probability"], entry["turn_rate_dps"], entry["cost_evaluations"], entry["seconds"])


def _tasks(params: Params, material: tuning.Sequences) -> dict[str, tuple]:
    """Each filter kind's `tune_filter` arguments: the same wherever it runs."""
    return {kind: (start_settings(kind, params), material, params.kalman.cost, params.kalman.max_iterations)
            for kind in _kinds(params)}


def _kinds(params: Params) -> tuple[str, ...]:
    """The kinds `kalman.filters` lists, in KINDS order."""
    return tuple(kind for kind in KINDS if kind in params.kalman.filters)


def _tuned_kind(tasks: dict[str, tuple], kind: str) -> tuple[FilterSettings, dict] | tuning.TuningError:
    """One kind tuned, or the TuningError it stopped with (raised by `tune_all` once all are in)."""
    try:
        return tune_filter(*tasks[kind])
    except tuning.TuningError as error:
        return error


def tune_all(params: Params, material: tuning.Sequences) -> dict[str, tuple[FilterSettings, dict]]:
    """Every filter kind of `kalman.filters` tuned (`tune_filter`), by kind in KINDS order, on `params.workers`
    workers of the bench's engine (`pipeline.bench.engine`: this process, a local cluster or a named scheduler).

    Raises the TuningError of the first kind (in KINDS order) that failed, after all have finished."""
    kinds = _kinds(params)
    units = [(kind,) for kind in sorted(kinds, key=LONGEST_FIRST.index)]
    tasks = _tasks(params, material)
    results = {}
    for (kind,), result in engine.completed_units(units, min(params.workers, len(kinds)), _tuned_kind, tasks,
                                                  _tasks, (params, material)):
        results[kind] = result
        if not isinstance(result, tuning.TuningError):
            _log_tuned(kind, result[1])
    failed = [results[kind] for kind in kinds if isinstance(results[kind], tuning.TuningError)]
    if failed:
        raise failed[0]
    return {kind: results[kind] for kind in kinds}


def run_tune(params: Params, simulated_dir: Path, models_dir: Path, reports_dir: Path) -> None:
    """Stage `tune_kalman`: the tuned filters and their report, in one MLflow run that spans the
    tuning and ends FAILED if it fails."""
    import mlflow

    plots_path = simulated_dir / params.kalman.split / "plots.parquet"
    plots = io.read_parquet(plots_path, simulate.PLOT_SCHEMA)
    gating = params.tracker.association
    material = tuning.target_sequences(plots, params.radar, params.kalman.restart_gap_s, params.kalman.burn_in_updates,
                                       gating.kalman_gate_probability, gating.young_track_plots)
    uri = experiment_tracking.tracking_uri(params.training.tracking_uri)
    experiment_tracking.check_tracking_store(uri, params.training.experiment, "tune_kalman")
    log.info("tune_kalman: %d target plots of %s, %d scored, cost %s, %d worker processes", int(material.valid.sum()),
             plots_path, int(material.scored.sum()), params.kalman.cost, min(params.workers, len(_kinds(params))))

    with experiment_tracking.stage_run(uri, params, "tune_kalman", "tune-kalman",
                                       {"input_data_sha256": experiment_tracking.data_hash(plots_path)}):
        mlflow.log_params({f"kalman.{key}": value for key, value in vars(params.kalman).items()})
        results = tune_all(params, material)
        report = {"cost": params.kalman.cost, "split": params.kalman.split,
                  "filters": {kind: entry for kind, (_, entry) in results.items()}}
        io.write_json({"cost": params.kalman.cost, "filters": {kind: s.to_dict() for kind, (s, _) in results.items()}},
                      models_dir / "kalman_tuned.json")
        io.write_metrics(report, reports_dir / "kalman_tuning.json")

        mlflow.log_metrics({f"{kind}.{name}": float(values[name]) for kind, values in report["filters"].items()
                            for name in ("cost_before", "cost_after")})
        mlflow.log_metrics({f"{kind}.{stage}.{name}": float(values[stage][name])
                            for kind, values in report["filters"].items() for stage in ("before", "after")
                            for name in ("rmse_m", "anees", "nees_in_95_interval")})
        mlflow.log_artifact(str(models_dir / "kalman_tuned.json"))
        mlflow.log_artifact(str(reports_dir / "kalman_tuning.json"))

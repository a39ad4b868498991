"""Stage `tune_kalman`: tune the classical filters (CV, CA, IMM) on a split's target plots.

Writes `models/kalman_tuned.json` (what the tracker and the comparison load) only when every
filter tuned; `reports/kalman_tuning.json` has each filter's cost, error and NEES before and
after. One MLflow run records the same.

The three filters tune independently, so with `compute.workers` > 1 they run in that many
worker processes (spawned, not forked: the parent may hold threads), the IMM first because it
takes about as long as the other two together. Every filter gets the same inputs whatever the
number of workers and the results are gathered by kind, so the outputs do not depend on it
(only the `seconds` in the report do). The workers' log lines go through the stage's logging.
"""

from __future__ import annotations

import logging
import logging.handlers
import multiprocessing
import time
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from pathlib import Path

from pipeline import io
from pipeline.filters import tuning
from pipeline.filters.classical_filters import KINDS, FilterSettings
from pipeline.learning import experiment_tracking
from pipeline.params import Params
from pipeline.simulation import simulate

log = logging.getLogger("pipeline")

LONGEST_FIRST = ("imm", "ca", "cv")  # submission order: each worker takes the next when it is free


def start_settings(kind: str, params: Params) -> FilterSettings:
    """The filter as params describe it before tuning."""
    k = params.kalman
    return FilterSettings(kind, k.noise_std[kind], k.velocity_std_mps, k.acceleration_std_mps2,
                          k.imm_switch_probability, k.imm_initial_cv_probability)


def tune_filter(start: FilterSettings, material: tuning.Sequences, cost: str, max_iterations: int
                ) -> tuple[FilterSettings, dict]:
    """One filter tuned (`tuning.tune`): the tuned settings and its entry of reports/kalman_tuning.json,
    with the seconds it took. Runs in a worker process or in the stage's own."""
    began = time.perf_counter()
    settings, before, after, evaluations = tuning.tune(start, material, cost, max_iterations)
    return settings, {
        "noise_std": list(settings.noise_std), "velocity_std_mps": settings.velocity_std_mps,
        "switch_probability": settings.switch_probability,
        "at_search_bound": tuning.at_bounds(start, settings),
        "cost_before": before.cost(cost), "cost_after": after.cost(cost),
        "before": before.to_dict(), "after": after.to_dict(), "cost_evaluations": evaluations,
        "seconds": time.perf_counter() - began}


def _log_tuned(kind: str, entry: dict) -> None:
    after = entry["after"]
    log.info("tune_kalman %s: cost %.4g -> %.4g, RMSE %.1f m (plots %.1f m), ANEES %.3f (95 %% bounds %.3f-%.3f), "
             "noise %s, velocity spread %.1f m/s, switch probability %.4g, %d evaluations, %.1f s", kind,
             entry["cost_before"], entry["cost_after"], after["rmse_m"], after["plot_rmse_m"], after["anees"],
             *after["anees_bounds"], [round(v, 4) for v in entry["noise_std"]], entry["velocity_std_mps"],
             entry["switch_probability"], entry["cost_evaluations"], entry["seconds"])


def _log_through(queue: multiprocessing.Queue, level: int) -> None:
    """Worker initializer: send every log record at `level` or above to the stage's process."""
    root = logging.getLogger()
    root.handlers[:] = [logging.handlers.QueueHandler(queue)]
    root.setLevel(level)


def tune_all(params: Params, material: tuning.Sequences) -> dict[str, tuple[FilterSettings, dict]]:
    """Every filter kind tuned (`tune_filter`), by kind in KINDS order, in `params.workers` processes.

    Raises the TuningError of the first kind (in KINDS order) that failed, after all have finished."""
    tasks = {kind: (start_settings(kind, params), material, params.kalman.cost, params.kalman.max_iterations)
             for kind in KINDS}
    if params.workers == 1:
        results = {}
        for kind in KINDS:
            results[kind] = tune_filter(*tasks[kind])
            _log_tuned(kind, results[kind][1])
        return results
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    listener = logging.handlers.QueueListener(queue, *logging.getLogger().handlers, respect_handler_level=True)
    listener.start()
    try:
        with ProcessPoolExecutor(min(params.workers, len(KINDS)), mp_context=context, initializer=_log_through,
                                 initargs=(queue, log.getEffectiveLevel())) as pool:
            futures: dict[str, Future] = {kind: pool.submit(tune_filter, *tasks[kind])
                                          for kind in sorted(KINDS, key=LONGEST_FIRST.index)}
            kinds = {future: kind for kind, future in futures.items()}
            for future in as_completed(kinds):
                if future.exception() is None:
                    _log_tuned(kinds[future], future.result()[1])
            return {kind: futures[kind].result() for kind in KINDS}
    finally:
        listener.stop()


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
             plots_path, int(material.scored.sum()), params.kalman.cost, min(params.workers, len(KINDS)))

    with experiment_tracking.stage_run(uri, params, "tune_kalman", "tune-kalman",
                                       {"input_data_sha256": experiment_tracking.data_hash(plots_path)}):
        mlflow.log_params({f"kalman.{key}": value for key, value in vars(params.kalman).items()})
        results = tune_all(params, material)
        report = {"cost": params.kalman.cost, "split": params.kalman.split,
                  "filters": {kind: entry for kind, (_, entry) in results.items()}}
        io.write_json({"cost": params.kalman.cost, "filters": {kind: s.to_dict() for kind, (s, _) in results.items()}},
                      models_dir / "kalman_tuned.json")
        io.write_json(report, reports_dir / "kalman_tuning.json")

        mlflow.log_metrics({f"{kind}.{name}": float(values[name]) for kind, values in report["filters"].items()
                            for name in ("cost_before", "cost_after")})
        mlflow.log_metrics({f"{kind}.{stage}.{name}": float(values[stage][name])
                            for kind, values in report["filters"].items() for stage in ("before", "after")
                            for name in ("rmse_m", "anees", "nees_in_95_interval")})
        mlflow.log_artifact(str(models_dir / "kalman_tuned.json"))
        mlflow.log_artifact(str(reports_dir / "kalman_tuning.json"))

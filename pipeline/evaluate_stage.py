"""Stage `evaluate`: the full tracker with every association method and window over the test scenarios.

Each scenario is one radar recording tracked on its own, as in the thesis. The MIA
sampling draws from a stream seeded by (tracker seed, scenario), so results do not depend
on the order scenarios are run in.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pipeline import experiment_tracking, figures, io, materials, routes, simulate
from pipeline.model_store import load_model
from pipeline.params import EvaluationRun, Params
from pipeline.stages import progress_logger
from pipeline.tracker.models import Models
from pipeline.tracker.run import track_plots
from pipeline.tracker_metrics import THESIS, THESIS_PLOTS, RouteCounts, markdown_table, route_counts, summarise

log = logging.getLogger("pipeline")

PLOT_FEATURE_COLUMNS = ("time_unix_s", "x_ecef_m", "y_ecef_m", "z_ecef_m", "range_m")


@dataclass
class Scenario:
    scenario_id: int
    features: np.ndarray          # [t, x, y, z, r] per plot, time order
    plot_ids: np.ndarray
    is_target: dict[int, bool]
    truth: object                 # t -> ECEF positions (a spline over the route)


def load_tracker_models(models_dir: Path, params: Params, need_autoencoder: bool) -> Models:
    """The trained networks, refusing any whose scaler differs from what params describe."""
    expected = materials.scalers(params.windows)
    loaded = {}
    for kind, layout in (("predictor", "states"), ("filter", "plots"), ("autoencoder", "plots")):
        if kind == "autoencoder" and not need_autoencoder:
            continue
        path = models_dir / f"{kind}.pt"
        model = load_model(path, expected_kind=kind)
        if model.scaler != expected[layout]:
            raise io.InputError(f"{path}: built with the scaler {model.scaler}, but params give {expected[layout]}; "
                                f"retrain it (dvc repro train_{kind})")
        loaded[kind] = model
    return Models(loaded["predictor"], loaded["filter"], loaded.get("autoencoder"), params.tracker.inference)


def load_scenarios(plots: pa.Table, route_table: pa.Table) -> list[Scenario]:
    scenarios = []
    route_ids = route_table.column("route_id").to_numpy()
    for scenario_id in np.unique(plots.column("scenario_id").to_numpy()):
        part = plots.filter(pc.equal(plots.column("scenario_id"), scenario_id))
        order = np.argsort(part.column("time_unix_s").to_numpy(), kind="stable")
        features = np.column_stack([part.column(c).to_numpy() for c in PLOT_FEATURE_COLUMNS])[order]
        plot_ids = part.column("plot_id").to_numpy()[order]
        flags = part.column("is_target").to_numpy(zero_copy_only=False)[order]
        route = route_table.filter(pa.array(route_ids == scenario_id))
        trajectory = simulate.trajectory_of({name: route.column(name).to_numpy() for name in simulate.ROUTE_COLUMNS})
        scenarios.append(Scenario(int(scenario_id), features, plot_ids,
                                  dict(zip(plot_ids.tolist(), flags.tolist())), _clipped(trajectory)))
    return scenarios


def _clipped(trajectory: object) -> object:
    """The route's position at any time, held at its ends outside it."""
    start, end = trajectory.x[0], trajectory.x[-1]
    return lambda t: trajectory(np.clip(t, start, end))


def evaluate_run(run: EvaluationRun, scenarios: list[Scenario], models: Models, params: Params
                 ) -> tuple[dict, dict[int, dict], float]:
    """Metrics of one method and window, each scenario's updates, and plots per second."""
    counts: list[RouteCounts] = []
    updates_by_scenario = {}
    report = progress_logger(f"evaluate {run.name}")
    elapsed = 0.0
    for done, scenario in enumerate(scenarios, start=1):
        start = time.perf_counter()
        updates = track_plots(scenario.features, scenario.plot_ids, run.method, run.window_m, models, params.tracker,
                              seed=[params.tracker.seed, scenario.scenario_id], radar=params.radar)
        elapsed += time.perf_counter() - start
        counts.append(route_counts(updates, scenario.is_target, scenario.truth, params.tracker.weight_confirmed))
        updates_by_scenario[scenario.scenario_id] = updates
        report(done, len(scenarios))
    plots = sum(len(s.features) for s in scenarios)
    return summarise(counts), updates_by_scenario, plots / elapsed if elapsed else float("nan")


def run_evaluate(params: Params, simulated_dir: Path, routes_dir: Path, models_dir: Path, reports_dir: Path) -> None:
    from lightning.pytorch.loggers import MLFlowLogger

    split = params.evaluate.split
    plots = io.read_parquet(simulated_dir / split / "plots.parquet", simulate.PLOT_SCHEMA)
    route_table = io.read_parquet(routes_dir / f"{split}.parquet", routes.ROUTE_SCHEMA)
    models = load_tracker_models(models_dir, params, any(run.method == "ae" for run in params.evaluate.runs))
    scenarios = load_scenarios(plots, route_table)
    uri = experiment_tracking.tracking_uri(params.training.tracking_uri)
    experiment_tracking.check_tracking_store(uri, params.training.experiment)

    results, speed, examples = {}, {}, {}
    for run in params.evaluate.runs:
        results[run.name], updates, speed[run.name] = evaluate_run(run, scenarios, models, params)
        log.info("evaluate %s: %s, %.0f plots/s", run.name,
                 ", ".join(f"{k} {v:.4g}" for k, v in results[run.name].items()), speed[run.name])
        if run.name == params.evaluate.example_run:
            examples = updates
    first = results[params.evaluate.runs[0].name]
    metrics = {"runs": results, "plots": {"target": first["target_plots"], "false": first["false_plots"]},
               "thesis": {"runs": THESIS, "plots": THESIS_PLOTS}}
    table = markdown_table(results)
    pictures = {scenario.scenario_id: figures.tracking_picture(scenario, examples[scenario.scenario_id], params,
                                                              params.evaluate.example_run)
                for scenario in scenarios[:params.evaluate.example_scenarios]}

    io.write_json(metrics, reports_dir / "tracker_metrics.json")
    io.write_text(f"# Tracker on the {split} scenarios\n\nGenerated by `dvc repro evaluate` "
                  f"(`python -m pipeline evaluate`); thesis rows from its tables 5.1 and 5.2.\n\n{table}\n",
                  reports_dir / "tracker_tables.md")
    for scenario_id, png in pictures.items():
        io.write_bytes(png, reports_dir / "tracks" / f"scenario_{scenario_id}.png")

    logger = MLFlowLogger(experiment_name=params.training.experiment, run_name="evaluate", tracking_uri=uri,
                          tags={"stage": "evaluate", "git_commit": experiment_tracking.git_commit(),
                                "input_data_sha256": experiment_tracking.data_hash(
                                    simulated_dir / split / "plots.parquet", *sorted(models_dir.glob("*.pt")))})
    logger.log_hyperparams({"runs": [run.name for run in params.evaluate.runs], "split": split,
                            **{f"tracker.{k}": v for k, v in vars(params.tracker).items()}})
    logger.log_metrics({f"{name}.{metric}": float(value) for name, values in results.items()
                        for metric, value in values.items() if np.isfinite(value)})
    logger.log_metrics({f"{name}.plots_per_second": value for name, value in speed.items()})
    for artifact in [reports_dir / "tracker_metrics.json", reports_dir / "tracker_tables.md",
                     *sorted((reports_dir / "tracks").glob("*.png"))]:
        logger.experiment.log_artifact(logger.run_id, str(artifact))
    logger.finalize("success")


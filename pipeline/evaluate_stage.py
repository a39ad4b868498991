"""Stage `evaluate`: the full tracker with every association method and window over the test scenarios.

Each scenario is one radar recording tracked on its own, as in the thesis. The MIA
sampling draws from a stream seeded by (tracker seed, scenario), so results do not depend
on the order scenarios are run in.

Besides the thesis's metrics every run gets OSPA (`pipeline.ospa`), ANEES where the tracker
gives covariances, and its speed in plots per second (tracking time only, one core). Two
references bound the problem: `plots`, the target's raw plots taken as the estimate with the
true association, and `oracle`, the tuned IMM given the true association.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pipeline import baselines, classical_filters, experiment_tracking, figures, io, materials, ospa, routes, simulate
from pipeline.model_store import load_model
from pipeline.params import EvaluationRun, Params
from pipeline.stages import progress_logger
from pipeline.tracker.models import Models
from pipeline.tracker.run import ORACLE, classical_kind, track_plots
from pipeline.tracker_metrics import (THESIS, THESIS_PLOTS, RouteCounts, confirmed_nees, markdown_table, route_counts,
                                      summarise)

log = logging.getLogger("pipeline")

PLOT_FEATURE_COLUMNS = ("time_unix_s", "x_ecef_m", "y_ecef_m", "z_ecef_m", "range_m")


@dataclass
class Scenario:
    scenario_id: int
    features: np.ndarray          # [t, x, y, z, r] per plot, time order
    plot_ids: np.ndarray
    is_target: dict[int, bool]
    truth: object                 # t -> ECEF positions (a spline over the route)
    scans: np.ndarray             # each plot's antenna scan
    coverage_scans: np.ndarray    # the scans in which the target was in radar coverage


def load_tracker_models(models_dir: Path, params: Params, methods: list[str]) -> Models:
    """The trained networks, refusing any whose scaler differs from what params describe, and
    the tuned classical filters when a method needs them."""
    need_autoencoder = "ae" in methods
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
    filters = {}
    if any(classical_kind(method) for method in methods):
        path = models_dir / "kalman_tuned.json"
        try:
            filters = classical_filters.load_settings(path)
        except (FileNotFoundError, ValueError) as error:
            raise io.InputError(str(error)) from None
    return Models(loaded["predictor"], loaded["filter"], loaded.get("autoencoder"), params.tracker.inference, filters)


def load_scenarios(plots: pa.Table, route_table: pa.Table, truth_table: pa.Table) -> list[Scenario]:
    scenarios = []
    route_ids = route_table.column("route_id").to_numpy()
    truth_scenarios = truth_table.column("scenario_id").to_numpy()
    truth_scans = truth_table.column("scan").to_numpy()
    in_coverage = truth_table.column("in_coverage").to_numpy(zero_copy_only=False)
    for scenario_id in np.unique(plots.column("scenario_id").to_numpy()):
        part = plots.filter(pc.equal(plots.column("scenario_id"), scenario_id))
        order = np.argsort(part.column("time_unix_s").to_numpy(), kind="stable")
        features = np.column_stack([part.column(c).to_numpy() for c in PLOT_FEATURE_COLUMNS])[order]
        plot_ids = part.column("plot_id").to_numpy()[order]
        flags = part.column("is_target").to_numpy(zero_copy_only=False)[order]
        route = route_table.filter(pa.array(route_ids == scenario_id))
        trajectory = simulate.trajectory_of({name: route.column(name).to_numpy() for name in simulate.ROUTE_COLUMNS})
        scenarios.append(Scenario(int(scenario_id), features, plot_ids,
                                  dict(zip(plot_ids.tolist(), flags.tolist())), _clipped(trajectory),
                                  part.column("scan").to_numpy()[order],
                                  np.unique(truth_scans[(truth_scenarios == scenario_id) & in_coverage])))
    return scenarios


def _clipped(trajectory: object) -> object:
    """The route's position at any time, held at its ends outside it."""
    start, end = trajectory.x[0], trajectory.x[-1]
    return lambda t: trajectory(np.clip(t, start, end))


def reference_updates(scenario: Scenario, method: str, models: Models, params: Params) -> dict[str, np.ndarray]:
    """The references' updates, from the target's plots only: `plots` takes each plot as the
    estimate of one always-confirmed track; `oracle` runs the tuned IMM tracker on them."""
    target = np.array([scenario.is_target[int(p)] for p in scenario.plot_ids], dtype=bool)
    features, plot_ids = scenario.features[target], scenario.plot_ids[target]
    if method == ORACLE:
        return track_plots(features, plot_ids, ORACLE, 0.0, models, params.tracker, radar=params.radar)
    count = len(features)
    return {"track_id": np.zeros(count, np.int64), "time_unix_s": features[:, 0], "plot_id": plot_ids,
            "x_ecef_m": features[:, 1], "y_ecef_m": features[:, 2], "z_ecef_m": features[:, 3],
            "range_m": features[:, 4], "weight": np.full(count, params.tracker.weight_confirmed),
            "association": np.array(["truth"] * count), "association_error": np.zeros(count),
            "position_covariance": baselines.measurement_covariance(features[:, 1:4], params.radar)}


def evaluate_run(name: str, track: callable, scenarios: list[Scenario], params: Params
                 ) -> tuple[dict, dict[int, dict], np.ndarray]:
    """Metrics of one tracker (`track(scenario)` gives its updates), each scenario's updates,
    and the OSPA of every scan of every scenario."""
    counts: list[RouteCounts] = []
    scan_ospa, nees = [], []
    updates_by_scenario = {}
    report = progress_logger(f"evaluate {name}")
    elapsed = 0.0
    confirmed = params.tracker.weight_confirmed
    for done, scenario in enumerate(scenarios, start=1):
        start = time.perf_counter()
        updates = track(scenario)
        elapsed += time.perf_counter() - start
        counts.append(route_counts(updates, scenario.is_target, scenario.truth, confirmed))
        scan_of_plot = dict(zip(scenario.plot_ids.tolist(), scenario.scans.tolist()))
        scan_ospa.append(ospa.scan_ospa(
            updates, np.array([scan_of_plot[int(p)] for p in updates["plot_id"]], dtype=np.int64), confirmed,
            scenario.coverage_scans, np.unique(scenario.scans), scenario.truth, params.evaluate.ospa_cutoff_m,
            params.evaluate.ospa_order))
        nees.append(confirmed_nees(updates, scenario.is_target, scenario.truth, confirmed))
        updates_by_scenario[scenario.scenario_id] = updates
        report(done, len(scenarios))
    plots = sum(len(s.features) for s in scenarios)
    all_nees = np.concatenate(nees)
    per_scan = np.concatenate(scan_ospa)
    metrics = {**summarise(counts), "OSPA": float(per_scan.mean()), "OSPA_p90": float(np.percentile(per_scan, 90)),
               "ANEES": float(all_nees.mean()) if len(all_nees) and np.isfinite(all_nees).all() else float("nan"),
               "plots_per_second": plots / elapsed if elapsed else float("nan")}
    return metrics, updates_by_scenario, per_scan


def tracker_runs(params: Params, models: Models) -> dict[str, callable]:
    """Every run of params, and the references, as name -> track(scenario)."""
    def method_run(run: EvaluationRun) -> callable:
        return lambda scenario: track_plots(scenario.features, scenario.plot_ids, run.method, run.window_m, models,
                                            params.tracker, seed=[params.tracker.seed, scenario.scenario_id],
                                            radar=params.radar)

    def reference_run(method: str) -> callable:
        return lambda scenario: reference_updates(scenario, method, models, params)

    return {**{run.name: method_run(run) for run in params.evaluate.runs},
            **{f"{method}_reference": reference_run(method) for method in params.evaluate.references}}


def run_evaluate(params: Params, simulated_dir: Path, routes_dir: Path, models_dir: Path, reports_dir: Path) -> None:
    from lightning.pytorch.loggers import MLFlowLogger

    split = params.evaluate.split
    plots = io.read_parquet(simulated_dir / split / "plots.parquet", simulate.PLOT_SCHEMA)
    route_table = io.read_parquet(routes_dir / f"{split}.parquet", routes.ROUTE_SCHEMA)
    truth_table = io.read_parquet(simulated_dir / split / "truth.parquet", simulate.TRUTH_SCHEMA)
    models = load_tracker_models(models_dir, params, [run.method for run in params.evaluate.runs]
                                 + [ORACLE for method in params.evaluate.references if method == ORACLE])
    scenarios = load_scenarios(plots, route_table, truth_table)
    uri = experiment_tracking.tracking_uri(params.training.tracking_uri)
    experiment_tracking.check_tracking_store(uri, params.training.experiment)

    results, examples, per_scan = {}, {}, {}
    for name, track in tracker_runs(params, models).items():
        results[name], updates, per_scan[name] = evaluate_run(name, track, scenarios, params)
        log.info("evaluate %s: %s", name, ", ".join(f"{k} {v:.4g}" for k, v in results[name].items()))
        if name == params.evaluate.example_run:
            examples = updates
    first = results[params.evaluate.runs[0].name]
    metrics = {"runs": results, "plots": {"target": first["target_plots"], "false": first["false_plots"]},
               "thesis": {"runs": THESIS, "plots": THESIS_PLOTS}}
    table = markdown_table({name: values for name, values in results.items() if not name.endswith("_reference")})
    pictures = {scenario.scenario_id: figures.tracking_picture(scenario, examples[scenario.scenario_id], params,
                                                              params.evaluate.example_run)
                for scenario in scenarios[:params.evaluate.example_scenarios]}

    ospa_png = figures.ospa_distribution(per_scan, params.evaluate.ospa_cutoff_m)
    io.write_json(metrics, reports_dir / "tracker_metrics.json")
    io.write_bytes(ospa_png, reports_dir / "ospa_per_scan.png")
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
    for artifact in [reports_dir / "tracker_metrics.json", reports_dir / "tracker_tables.md",
                     *sorted((reports_dir / "tracks").glob("*.png"))]:
        logger.experiment.log_artifact(logger.run_id, str(artifact))
    logger.finalize("success")


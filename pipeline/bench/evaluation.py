"""Evaluate trackers over scenarios: one unit per (run, scenario), run on the bench's engine.

Each scenario is one radar recording tracked on its own, as in the thesis. The MIA
sampling draws from a stream seeded by (tracker seed, scenario), so results do not depend
on the order scenarios are run in.

Besides the thesis's metrics every run gets OSPA (`pipeline.bench.ospa`), GOSPA with its parts, track
switches, tracks per truth and track purity (`pipeline.bench.gospa`, on OSPA's sets of each scan), ANEES
where the tracker gives covariances, the surveillance scorecard (`pipeline.surveillance.scorecard`, params'
`scorecard`, the update interval the radar's scan period; issue 32) of its confirmed updates against the
target's true position at every scan, and its speed in plots per second (tracking time only, one core). Two
references bound the problem: `plots`, the target's raw plots taken as the estimate with the
true association, and `oracle`, the tuned IMM given the true association.

With `evaluate.seeds` > 1 every scenario is tracked again on further draws of the radar's noise,
detections and clutter over the same route (`drawn_scenarios`); a run's metrics are over all of them,
its counts (NOPA, NOFPA, plots, switches) means per draw, and their confidence intervals
(`metric_intervals`, `pipeline.bench.intervals`) resample the routes, each with all its draws.

The units are all independent, run on the bench's engine (`pipeline.bench.engine`: `compute.workers`
Dask worker processes, 1: all in this one, or the workers of the scheduler DASK_SCHEDULER_ADDRESS names).
Units are handed out largest first so no worker is left with a long one at the end, and their
results are put together by run and scenario, never in the order they finish: the metrics are
the same byte for byte whatever the number of workers, except the speeds, which are timings.
The stages `evaluate` (the evaluated split at the radar's site) and `evaluate_sites` (the same
routes at other sites) both run their scenarios through here.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.bench import engine, gospa, intervals, ospa
from pipeline.bench.runs import Run, evaluated
from pipeline.bench.tracker_metrics import RouteCounts, confirmed_nees, route_counts, summarise
from pipeline.filters import classical_filters
from pipeline.params import Params
from pipeline.progress import progress_logger
from pipeline.recordings import plot_table
from pipeline.recordings.plot_table import NO_TARGET, Plots
from pipeline.simulation import routes, simulate
from pipeline.surveillance import pcrb, scorecard
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.management import TrackManagement
from pipeline.tracker.models import Models
from pipeline.tracker.run import track
from pipeline.tracker.updates import COLUMNS, confirmed_associations, positions

log = logging.getLogger("pipeline")

DRAW_FOLDER = "pipeline-draw"  # the prefix of a draw's temporary split in the system's temporary folder
PLOTS_REFERENCE = "plots"     # the target's raw plots with the true association (not a tracker)
PLOTS_REFERENCE_COST = 0.03   # its relative cost (see registry.Method.relative_cost)
SPEED = "plots_per_second"    # the one metric that is a timing, not a result


@dataclass
class Scenario:
    scenario_id: int
    plots: Plots                  # the scenario's plots, time order
    is_target: dict[int, bool]    # plot id -> whether the plot is the target's
    truth: object                 # t -> ECEF positions (a spline over the route)
    scans: np.ndarray             # each plot's antenna scan
    coverage_scans: np.ndarray    # the scans in which the target was in radar coverage
    strategy: str                 # the route's strategy (routes.STRATEGIES), for metrics by kind of flight
    draw: int = 0                 # its draw of noise, detections and clutter (0: the simulate stage's plots)
    surveillance: scorecard.Truth | None = None  # the target at every scan, what the scorecard reads (None: none)


def surveillance_truth(truth: pa.Table, rows: np.ndarray) -> scorecard.Truth:
    """The scorecard's truth (`scorecard.Truth`) of the `rows` (bool or indices) of a simulator's truth table
    (`simulate.TRUTH_SCHEMA`): each aircraft's true position at every scan, in coverage or not."""
    position = np.stack([truth.column(f"{axis}_ecef_m").to_numpy()[rows] for axis in "xyz"], axis=1)
    return scorecard.Truth(truth.column("target_id").to_numpy()[rows].astype(np.int64),
                           truth.column("time_unix_s").to_numpy()[rows], position,
                           truth.column("in_coverage").to_numpy(zero_copy_only=False)[rows])


def split_bounds(params: Params, simulated_dir: Path, models_dir: Path) -> dict[str, float]:
    """The limit beside the scorecard's position RMS on the evaluated split as the simulate stage (or a site)
    wrote it under `simulated_dir`: the PCRB's horizontal RMS (m) over every in-coverage scan of its routes
    (`pcrb.horizontal_rms`: params' radar, the simulator's detection probabilities) under each tuned model of
    `pcrb.MODELS` (`models_dir/kalman_tuned.json`), by model. The further draws have the same routes and
    detection probabilities, so the simulate stage's draw gives the bound of them all."""
    truth = io.read_parquet(simulated_dir / params.evaluate.split / "truth.parquet", simulate.TRUTH_SCHEMA)
    scenario = truth.column("scenario_id").to_numpy()
    detection = truth.column("detection_probability").to_numpy()
    items = [(surveillance_truth(truth, scenario == s), detection[scenario == s], params.radar)
             for s in np.unique(scenario).tolist()]
    tuned = classical_filters.load_settings(models_dir / "kalman_tuned.json")
    return {kind: pcrb.horizontal_rms(items, tuned[kind]) for kind in pcrb.MODELS}


def card_parts(params: Params, updates: dict[str, np.ndarray], confirmed: np.ndarray, truth: scorecard.Truth,
               update_interval_s: float | None = None) -> scorecard.Parts:
    """The scorecard's parts (`scorecard.parts`, params' `scorecard`) of one unit's updates (an update table's
    track ids, times, positions, and `velocity` where recorded), those `confirmed` (U,) bool scored, against
    `truth`; the update interval `update_interval_s`, default params' radar's scan period."""
    interval = update_interval_s if update_interval_s is not None else 60.0 / params.radar.rotation_rpm
    velocity = updates.get("velocity", np.full((len(confirmed), 3), np.nan))
    return scorecard.parts(scorecard.TrackUpdates(updates["track_id"], updates["time_unix_s"], positions(updates),
                                                  velocity, confirmed),
                           truth, scorecard.Settings.from_params(interval, params.scorecard))


def load_scenarios(plots: Plots, plot_scans: dict[int, int], route_table: pa.Table, truth_table: pa.Table
                   ) -> list[Scenario]:
    """The scenarios of a split: its plots (`plot_table`), each plot's scan by plot id, its routes and truth."""
    scenarios = []
    route_ids = route_table.column("route_id").to_numpy()
    truth_scenarios = truth_table.column("scenario_id").to_numpy()
    truth_scans = truth_table.column("scan").to_numpy()
    in_coverage = truth_table.column("in_coverage").to_numpy(zero_copy_only=False)
    for scenario_id, part in plots.scenarios():
        route = route_table.filter(pa.array(route_ids == scenario_id))
        trajectory = simulate.trajectory_of({name: route.column(name).to_numpy() for name in simulate.ROUTE_COLUMNS})
        scenarios.append(Scenario(scenario_id, part, dict(zip(part.plot_id.tolist(),
                                                                (part.target_id != NO_TARGET).tolist())),
                                  _clipped(trajectory), np.array([plot_scans[p] for p in part.plot_id.tolist()]),
                                  np.unique(truth_scans[(truth_scenarios == scenario_id) & in_coverage]),
                                  str(route.column("strategy")[0].as_py()),
                                  surveillance=surveillance_truth(truth_table, truth_scenarios == scenario_id)))
    return scenarios


def read_scenarios(params: Params, simulated_dir: Path, routes_dir: Path) -> list[Scenario]:
    """The evaluated split's scenarios, from the simulate and routes stages' files."""
    split = params.evaluate.split
    plots_path = simulated_dir / split / "plots.parquet"
    table = io.read_parquet(plots_path, simulate.PLOT_SCHEMA)  # the simulated schema: scans, truth
    plots = plot_table.read_parquet_plots(plots_path, simulated_dir / split / "radar.parquet", params.radar)
    return load_scenarios(plots, dict(zip(table.column("plot_id").to_numpy().tolist(),
                                          table.column("scan").to_numpy().tolist())),
                          io.read_parquet(routes_dir / f"{split}.parquet", routes.ROUTE_SCHEMA),
                          io.read_parquet(simulated_dir / split / "truth.parquet", simulate.TRUTH_SCHEMA))


def draw_seed(simulate_seed: int, draw: int) -> int:
    """The radar's seed of draw `draw`: the simulate stage's own for draw 0, else one from (simulate seed, draw)."""
    if draw == 0:
        return simulate_seed
    return int(np.random.SeedSequence([simulate_seed, draw]).generate_state(1)[0])


def drawn_scenarios(params: Params, routes_dir: Path, draw: int) -> list[Scenario]:
    """The evaluated split's scenarios simulated again with the seed of `draw` (> 0): the same routes,
    manoeuvres and times, fresh noise, detections and clutter. Made where it is needed (each worker
    makes its own, the same bytes: a cluster needs no shared temporary files), in a temporary folder
    laid out as the stages lay theirs out, read back as the simulate stage's plots are."""
    drawn = dataclasses.replace(params, simulate_seed=draw_seed(params.simulate_seed, draw))
    split = params.routes.split(params.evaluate.split)
    route_table = io.read_parquet(routes_dir / f"{split.name}.parquet", routes.ROUTE_SCHEMA)
    plots, truth = simulate.simulate_split(drawn, split, route_table)
    with io.temporary_folder(DRAW_FOLDER) as folder:
        simulate.write_split(plots, truth, simulate.radar_description(drawn), folder / split.name)
        scenarios = read_scenarios(params, folder, routes_dir)
    return [dataclasses.replace(scenario, draw=draw) for scenario in scenarios]


def _clipped(trajectory: object) -> object:
    """The route's position at any time, held at its ends outside it."""
    start, end = trajectory.x[0], trajectory.x[-1]
    return lambda t: trajectory(np.clip(t, start, end))


def reference_updates(scenario: Scenario, method: str, models: Models, params: Params, records_velocity: bool = False
                      ) -> dict[str, np.ndarray]:
    """The references' updates, from the target's plots only: `plots` takes each plot as the
    estimate of one always-confirmed track; a registered reference (the oracle) runs its tracker on them,
    its updates with their `velocity` where `records_velocity`."""
    target = scenario.plots.take(scenario.plots.target_id != NO_TARGET)
    if method != PLOTS_REFERENCE:
        return track(target, dataclasses.replace(registry.compose(method, models, params.tracker, 0.0,
                                                                  params.tracker.seed),
                                                 records_velocity=records_velocity))
    count = len(target)
    values = {"track_id": np.zeros(count, np.int64), "time_unix_s": target.time, "plot_id": target.plot_id,
              "radar_id": target.radar_id, "x_ecef_m": target.position[:, 0], "y_ecef_m": target.position[:, 1],
              "z_ecef_m": target.position[:, 2],
              "weight": np.full(count, params.tracker.management.weight_confirmed),
              "association": np.array(["truth"] * count), "association_error": np.zeros(count),
              "position_covariance": target.covariance}
    return {name: values[name] for name in COLUMNS}


def tracker_seed(params: Params, scenario: object) -> list[int]:
    """The seed of a run's random draws (MIA's samples, the LSTM update's dropout masks) on `scenario`
    (a Scenario or a Scene): (tracker seed, scenario id), and its draw beyond the first."""
    draw = getattr(scenario, "draw", 0)
    return [params.tracker.seed, scenario.scenario_id, *([draw] if draw else [])]


def tracker_runs(params: Params, models: Models, records_velocity: bool = False) -> dict[Run, callable]:
    """Every run of params, and the references (`runs.evaluated`), as run -> track(scenario); a method's
    updates with their `velocity` where `records_velocity` (the scorecard's velocity errors read it)."""
    def method_run(run: Run) -> callable:
        return lambda scenario: track(scenario.plots, dataclasses.replace(registry.compose(
            run.method, models, params.tracker, run.window_m, tracker_seed(params, scenario), run.management),
            records_velocity=records_velocity))

    def reference_run(run: Run) -> callable:
        return lambda scenario: reference_updates(scenario, run.method, models, params, records_velocity)

    return {run: reference_run(run) if run.reference else method_run(run) for run in evaluated(params.evaluate)}


def run_rule(params: Params, run: Run) -> TrackManagement:
    """The track management rule `run` is tracked and scored under: the one it names, else the tracker's
    (`tracker.management.rule`, every reference's)."""
    return registry.management(run.management or params.tracker.management.rule, params.tracker)


@dataclass
class UnitResult:
    """What tracking one scenario with one run contributes to the run's metrics."""

    counts: RouteCounts
    scan_ospa: np.ndarray                  # OSPA (m) of each scan of the scenario
    scan_gospa: np.ndarray                 # (S, 3) m: each scan's GOSPA in its localisation, missed and false shares
    track_switches: int                    # of the target (`pipeline.bench.gospa.track_switches`)
    tracks_per_truth: np.ndarray           # (1,) when the target is in coverage at some scan, else (0,)
    track_purity: np.ndarray               # of each confirmed track ever assigned to the target
    nees: np.ndarray                       # NEES of each confirmed target update (NaN without covariances)
    seconds: float                         # tracking time alone
    updates: dict[str, np.ndarray] | None  # the updates, kept only where a picture needs them
    card: scorecard.Parts | None = None    # the surveillance scorecard's parts (scenarios with `surveillance` truth)


@dataclass
class Evaluation:
    """What every unit reads: the params, the test scenarios, and each run as run -> track(scenario);
    and the folders they come from (simulated data, routes, models), for worker processes to load
    their own copy."""

    params: Params
    folders: tuple[Path, Path, Path]
    scenarios: list[Scenario]
    runs: dict[Run, Callable[[Scenario], dict[str, np.ndarray]]]


def prepare(params: Params, simulated_dir: Path, routes_dir: Path, models_dir: Path) -> Evaluation:
    """The scenarios of the evaluated split, the simulate stage's and those of every further draw of
    `evaluate.seeds` (`drawn_scenarios`), draw by draw, and every run, with what the runs need loaded (and
    checked against params)."""
    models = load_models(models_dir, params, [run.method for run in params.evaluate.runs]
                         + [name for name in params.evaluate.references if name in registry.REFERENCES],
                         [None, *(run.management for run in params.evaluate.runs)])
    scenarios = read_scenarios(params, simulated_dir, routes_dir)
    for draw in range(1, params.evaluate.seeds):
        scenarios += drawn_scenarios(params, routes_dir, draw)
    return Evaluation(params, (simulated_dir, routes_dir, models_dir), scenarios,
                      tracker_runs(params, models, records_velocity=True))


def evaluate_unit(evaluation: Evaluation, run: Run, index: int) -> UnitResult:
    """Track scenario `index` (position in `evaluation.scenarios`) with `run`, and score it."""
    params, scenario = evaluation.params, evaluation.scenarios[index]
    management = run_rule(params, run)
    start = time.perf_counter()
    updates = evaluation.runs[run](scenario)
    seconds = time.perf_counter() - start
    scan_of_plot = dict(zip(scenario.plots.plot_id.tolist(), scenario.scans.tolist()))
    update_scans = np.array([scan_of_plot[int(p)] for p in updates["plot_id"]], dtype=np.int64)
    scans = np.unique(scenario.scans)
    scan_ospa = ospa.scan_ospa(updates, update_scans, management, scenario.coverage_scans, scans, scenario.truth,
                               params.evaluate.ospa_cutoff_m, params.evaluate.ospa_order)
    scored = target_gospa(scenario, ospa.scan_estimates(updates, update_scans, management), scans,
                          params.evaluate.gospa_cutoff_m, params.evaluate.gospa_order)
    truths = np.zeros(int(np.isin(scans, scenario.coverage_scans).any()), dtype=np.int64)
    pictured = run.name == params.evaluate.example_run and index < params.evaluate.example_scenarios
    card = None if scenario.surveillance is None else card_parts(
        params, updates, confirmed_associations(updates, management), scenario.surveillance)
    return UnitResult(route_counts(updates, scenario.is_target, scenario.truth, management), scan_ospa,
                      gospa.shares_in_metres(scored.parts, params.evaluate.gospa_order),
                      int(gospa.track_switches(scored.truth, scored.scan, scored.track, truths).sum()),
                      gospa.tracks_per_truth(scored.truth, scored.track, truths),
                      gospa.track_purity(scored.truth, scored.track),
                      confirmed_nees(updates, scenario.is_target, scenario.truth, management), seconds,
                      updates if pictured else None, card)


def target_gospa(scenario: Scenario, estimates: ospa.ScanEstimates, scans: np.ndarray, cutoff: float, order: float
                 ) -> gospa.ScanGospa:
    """GOSPA at each of `scans` of a single-target scenario, on OSPA's sets (`pipeline.bench.ospa`): the
    target (truth id 0) where it is in coverage, each confirmed track's last estimate in the scan,
    each compared with the true position at its own time."""
    errors = np.linalg.norm(estimates.position - scenario.truth(estimates.time), axis=1) if len(estimates.time) \
        else np.empty(0)
    present = scans[np.isin(scans, scenario.coverage_scans)]
    return gospa.scan_gospa(scans, present, np.zeros(len(present), dtype=np.int64), estimates.scan, estimates.track,
                            lambda truths, tracks: np.broadcast_to(errors[tracks], (len(truths), len(tracks))),
                            cutoff, order, keep_pairs=True)  # switches counted as for the scenes


def run_metrics(results: list[UnitResult], plots: int) -> dict[str, float]:
    """A run's metrics from its units in scenario order; `plots` is the number of plots of all
    scenarios, and the speed counts the tracking time alone, summed over the units. GOSPA and its
    parts (m) are means over all scans, the parts each scan's shares (`pipeline.bench.gospa`), so they add
    up to GOSPA; track switches are summed over the routes, tracks per truth averaged over the
    routes whose target was in coverage, purity over the confirmed tracks ever assigned to a target; the
    scorecard's indicators (`scorecard.combined`, the scenarios pooled) where every unit has them, but its
    `tracks_per_aircraft`: the name is the continuity metric's (`tracker_metrics.summarise`: routes the radar
    saw, a route never tracked counting 0), kept as the comparison has always read it."""
    nees = np.concatenate([r.nees for r in results])
    per_scan = np.concatenate([r.scan_ospa for r in results])
    shares = np.concatenate([r.scan_gospa for r in results])
    per_truth = np.concatenate([r.tracks_per_truth for r in results])
    purity = np.concatenate([r.track_purity for r in results])
    seconds = sum(r.seconds for r in results)
    card = scorecard.combined([r.card for r in results]) if all(r.card is not None for r in results) else {}
    return {**card, **summarise([r.counts for r in results]), "OSPA": float(per_scan.mean()),
            "OSPA_p90": float(np.percentile(per_scan, 90)), "GOSPA": float(shares.sum(axis=1).mean()),
            **{f"GOSPA_{part}": float(value) for part, value in zip(gospa.PARTS, shares.mean(axis=0))},
            "track_switches": sum(r.track_switches for r in results),
            "tracks_per_truth": float(per_truth.mean()) if len(per_truth) else float("nan"),
            "track_purity": float(purity.mean()) if len(purity) else float("nan"),
            "ANEES": float(nees.mean()) if len(nees) and np.isfinite(nees).all() else float("nan"),
            SPEED: plots / seconds if seconds else float("nan")}


COUNTS = ("NOFPA", "NOPA", "target_plots", "false_plots", "track_switches", *scorecard.COUNTS)  # sums over them


def per_draw(metrics: dict[str, float], draws: int) -> dict[str, float]:
    """A run's metrics over `draws` draws of every scenario (or scene) with its counts (COUNTS, the scorecard's
    included) as means per draw, so that they stay those of one test split (or set of scenes), the thesis's
    tables' scale; ratios and means need nothing."""
    if draws == 1:
        return metrics
    return {name: value / draws if name in COUNTS else value for name, value in metrics.items()}


def draws_of(scenarios: list[Scenario]) -> int:
    """The number of draws the scenarios hold (`evaluate.seeds`, or fewer for a list cut short)."""
    return len({scenario.draw for scenario in scenarios})


def relative_cost(run: Run, scenario: Scenario) -> float:
    """Rough tracking time of one unit (`run`, one scenario), to hand out the largest first."""
    method = run.registered
    return (PLOTS_REFERENCE_COST if method is None else method.relative_cost) * len(scenario.plots)


def metrics_by_strategy(scenarios: list[Scenario], ordered: list[UnitResult]) -> dict[str, dict[str, float]]:
    """A run's metrics (without its speed) over the scenarios of each route strategy, by strategy
    in the order of routes.STRATEGIES: how it fares on straight legs, short turns, long turns and
    climbs, apart."""
    by_strategy = {}
    for strategy in routes.STRATEGIES:
        chosen = [i for i, scenario in enumerate(scenarios) if scenario.strategy == strategy]
        if chosen:
            values = per_draw(run_metrics([ordered[i] for i in chosen], sum(len(scenarios[i].plots) for i in chosen)),
                              draws_of(scenarios))
            by_strategy[strategy] = {key: value for key, value in values.items() if key != SPEED}
    return by_strategy


PAIRED = ("OSPA", "GOSPA", "ROCA", "MAE", "tracks_per_aircraft", "false_tracks",  # the metrics the comparison's
          "initiation_mean_s")                                                    # verdicts compare
CONSTANT = ("target_plots", "false_plots", SPEED)  # the same on every resample, or a timing: no interval


def metric_intervals(params: Params, scenarios: list[Scenario], units: dict[Run, list[UnitResult]]) -> dict:
    """The 95 % (`evaluate.confidence`) intervals of every run's metrics and, for the metrics of PAIRED, of
    the difference of every pair of runs (`intervals.run_intervals`, over the `scenarios`, a route's draws
    resampled together), by run name."""
    chosen = params.evaluate
    first = next(iter(units.values()))
    names = [name for name in run_metrics(first, 0) if name not in CONSTANT]
    draws = draws_of(scenarios)
    return intervals.run_intervals({run.name: results for run, results in units.items()},
                                   lambda results: per_draw(run_metrics(results, 0), draws), names,
                                   [name for name in PAIRED if name in names],
                                   chosen.bootstrap_replicates, chosen.confidence, chosen.bootstrap_seed,
                                   [scenario.scenario_id for scenario in scenarios])


def evaluate_all(evaluation: Evaluation, workers: int, label: str = "evaluate"
                 ) -> tuple[dict[Run, dict], dict[Run, np.ndarray], dict[int, dict], dict[Run, dict],
                            dict[Run, list[UnitResult]]]:
    """Every run over every scenario, on `workers` workers (`engine.completed_units`): each run's metrics, the OSPA of
    every scan (scenarios in order), the example run's updates of the pictured scenarios by
    scenario id, each run's metrics by route strategy (`metrics_by_strategy`), and each run's unit
    results in scenario order (for `metric_intervals`), by run in `evaluation.runs` order. Each run's
    metrics are logged, after `label`, as soon as its last unit is in."""
    scenarios = evaluation.scenarios
    plots = sum(len(s.plots) for s in scenarios)
    units = sorted(((run, index) for run in evaluation.runs for index in range(len(scenarios))),
                   key=lambda unit: -relative_cost(unit[0], scenarios[unit[1]]))
    workers = max(1, min(workers, len(units)))
    parts: dict[Run, dict[int, UnitResult]] = {run: {} for run in evaluation.runs}
    results, per_scan, examples, by_strategy, units_by_run = {}, {}, {}, {}, {}
    report = progress_logger(f"{label} ({engine.where(workers)})")
    for done, ((run, index), result) in enumerate(engine.completed_units(
            units, workers, evaluate_unit, evaluation, prepare, (evaluation.params, *evaluation.folders)), start=1):
        parts[run][index] = result
        report(done, len(units))
        if len(parts[run]) == len(scenarios):
            finished = parts.pop(run)
            ordered = units_by_run[run] = [finished[i] for i in range(len(scenarios))]
            results[run] = per_draw(run_metrics(ordered, plots), draws_of(scenarios))
            by_strategy[run] = metrics_by_strategy(scenarios, ordered)
            per_scan[run] = np.concatenate([r.scan_ospa for r in ordered])
            examples.update({scenarios[i].scenario_id: r.updates for i, r in enumerate(ordered)
                             if r.updates is not None})
            log.info("%s %s: %s", label, run.name, ", ".join(f"{k} {v:.4g}" for k, v in results[run].items()))
    return ({run: results[run] for run in evaluation.runs}, {run: per_scan[run] for run in evaluation.runs},
            examples, {run: by_strategy[run] for run in evaluation.runs}, {run: units_by_run[run] for run in evaluation.runs})

"""Evaluate trackers on the multi-target scenes (`pipeline.simulation.scenes`): one unit per (run, scene),
run on the bench's engine (`pipeline.bench.engine`) as `pipeline.bench.evaluation` runs its (run, scenario) units.

Each scene is one radar recording tracked whole: all its aircraft and its clutter at once. The
runs are those of `evaluate.scene_runs` (`Evaluate.runs_on_scenes`) and the registered
references of `evaluate.references` (the oracle, the tuned IMM given each plot's aircraft; the
`plots` reference is one track per scenario, a single-target idea, and is left out).

Scoring, per scan of a scene (`pipeline.bench.gospa`, on OSPA's estimate sets, `ospa.scan_estimates`):
the truths are the aircraft the simulator had in radar coverage at that scan; the estimates are
the confirmed tracks updated in the scan, each at its last update there, compared with every
truth's position at that update's time. Per run, over all scans of all scenes:

- GOSPA (alpha = 2, cutoff and order `evaluate.gospa_cutoff_m`, `gospa_order`) and its
  localisation, missed and false parts, in metres, each scan's GOSPA split in proportion to its
  parts (`gospa.shares_in_metres`), so the three add up to GOSPA; means over the scans;
- track switches, summed over the aircraft of all scenes (`gospa.track_switches`), on the kept
  pairs (`gospa.kept_pairs`: an aircraft keeps its track while that stays within the cutoff, so
  two aircraft crossing within the estimates' errors cost no switch unless a track changes
  aircraft); tracks per truth, fragmentation and purity read the same pairs;
- tracks per truth, the distinct confirmed tracks ever assigned to an aircraft in coverage at
  some scan, averaged over those aircraft; and fragmentation, the tracks assigned beyond the
  first, max(tracks per truth - 1, 0), averaged over the same aircraft: the extra pieces an
  aircraft's track falls into (0 for one track all along, and for an aircraft never tracked,
  which the missed part counts);
- track purity, per confirmed track ever assigned, averaged over those tracks;
- GOSPA's missed part split by why each missed aircraft-scan was missed (`missed_causes`: no plot of it,
  before its first track, after a track) and its false part by what each unassigned estimate is
  (`false_causes`: a clutter track, a second track of an aircraft, a track astray from its aircraft), issue 34;
- the surveillance scorecard (`pipeline.surveillance.scorecard`, params' `scorecard`, the update interval the
  radar's scan period) against every aircraft's true position at every scan (`Scene.surveillance`), issue 32;
- speed, the scenes' plots over the tracking time alone (one core).

With `evaluate.seeds` > 1 every scene is tracked again on further draws of the radar's noise,
detections and clutter (`drawn_scenes`): the metrics are over all draws, track switches a mean per
draw, and the intervals (`metric_intervals`) resample the scenes, each with all its draws.

Results are put together by run and scene, never in the order the units finish: the metrics but
the speeds are the same whatever the number of workers.
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
from pipeline.bench import engine, evaluation, gospa, intervals, ospa
from pipeline.bench.evaluation import DRAW_FOLDER, draw_seed, per_draw
from pipeline.bench.runs import Run
from pipeline.params import Params
from pipeline.progress import progress_logger
from pipeline.recordings import plot_table
from pipeline.recordings.plot_table import Plots
from pipeline.simulation import scenes, simulate
from pipeline.surveillance import scorecard
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.management import TrackManagement
from pipeline.tracker.updates import confirmed_associations

log = logging.getLogger("pipeline")

SPEED = evaluation.SPEED


@dataclass
class Scene:
    """One scene as the trackers and the scoring see it. `scenario_id` is the scene's id (the plots'
    scenario_id), named as a single-target scenario's so the runs of `evaluation.tracker_runs`
    (which seed MIA by it) track a scene as they track a scenario."""

    scenario_id: int
    plots: Plots                   # the scene's plots, time order
    scans: np.ndarray              # (P,) each plot's antenna scan
    all_scans: np.ndarray          # (S,) every scan of the scene, sorted
    truth_scan: np.ndarray         # (N,) the scan of each (aircraft, scan) in coverage, sorted by scan
    truth_id: np.ndarray           # (N,) its aircraft's id
    trajectories: dict[int, Callable[[np.ndarray], np.ndarray]]  # aircraft id -> t (s) -> (len(t), 3) m ECEF
    roles: dict[int, str]          # aircraft id -> its role in the scene (scenes.CROSSING ... or a strategy)
    draw: int = 0                  # its draw of noise, detections and clutter (0: the scenes stage's plots)
    surveillance: scorecard.Truth | None = None  # every truth row, what the scorecard reads (None: no scorecard)


def clipped(route: dict[str, np.ndarray]) -> Callable[[np.ndarray], np.ndarray]:
    """The aircraft's true ECEF position at any time, held at its route's ends outside it."""
    trajectory = simulate.trajectory_of(route)
    start, end = trajectory.x[0], trajectory.x[-1]
    return lambda t: trajectory(np.clip(t, start, end))


def read_scenes(params: Params, scenes_dir: Path) -> list[Scene]:
    """The scenes the `scenes` stage wrote to `scenes_dir` (routes, plots, truth, radar)."""
    table = io.read_parquet(scenes_dir / "plots.parquet", simulate.PLOT_SCHEMA)
    plots = plot_table.read_parquet_plots(scenes_dir / "plots.parquet", scenes_dir / "radar.parquet", params.radar)
    scan_of_plot = dict(zip(table.column("plot_id").to_numpy().tolist(), table.column("scan").to_numpy().tolist()))
    route_table = io.read_parquet(scenes_dir / "routes.parquet", scenes.SCENE_ROUTE_SCHEMA)
    truth = io.read_parquet(scenes_dir / "truth.parquet", simulate.TRUTH_SCHEMA)
    truth_scene = truth.column("scenario_id").to_numpy()
    truth_scan, truth_id = truth.column("scan").to_numpy(), truth.column("target_id").to_numpy()
    in_coverage = truth.column("in_coverage").to_numpy(zero_copy_only=False)
    route_scene = route_table.column("scene_id").to_numpy()
    loaded = []
    for scene_id, part in plots.scenarios():
        aircraft = simulate.routes_by_id(route_table.filter(pa.array(route_scene == scene_id)))
        roles = route_table.filter(pa.array(route_scene == scene_id)).select(["route_id", "strategy"]).to_pydict()
        mine = (truth_scene == scene_id) & in_coverage
        order = np.lexsort((truth_id[mine], truth_scan[mine]))
        scans = np.array([scan_of_plot[p] for p in part.plot_id.tolist()], dtype=np.int64)
        loaded.append(Scene(scene_id, part, scans, np.unique(np.concatenate([scans, truth_scan[mine]])),
                            truth_scan[mine][order], truth_id[mine][order],
                            {int(route["route_id"][0]): clipped(route) for route in aircraft},
                            dict(zip(roles["route_id"], roles["strategy"])),
                            surveillance=evaluation.surveillance_truth(truth, truth_scene == scene_id)))
    return loaded


def drawn_scenes(params: Params, draw: int) -> list[Scene]:
    """The scenes simulated again with the radar seed of `draw` (> 0, `evaluation.draw_seed`): the same
    layouts, routes and times (planned from `scenes.seed`), fresh noise, detections and clutter; made
    where needed, in a temporary folder laid out as the scenes stage lays its out, and read back."""
    drawn = dataclasses.replace(params, simulate_seed=draw_seed(params.simulate_seed, draw))
    route_table, plots, truth = scenes.generate_scenes(drawn)
    with io.temporary_folder(DRAW_FOLDER) as folder:
        io.write_parquet(route_table, folder / "routes.parquet")
        simulate.write_split(plots, truth, simulate.radar_description(drawn), folder)
        return [dataclasses.replace(scene, draw=draw) for scene in read_scenes(params, folder)]


def scene_params(params: Params) -> Params:
    """Params whose evaluation runs are the scenes' (`evaluate.scene_runs`) and whose references are
    the registered ones (the oracle)."""
    chosen = params.evaluate
    return dataclasses.replace(params, evaluate=dataclasses.replace(
        chosen, runs=chosen.runs_on_scenes(),
        references=tuple(name for name in chosen.references if name in registry.REFERENCES)))


@dataclass
class SceneEvaluation:
    """What every unit reads: params (`scene_params`'), the scenes, each run as run -> track(scene)
    and its track management rule; and the folders (scenes, models) for worker processes to load
    their own copy."""

    params: Params
    folders: tuple[Path, Path]
    scenes: list[Scene]
    runs: dict[Run, Callable[[Scene], dict[str, np.ndarray]]]
    management: dict[Run, TrackManagement]


def prepare(params: Params, scenes_dir: Path, models_dir: Path) -> SceneEvaluation:
    """The scenes, the scenes stage's and those of every further draw of `evaluate.seeds` (`drawn_scenes`),
    and every run scored on them, with what the runs need loaded."""
    chosen = scene_params(params)
    models = load_models(models_dir, chosen, [run.method for run in chosen.evaluate.runs]
                         + list(chosen.evaluate.references), [None, *(run.management for run in chosen.evaluate.runs)])
    runs = evaluation.tracker_runs(chosen, models, records_velocity=True)  # the scorecard's velocity errors
    tracked = read_scenes(chosen, scenes_dir)
    for draw in range(1, chosen.evaluate.seeds):
        tracked += drawn_scenes(chosen, draw)
    return SceneEvaluation(chosen, (scenes_dir, models_dir), tracked, runs,
                           {run: evaluation.run_rule(chosen, run) for run in runs})


def scene_gospa(scene: Scene, estimates: ospa.ScanEstimates, cutoff: float, order: float) -> gospa.ScanGospa:
    """GOSPA at every scan of a scene: the aircraft in coverage against the confirmed tracks'
    estimates, each estimate compared with each aircraft's position at the estimate's time; the
    identity metrics read the kept pairs (`pipeline.bench.gospa`), so two aircraft passing within the
    estimates' errors of each other cost no switch while each keeps its track."""
    def distances(truth_rows: np.ndarray, track_rows: np.ndarray) -> np.ndarray:
        times, estimated = estimates.time[track_rows], estimates.position[track_rows]
        return np.stack([np.linalg.norm(estimated - scene.trajectories[int(aircraft)](times), axis=1)
                         for aircraft in scene.truth_id[truth_rows]])

    return gospa.scan_gospa(scene.all_scans, scene.truth_scan, scene.truth_id, estimates.scan, estimates.track,
                            distances, cutoff, order, keep_pairs=True)


@dataclass
class SceneResult:
    """What tracking one scene with one run contributes to the run's metrics."""

    scan_gospa: np.ndarray         # (S, 3) m: each scan's GOSPA in its localisation, missed and false shares
    track_switches: int            # summed over the scene's aircraft
    tracks_per_truth: np.ndarray   # (A,) of each aircraft in coverage at some scan
    track_purity: np.ndarray       # of each confirmed track ever assigned to an aircraft
    seconds: float                 # tracking time alone
    pictured: tuple[dict[str, np.ndarray], gospa.ScanGospa] | None  # updates and assignment, for the picture
    missed: np.ndarray | None = None  # (S, 3) m: each scan's missed share by cause (`missed_causes`)
    false: np.ndarray | None = None   # (S, 3) m: each scan's false share by cause (`false_causes`)
    card: scorecard.Parts | None = None  # the surveillance scorecard's parts (scenes with `surveillance` truth)


def evaluate_unit(evaluation: SceneEvaluation, run: Run, index: int, pictured: bool = False) -> SceneResult:
    """Track scene `index` (position in `evaluation.scenes`) with `run`, and score it; keep the
    updates and the assignment when the scene is `pictured`."""
    scene = evaluation.scenes[index]
    start = time.perf_counter()
    updates = evaluation.runs[run](scene)
    seconds = time.perf_counter() - start
    return scene_result(evaluation.params, scene, updates, confirmed_associations(updates, evaluation.management[run]),
                        seconds, pictured)


def scene_result(params: Params, scene: Scene, updates: dict[str, np.ndarray], confirmed: np.ndarray, seconds: float,
                 pictured: bool = False, update_interval_s: float | None = None) -> SceneResult:
    """Score a scene's updates (an update table's track ids, times, plot ids and positions, and `velocity` where
    recorded), those `confirmed` (U,) bool the estimates (see the module docstring), tracked in `seconds`: GOSPA
    with its missed and false parts split by cause, and, for a scene with `surveillance` truth, the scorecard's
    parts (params' `scorecard`, the update interval `update_interval_s`, default params' radar's scan period);
    keep the updates and the assignment when `pictured`."""
    scan_of_plot = dict(zip(scene.plots.plot_id.tolist(), scene.scans.tolist()))
    update_scans = np.array([scan_of_plot[int(p)] for p in updates["plot_id"]], dtype=np.int64)
    estimates = ospa.marked_estimates(updates, update_scans, confirmed)
    scored = scene_gospa(scene, estimates, params.evaluate.gospa_cutoff_m, params.evaluate.gospa_order)
    truths = np.unique(scene.truth_id)
    shares = gospa.shares_in_metres(scored.parts, params.evaluate.gospa_order)
    card = None if scene.surveillance is None else evaluation.card_parts(params, updates, confirmed,
                                                                         scene.surveillance, update_interval_s)
    return SceneResult(shares, int(gospa.track_switches(scored.truth, scored.scan, scored.track, truths).sum()),
                       gospa.tracks_per_truth(scored.truth, scored.track, truths),
                       gospa.track_purity(scored.truth, scored.track), seconds,
                       (updates, scored) if pictured else None, missed_causes(scene, scored, shares[:, 1]),
                       false_causes(scene, scored, estimates, _track_origins(scene, updates, confirmed), shares[:, 2]),
                       card)


MISSED_CAUSES = ("undetected", "initiation", "after_track")  # where a missed aircraft-scan is lost (`missed_causes`)
FALSE_CAUSES = ("clutter", "duplicate", "astray")  # what a false (unassigned) estimate is (`false_causes`)


def missed_causes(scene: Scene, scored: gospa.ScanGospa, missed_m: np.ndarray) -> np.ndarray:
    """Each scan's GOSPA missed share `missed_m` (S,) m split by why its aircraft were missed (S, 3) m, in the
    order of MISSED_CAUSES (issue 34): `undetected`, no plot of the aircraft in the scan; `initiation`, a plot but
    no track of the aircraft yet (the scans before its first pair: detections the track management has not yet
    confirmed); `after_track`, a plot, and the aircraft had a track before (the track lost, deleted, swapped away,
    or the plot refused by its gate). Every missed aircraft costs a scan's GOSPA the same (c^p / 2), so a scan's
    missed metres are split in proportion to the counts of its causes."""
    index = {int(scan): row for row, scan in enumerate(scene.all_scans.tolist())}
    paired = set(zip(scored.truth.tolist(), scored.scan.tolist()))
    first = {}
    for truth, scan in zip(scored.truth.tolist(), scored.scan.tolist()):
        first[truth] = min(scan, first.get(truth, scan))
    seen = scene.plots.target_id >= 0
    detected = set(zip(scene.plots.target_id[seen].tolist(), scene.scans[seen].tolist()))
    counts = np.zeros((len(scene.all_scans), len(MISSED_CAUSES)))
    for truth, scan in zip(scene.truth_id.tolist(), scene.truth_scan.tolist()):
        if (truth, scan) in paired:
            continue
        cause = 0 if (truth, scan) not in detected else 1 if scan < first.get(truth, np.inf) else 2
        counts[index[scan], cause] += 1
    total = counts.sum(axis=1, keepdims=True)
    return np.divide(counts * missed_m[:, None], total, out=np.zeros_like(counts), where=total > 0)


def _track_origins(scene: Scene, updates: dict[str, np.ndarray], confirmed: np.ndarray) -> dict[int, int]:
    """Each confirmed track's origin: the aircraft most of its confirmed updates' plots came from, or
    `plot_table.NO_TARGET` when most were false plots (ties to the lowest id)."""
    target_of = dict(zip(scene.plots.plot_id.tolist(), scene.plots.target_id.tolist()))
    tracks = updates["track_id"][confirmed]
    targets = np.array([target_of[int(p)] for p in updates["plot_id"][confirmed]], dtype=np.int64)
    origins = {}
    for track in np.unique(tracks).tolist():
        values, counts = np.unique(targets[tracks == track], return_counts=True)
        origins[int(track)] = int(values[np.argmax(counts)])
    return origins


def false_causes(scene: Scene, scored: gospa.ScanGospa, estimates: ospa.ScanEstimates, origins: dict[int, int],
                 false_m: np.ndarray) -> np.ndarray:
    """Each scan's GOSPA false share `false_m` (S,) m split by what its unassigned estimates are (S, 3) m, in
    the order of FALSE_CAUSES (issue 34): `clutter`, a track made mostly of false plots; `duplicate`, a track of
    an aircraft that another track holds in that scan (the aircraft tracked twice); `astray`, a track of an
    aircraft that no track holds in that scan (the track too far off its aircraft, or the aircraft out of
    coverage). A track's aircraft is its origin (`_track_origins`: the most of its confirmed updates' plots).
    Every unassigned estimate costs a scan's GOSPA the same (c^p / 2), so a scan's false metres are split in
    proportion to the counts of its causes."""
    index = {int(scan): row for row, scan in enumerate(scene.all_scans.tolist())}
    assigned = set(zip(scored.scan.tolist(), scored.track.tolist()))
    held = set(zip(scored.scan.tolist(), scored.truth.tolist()))
    counts = np.zeros((len(scene.all_scans), len(FALSE_CAUSES)))
    for scan, track in zip(estimates.scan.tolist(), estimates.track.tolist()):
        if (scan, track) in assigned:
            continue
        origin = origins.get(int(track), plot_table.NO_TARGET)
        cause = 0 if origin == plot_table.NO_TARGET else 1 if (scan, origin) in held else 2
        counts[index[scan], cause] += 1
    total = counts.sum(axis=1, keepdims=True)
    return np.divide(counts * false_m[:, None], total, out=np.zeros_like(counts), where=total > 0)


def run_metrics(results: list[SceneResult], plots: int) -> dict[str, float]:
    """A run's metrics from its units (see the module docstring); `plots` is the scenes' plots. GOSPA's missed and
    false parts by cause (`missed_causes`, `false_causes`), and the scorecard's indicators (`scorecard.combined`,
    the scenes pooled) where every unit has them."""
    shares = np.concatenate([r.scan_gospa for r in results])
    per_truth = np.concatenate([r.tracks_per_truth for r in results])
    purity = np.concatenate([r.track_purity for r in results])
    seconds = sum(r.seconds for r in results)
    metrics = {"GOSPA": float(shares.sum(axis=1).mean()),
               **{f"GOSPA_{part}": float(value) for part, value in zip(gospa.PARTS, shares.mean(axis=0))},
               "track_switches": sum(r.track_switches for r in results),
               "tracks_per_truth": float(per_truth.mean()) if len(per_truth) else float("nan"),
               "fragmentation": float(np.maximum(per_truth - 1, 0).mean()) if len(per_truth) else float("nan"),
               "track_purity": float(purity.mean()) if len(purity) else float("nan"),
               SPEED: plots / seconds if seconds else float("nan")}
    if all(r.missed is not None for r in results):
        missed = np.concatenate([r.missed for r in results])
        metrics.update({f"GOSPA_missed_{cause}": float(value) for cause, value in zip(MISSED_CAUSES, missed.mean(axis=0))})
    if all(r.false is not None for r in results):
        false = np.concatenate([r.false for r in results])
        metrics.update({f"GOSPA_false_{cause}": float(value) for cause, value in zip(FALSE_CAUSES, false.mean(axis=0))})
    if all(r.card is not None for r in results):
        metrics.update(scorecard.combined([r.card for r in results]))
    return metrics


PAIRED = ("GOSPA", "GOSPA_localisation", "GOSPA_missed", "GOSPA_false", "track_switches",  # the verdicts';
          "tracks_per_aircraft", "false_tracks", "initiation_mean_s")  # the scorecard's where the scenes have it


def metric_intervals(params: Params, tracked: list[Scene], units: dict[Run, list[SceneResult]]) -> dict:
    """The intervals of every run's metrics and of the differences of PAIRED between runs, over the scenes
    `tracked` (`intervals.run_intervals`, a scene's draws resampled together), by run name."""
    chosen = params.evaluate
    first = next(iter(units.values()))
    names = [name for name in run_metrics(first, 0) if name != SPEED]
    draws = len({scene.draw for scene in tracked})
    return intervals.run_intervals({run.name: results for run, results in units.items()},
                                   lambda results: per_draw(run_metrics(results, 0), draws), names,
                                   [name for name in PAIRED if name in names], chosen.bootstrap_replicates, chosen.confidence, chosen.bootstrap_seed,
                                   [scene.scenario_id for scene in tracked])


def evaluate_all(evaluation: SceneEvaluation, workers: int, example: tuple[Run, int]
                 ) -> tuple[dict[Run, dict], tuple[dict[str, np.ndarray], gospa.ScanGospa], dict[Run, list[SceneResult]]]:
    """Every run over every scene on `workers` workers (`engine.completed_units`): each run's metrics by run, in
    `evaluation.runs` order (logged as soon as its last unit is in), the updates and assignment of the `example`
    unit (run, scene index), and each run's unit results in scene order (for `metric_intervals`)."""
    tracked = evaluation.scenes
    plots = sum(len(scene.plots) for scene in tracked)

    def cost(unit: tuple[Run, int, bool]) -> float:
        return -unit[0].registered.relative_cost * len(tracked[unit[1]].plots)

    units = sorted(((run, index, (run, index) == example) for run in evaluation.runs
                    for index in range(len(tracked))), key=cost)
    workers = max(1, min(workers, len(units)))
    parts: dict[Run, dict[int, SceneResult]] = {run: {} for run in evaluation.runs}
    results, pictured, units_by_run = {}, None, {}
    report = progress_logger(f"evaluate_scenes ({engine.where(workers)})")
    for done, ((run, index, _), result) in enumerate(engine.completed_units(
            units, workers, evaluate_unit, evaluation, prepare, (evaluation.params, *evaluation.folders)), start=1):
        parts[run][index] = result
        pictured = result.pictured or pictured
        report(done, len(units))
        if len(parts[run]) == len(tracked):
            finished = parts.pop(run)
            units_by_run[run] = [finished[i] for i in range(len(tracked))]
            results[run] = per_draw(run_metrics(units_by_run[run], plots), len({scene.draw for scene in tracked}))
            log.info("evaluate_scenes %s: %s", run.name, ", ".join(f"{k} {v:.4g}" for k, v in results[run].items()))
    return {run: results[run] for run in evaluation.runs}, pictured, {run: units_by_run[run] for run in evaluation.runs}

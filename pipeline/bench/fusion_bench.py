"""The fusion stage's work as units of the bench's engine (issue 30): a unit is one scene seen by both radars.

A unit (`scene_unit`) simulates the scene for each radar of `fusion.radars`, tracks each radar's plots alone
(`radar_fusion.radar_tracks`: the track tables handed on in memory, no Parquet round trip), scores every
picture and association method on it (`radar_fusion.scene_scores`) and, for the first `fusion.sweep_scenes`
scenes, counts every method's pairs against radar 2's registration bias (`fusion_bias_sweep.scene_counts`),
reusing radar 1's tracks, which the sweep's radar 1 (`fusion.radars[0]` as it is) would make again. The
units run on `engine.completed_units` (`compute.workers` processes, or a Dask scheduler named by
`DASK_SCHEDULER_ADDRESS`), each worker loading the association network once per call (`prepare`), and are
merged in scene order, so `reports/fusion.json` is the same bytes with any number of workers.

The scenes are also the units of the intervals (`fusion_intervals`): every picture's GOSPA and every method's
association accuracy recomputed on the bootstrap's resamples of the scenes (`intervals.run_intervals`, paired:
every picture and method is scored on the same scenes), so a fused picture's lead over another, or over the
better radar alone, is told from the noise of which scenes were drawn.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pipeline.association import association_net, registry
from pipeline.bench import engine, fusion_bias_sweep, intervals, radar_fusion
from pipeline.params import Params
from pipeline.progress import progress_logger
from pipeline.simulation import scenes
from pipeline.surveillance import scorecard

log = logging.getLogger("pipeline")
CARD_PAIRED = ("position_rms_m", "probability_of_update", "ratio_of_long_gaps")  # the scorecard's paired differences


class FusionBench(NamedTuple):
    """What a worker needs for the fusion units: the params, the models folder (the local tracker's tuned
    filters) and the association network (None when `fusion.methods` does not list network)."""

    params: Params
    models_dir: Path
    model: association_net.AssociationNet | None


class SceneResult(NamedTuple):
    """One scene's pictures' scores and pair counts (`radar_fusion.scene_scores`), and its bias sweep's
    counts (biases, methods, 4) (`fusion_bias_sweep.scene_counts`), None past `fusion.sweep_scenes`."""

    pictures: dict[str, radar_fusion.PictureScore]
    counts: dict[str, np.ndarray]
    sweep: np.ndarray | None


def prepare(params: Params, models_dir: Path) -> FusionBench:
    """The units' state: the association network loaded from `models_dir/association_net.pt` when a method
    needs it (`registry.needs_network`)."""
    model = (association_net.load(models_dir / "association_net.pt") if registry.needs_network(params.fusion.methods)
             else None)
    return FusionBench(params, models_dir, model)


def scene_unit(bench: FusionBench, scene_id: int) -> SceneResult:
    """Scene `scene_id` seen by both radars, scored (module docstring)."""
    params = bench.params
    routes = scenes.scene_routes(params, scene_id, scenes.plan_scene(params, scene_id))
    tracked = [radar_fusion.radar_tracks(params, radar, scene_id, routes, bench.models_dir)
               for radar in params.fusion.radars]
    pictures, counts = radar_fusion.scene_scores(params, scene_id, routes, tracked, bench.model)
    sweep = (fusion_bias_sweep.scene_counts(params, scene_id, routes, tracked[0], bench.models_dir, bench.model)
             if scene_id < params.fusion.sweep_scenes else None)
    return SceneResult(pictures, counts, sweep)


def _mean_gospa(units: list[tuple[float, int]]) -> dict[str, float]:
    """A picture's GOSPA (m) per common time over scenes' (GOSPA summed over common times, common times), as
    `radar_fusion.fusion_report` means it."""
    return {"GOSPA": sum(total for total, _ in units) / max(sum(times for _, times in units), 1)}


def _accuracy(units: list[tuple[int, int]]) -> dict[str, float]:
    """A method's association accuracy over scenes' (correct pairs, oracle pairs)."""
    return {"accuracy": sum(correct for correct, _ in units) / max(sum(oracle for _, oracle in units), 1)}


def fusion_intervals(params: Params, scored: list[SceneResult]) -> dict:
    """reports/fusion_intervals.json: the `evaluate.confidence` intervals (`evaluate.bootstrap_replicates`
    resamples of the scenes, seed `evaluate.bootstrap_seed`) of every picture's GOSPA, its scorecard's
    indicators and every method's association accuracy, and of their paired differences (`intervals.run_intervals`;
    of the scorecard, CARD_PAIRED's), from every scene's result in scene order: {"pictures": ..., "association":
    ..., "scorecard": ...}."""
    chosen = params.evaluate
    pictures = {name: [(result.pictures[name].gospa_sum, int(result.counts["times"])) for result in scored]
                for name in scored[0].pictures}
    methods = {method: [(int(result.counts[f"pairs_{method}"][0]), int(result.counts["oracle_pairs"]))
                        for result in scored] for method in params.fusion.methods}
    cards = {name: [result.pictures[name].card for result in scored] for name in scored[0].pictures}
    settings = (chosen.bootstrap_replicates, chosen.confidence, chosen.bootstrap_seed)
    return {"pictures": intervals.run_intervals(pictures, _mean_gospa, ["GOSPA"], ["GOSPA"], *settings),
            "association": intervals.run_intervals(methods, _accuracy, ["accuracy"], ["accuracy"], *settings),
            "scorecard": intervals.run_intervals(cards, scorecard.combined, scorecard.INDICATORS, CARD_PAIRED,
                                                 *settings)}


def fusion_reports(params: Params, models_dir: Path, workers: int) -> tuple[dict, dict]:
    """reports/fusion.json (`radar_fusion.fusion_report`, its bias sweep under "bias_sweep",
    `fusion_bias_sweep.sweep_report`) and reports/fusion_intervals.json (`fusion_intervals`) from the first
    `fusion.scenes` scenes on `workers` workers. Raises `engine.SchedulerUnreachable` and what a unit raised."""
    units = [(scene_id,) for scene_id in range(params.fusion.scenes)]
    workers = max(1, min(workers, len(units)))
    report = progress_logger(f"fusion scenes ({engine.where(workers)})")
    state = prepare(params, models_dir) if workers == 1 and engine.scheduler_address() is None else None
    results: dict[int, SceneResult] = {}
    for done, ((scene_id,), result) in enumerate(engine.completed_units(
            units, workers, scene_unit, state, prepare, (params, models_dir)), start=1):
        results[scene_id] = result
        report(done, len(units))
    ordered = [results[scene_id] for scene_id in range(params.fusion.scenes)]
    fused = radar_fusion.fusion_report(params, [(result.pictures, result.counts) for result in ordered])
    fused["bias_sweep"] = fusion_bias_sweep.sweep_report(params, [result.sweep for result in ordered
                                                                  if result.sweep is not None])
    return fused, fusion_intervals(params, ordered)

"""Stage `evaluate_scenes`: every run of `evaluate.scene_runs` and the oracle over the multi-target
scenes (`pipeline.simulation.scenes`, stage `scenes`), scored by `pipeline.bench.scene_evaluation`.

Writes `reports/scene_metrics.json` (the scenes' size and plot counts, and per run GOSPA with its
parts, track switches, tracks per truth, fragmentation, purity and speed), their confidence intervals
over the scenes (`reports/scene_intervals.json`, `pipeline.bench.intervals`) and
`reports/scene_example.png`, the busiest scene (most target plots) tracked by
`evaluate.example_run`.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pipeline import io
from pipeline.bench import scene_evaluation
from pipeline.bench.runs import by_name, declared_runs
from pipeline.params import Params
from pipeline.reports import figures

log = logging.getLogger("pipeline")


def run_evaluate_scenes(params: Params, scenes_dir: Path, models_dir: Path, reports_dir: Path) -> None:
    evaluation = scene_evaluation.prepare(params, scenes_dir, models_dir)
    recorded = [scene for scene in evaluation.scenes if scene.draw == 0]  # the scenes stage's; draws follow them
    target_plots = [int((scene.plots.target_id >= 0).sum()) for scene in recorded]
    busiest, run_name = int(np.argmax(target_plots)), params.evaluate.example_run
    example = declared_runs(params)[run_name]
    runs, (updates, scored), units = scene_evaluation.evaluate_all(evaluation, params.workers, (example, busiest))
    intervals = scene_evaluation.metric_intervals(params, evaluation.scenes, units)
    scenes = params.scenes
    plots = sum(len(scene.plots) for scene in recorded)
    report = {"scenes": scenes.count, "aircraft_per_scene": scenes.aircraft, "duration_s": scenes.duration_s,
              "plots": {"target": sum(target_plots), "false": plots - sum(target_plots)},
              "example": {"scene": evaluation.scenes[busiest].scenario_id, "run": run_name}, "runs": by_name(runs)}
    picture = figures.scene_picture(evaluation.scenes[busiest], updates, scored, evaluation.management[example],
                                    params, run_name)
    io.write_metrics(report, reports_dir / "scene_metrics.json")
    io.write_metrics(intervals, reports_dir / "scene_intervals.json")
    io.write_bytes(picture, reports_dir / "scene_example.png")
    log.info("evaluate_scenes: %d runs over %d scenes -> %s, %s", len(runs), scenes.count,
             reports_dir / "scene_metrics.json", reports_dir / "scene_example.png")

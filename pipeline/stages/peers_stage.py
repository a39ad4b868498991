"""Stage `peers`: Stone Soup's trackers, our runs of `peers.runs` and the oracle on the same plots, a few test
scenarios, a few many-aircraft scenes and a real-traffic scene (`pipeline.bench.peers`), scored by GOSPA and the surveillance scorecard.

Writes `reports/peers.json` (per material: what was tracked, and per run its metrics and the scorecard's
reference figures with pass or fail), `reports/peers_intervals.json` (the test and scene materials' 95 % intervals and
paired intervals, `pipeline.bench.intervals`) and `reports/peers.md` (the tables, `pipeline.reports.peers_tables`).
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.bench import peers
from pipeline.params import Params
from pipeline.reports import peers_tables
from pipeline.surveillance import pcrb, scorecard

log = logging.getLogger("pipeline")

ROOT = Path(".")  # the repository: the stage runs there (dvc.yaml), the real-traffic states path is relative to it


def material_summary(params: Params, material: str, recordings: list[peers.Recording]) -> dict:
    """What a material holds: its recordings' ids, plots and targets in coverage, and where it comes from."""
    plots = sum(len(r.scene.plots) for r in recordings)
    target = sum(int((r.scene.plots.target_id >= 0).sum()) for r in recordings)
    summary = {"recordings": [r.scene.scenario_id for r in recordings], "plots": {"target": target,
                                                                                  "false": plots - target},
               "targets": sum(len(set(r.truth.target_id[r.truth.in_coverage].tolist())) for r in recordings),
               "update_interval_s": recordings[0].update_interval_s}
    if material == peers.TEST:
        return {**summary, "split": params.evaluate.split, "window_s": params.peers.window_s,
                "strategies": {str(r.scene.scenario_id): next(iter(r.scene.roles.values())) for r in recordings}}
    if material == peers.SCENES:
        return {**summary, "window_s": params.peers.scene_window_s,
                "aircraft": {str(r.scene.scenario_id): len(r.scene.roles) for r in recordings}}
    site = params.peers.real_traffic
    return {**summary, "states": site.states, "site": {"latitude_deg": site.latitude_deg,
                                                       "longitude_deg": site.longitude_deg, "height_m": site.height_m}}


def run_peers(params: Params, simulated_dir: Path, routes_dir: Path, scenes_dir: Path, models_dir: Path,
              reports_dir: Path) -> None:
    bench = peers.prepare(params, simulated_dir, routes_dir, scenes_dir, models_dir, ROOT)
    results = peers.evaluate_all(bench, params.workers)
    report = {"materials": {}, "runs": {}, "references": {}, "families": {p.name: p.family for p in bench.peers}}
    interval_report = {}
    for material, units in results.items():
        recordings = [r for r in bench.recordings if r.material == material]
        plots = sum(len(r.scene.plots) for r in recordings)
        report["materials"][material] = {**material_summary(params, material, recordings),
                                          "pcrb_horizontal_rms_m": {
            kind: pcrb.horizontal_rms([(r.truth, r.detection_probability, r.radar) for r in recordings],
                                      bench.tuned[kind]) for kind in pcrb.MODELS}}
        metrics = {name: peers.run_metrics(done, plots) for name, done in units.items()}
        report["runs"][material] = metrics
        report["references"][material] = {name: scorecard.judged(card) for name, card in metrics.items()}
        for name, values in metrics.items():
            log.info("peers %s %s: GOSPA %.1f m, position RMS %.1f m, probability of update %.4f, long gaps %.4f, "
                     "%.0f plots/s", material, name, values["GOSPA"], values["position_rms_m"],
                     values["probability_of_update"], values["ratio_of_long_gaps"], values["plots_per_second"])
        if material in peers.RESAMPLED:
            interval_report[material] = peers.metric_intervals(params, recordings, units)
    io.write_metrics(report, reports_dir / "peers.json")
    io.write_metrics(interval_report, reports_dir / "peers_intervals.json")
    io.write_text(peers_tables.report_markdown(report, interval_report), reports_dir / "peers.md")
    log.info("peers: %d runs over %d recordings -> %s, %s", len(bench.peers), len(bench.recordings),
             reports_dir / "peers.json", reports_dir / "peers.md")

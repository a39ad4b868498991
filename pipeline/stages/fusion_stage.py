"""Stage `fusion`: two radars' local tracks of the multi-target scenes associated by every method and fused; the
fused picture's GOSPA against each radar alone and the oracle association (`radar_fusion`); and every method's
association accuracy against radar 2's registration bias in those scenes (`fusion_bias_sweep`). A scene is a
unit of the bench's engine (`fusion_bench`: `compute.workers` processes or a Dask scheduler).

Writes `reports/fusion.json` (DVC metrics; the sweep under `bias_sweep`), `reports/fusion_intervals.json` (the
pictures' GOSPA and the methods' accuracy with their intervals over the scenes) and `reports/fusion_bias.png` (accuracy
and false pairs against the bias). Reads `models/kalman_tuned.json` (the local tracker) and, when `fusion.methods`
lists network, `models/association_net.pt`.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.bench import fusion_bench, fusion_bias_sweep
from pipeline.params import Params

log = logging.getLogger("pipeline")


def run_fusion(params: Params, models_dir: Path, reports_dir: Path) -> None:
    report, intervals = fusion_bench.fusion_reports(params, models_dir, params.workers)
    io.write_metrics(report, reports_dir / "fusion.json")
    io.write_metrics(intervals, reports_dir / "fusion_intervals.json")
    io.write_bytes(fusion_bias_sweep.sweep_figure(report["bias_sweep"]), reports_dir / "fusion_bias.png")
    log.info("fusion: %d scenes, %d common times; GOSPA %s -> %s", report["scenes"], report["common_times"],
             ", ".join(f"{name} {value:.0f} m" for name, value in report["gospa_m"].items()),
             reports_dir / "fusion.json")

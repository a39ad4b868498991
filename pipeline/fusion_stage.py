"""Stage `fusion`: two radars' local tracks of the multi-target scenes associated by every method and fused; the
fused picture's GOSPA against each radar alone and the oracle association (`radar_fusion`).

Writes `reports/fusion.json` (DVC metrics). Reads `models/kalman_tuned.json` (the local tracker) and, when
`fusion.methods` lists network, `models/association_net.pt`.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import association_net, io, radar_fusion
from pipeline.params import Params

log = logging.getLogger("pipeline")


def run_fusion(params: Params, models_dir: Path, reports_dir: Path) -> None:
    model = association_net.load(models_dir / "association_net.pt") if "network" in params.fusion.methods else None
    report = radar_fusion.fusion_report(params, models_dir, model)
    io.write_json(report, reports_dir / "fusion.json")
    log.info("fusion: %d scenes, %d common times; GOSPA %s -> %s", report["scenes"], report["common_times"],
             ", ".join(f"{name} {value:.0f} m" for name, value in report["gospa_m"].items()),
             reports_dir / "fusion.json")

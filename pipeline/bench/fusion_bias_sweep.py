"""Association accuracy against radar 2's registration bias in our scenes (issue 19, report item 5), beside the
seed's synthetic setting that `association_report` sweeps.

Per scene (the first `fusion.sweep_scenes` of the fusion stage's): radar 1 as `fusion.radars[0]` and radar 2
as `fusion.radars[1]` with its registration biases set to zero are simulated and tracked (`radar_fusion.radar_tracks`;
radar 1's tracks are the fusion unit's own, `fusion_bench`),
and both track tables taken at common times (`common_time_states`). Each bias length b of `fusion.sweep_bias_m`
is then a registration error of radar 2's site: every radar 2 track state is moved by b in a direction drawn
uniformly per (scene, bias) from radar 2's seed (the seed's bias: a translation of uniform direction, seed 002,
section 4.1). A site error moves every track of the radar by the same vector, which is what moving the tracks
does (the tracker's conversion from a site b away), so the tracks are simulated once per scene, not per bias.
Every method of `fusion.methods` decides (with memory, `table_association.decide`) on the same tracks, and its
pairs are counted against the oracle's (`radar_fusion.oracle_pairs`: the tracks' majority targets, which the
bias does not change): accuracy = correct / true pairs, false and missed pairs per true pair
(`association_report.count_pairs`, the seed-setting report's measures).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402

from pipeline.association import association_net, table_association
from pipeline.association.common_time_states import Snapshot, common_frame, common_snapshots  # noqa: E402
from pipeline.bench import radar_fusion
from pipeline.bench.association_report import count_pairs  # noqa: E402
from pipeline.figure_png import png  # noqa: E402
from pipeline.params import Params  # noqa: E402

COUNTS = ("true", "correct", "false", "missed")
MEASURES = (("accuracy", "correct pairs / true pairs"), ("false_pairs", "false pairs / true pairs"),
            ("missed_pairs", "missed pairs / true pairs"))


def moved(snapshots: list[Snapshot], offset_m: np.ndarray) -> list[Snapshot]:
    """The snapshots with every second-user track's east, north position moved by `offset_m` (2,) m."""
    out = []
    for snapshot in snapshots:
        states = snapshot.states[1].copy()
        states[:, :2] += offset_m
        out.append(dataclasses.replace(snapshot, states=(snapshot.states[0], states)))
    return out


def bias_offset(bias_m: float, seed: int, scene_id: int, index: int) -> np.ndarray:
    """East, north offset (2,) m of length `bias_m`, direction uniform from the stream (seed, scene, bias index)."""
    angle = np.random.default_rng([seed, scene_id, index]).uniform(0.0, 2.0 * np.pi)
    return bias_m * np.array([np.sin(angle), np.cos(angle)])


def scene_counts(params: Params, scene_id: int, routes: pa.Table, first: radar_fusion.RadarTracks, models_dir: Path,
                 model: association_net.AssociationNet | None) -> np.ndarray:
    """(biases, methods, 4) counts [true, correct, false, missed] of one scene of `routes` (module docstring),
    radar 1's tracks `first` those the fusion stage made of it (`radar_fusion.radar_tracks`: the same radar)."""
    fusion = params.fusion
    unbiased = dataclasses.replace(fusion.radars[1], bias_range_m=0.0, bias_azimuth_deg=0.0, bias_east_m=0.0,
                                   bias_north_m=0.0)
    table1, targets1, _ = first
    table2, targets2, _ = radar_fusion.radar_tracks(params, unbiased, scene_id, routes, models_dir)
    snapshots = common_snapshots(table1, table2, common_frame(table1, table2), params.associate)
    oracle = [radar_fusion.oracle_pairs(snapshot, (targets1, targets2)) for snapshot in snapshots]
    counts = np.zeros((len(fusion.sweep_bias_m), len(fusion.methods), len(COUNTS)), dtype=np.int64)
    for b, bias_m in enumerate(fusion.sweep_bias_m):
        shifted = moved(snapshots, bias_offset(bias_m, unbiased.seed, scene_id, b))
        for m, method in enumerate(fusion.methods):
            decisions = table_association.decide(shifted, method, params.association, model,
                                                 params.associate.keep_probability)
            for decision, true_pairs in zip(decisions, oracle):
                found = count_pairs(decision.pairs, true_pairs)
                counts[b, m] += [found[key] for key in COUNTS]
    return counts


def sweep_report(params: Params, counts: list[np.ndarray]) -> dict:
    """{"scenes", "by_bias_m": {bias: {"methods": {method: accuracy, false_pairs, missed_pairs (per true pair) and
    the counts}}}}, the shape `association_report.bias_figure` draws, from the first `fusion.sweep_scenes` scenes'
    `scene_counts`."""
    fusion = params.fusion
    totals = sum(counts)
    by_bias = {}
    for b, bias_m in enumerate(fusion.sweep_bias_m):
        methods = {}
        for m, method in enumerate(fusion.methods):
            count = dict(zip(COUNTS, totals[b, m].tolist()))
            true = max(count["true"], 1)
            methods[method] = {"accuracy": count["correct"] / true, "false_pairs": count["false"] / true,
                               "missed_pairs": count["missed"] / true, **{f"{k}_count": v for k, v in count.items()}}
        by_bias[f"{bias_m:g}"] = {"methods": methods}
    return {"scenes": fusion.sweep_scenes, "by_bias_m": by_bias}


def sweep_figure(report: dict) -> bytes:
    """PNG of `sweep_report`'s measures against the bias length, a panel per measure, a line per method, with the
    issue's goal (95 % at 200 m) on the accuracy panel."""
    biases = sorted(report["by_bias_m"], key=float)
    methods = list(report["by_bias_m"][biases[0]]["methods"])
    figure, axes = plt.subplots(1, len(MEASURES), figsize=(13, 4))
    for axis, (key, label) in zip(axes, MEASURES):
        for method in methods:
            axis.plot([float(b) for b in biases], [report["by_bias_m"][b]["methods"][method][key] for b in biases],
                      marker="o", label=method)
        axis.set(xlabel="radar 2 site error (m)", ylabel=label, title=f"{label}, {report['scenes']} scenes")
    axes[0].plot([200.0], [0.95], marker="*", color="grey", linestyle="none", markersize=12,
                 label="issue 19's goal (95 % at 200 m)")
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    return png(figure)

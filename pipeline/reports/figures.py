"""Pictures of the tracking runs (tracks, comparisons, OSPA, scenes), returned as PNG bytes so the caller can
write them atomically; the simulated data's are `pipeline.reports.data_figures`."""

from __future__ import annotations

from collections.abc import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pymap3d  # noqa: E402

from pipeline.bench.runs import Run  # noqa: E402
from pipeline.figure_png import png  # noqa: E402
from pipeline.geometry import geodesy  # noqa: E402
from pipeline.params import Params  # noqa: E402
from pipeline.tracker.management import TrackManagement  # noqa: E402
from pipeline.tracker.registry import CLASSICAL, NEURAL, REFERENCE  # noqa: E402
from pipeline.tracker.updates import confirmed_associations, positions  # noqa: E402

FAMILY_COLOURS = {NEURAL: "tab:blue", CLASSICAL: "tab:orange", REFERENCE: "tab:grey"}


def tracking_picture(scenario: object, updates: dict[str, np.ndarray], params: Params, run_name: str,
                     management: TrackManagement) -> bytes:
    """One scenario: the true route, target and false plots near it, and the confirmed tracks' states
    (confirmed by the run's track management rule `management`)."""
    radar = params.radar

    def local_km(ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        east, north, _ = pymap3d.ecef2enu(ecef[:, 0], ecef[:, 1], ecef[:, 2], radar.latitude_deg,
                                          radar.longitude_deg, radar.height_m, ell=geodesy.WGS84_ELLIPSOID)
        return np.asarray(east) / 1000.0, np.asarray(north) / 1000.0

    times = scenario.plots.time
    truth_e, truth_n = local_km(scenario.truth(np.linspace(times.min(), times.max(), 2000)))
    plot_e, plot_n = local_km(scenario.plots.position)
    target = np.array([scenario.is_target[int(p)] for p in scenario.plots.plot_id], dtype=bool)
    margin = 20.0
    box = (truth_e.min() - margin, truth_e.max() + margin, truth_n.min() - margin, truth_n.max() + margin)
    shown = (plot_e > box[0]) & (plot_e < box[1]) & (plot_n > box[2]) & (plot_n < box[3])
    figure, axis = plt.subplots(figsize=(8, 8))
    axis.scatter(plot_e[shown & ~target], plot_n[shown & ~target], s=2, color="0.7", label="false plots")
    axis.scatter(plot_e[target], plot_n[target], s=4, color="black", label="target plots")
    axis.plot(truth_e, truth_n, color="tab:green", lw=1.0, label="truth")
    confirmed = confirmed_associations(updates, management)
    states = positions(updates)
    for number, track_id in enumerate(np.unique(updates["track_id"][confirmed])):
        rows = confirmed & (updates["track_id"] == track_id)
        east, north = local_km(states[rows])
        axis.plot(east, north, "-", lw=1.6, color=plt.cm.tab10.colors[number % 10],
                  label="confirmed tracks" if number == 0 else None)
    axis.set_xlim(box[0], box[1])
    axis.set_ylim(box[2], box[3])
    axis.set_aspect("equal")
    axis.set_xlabel("east of radar (km)")
    axis.set_ylabel("north of radar (km)")
    axis.set_title(f"scenario {scenario.scenario_id}, {run_name}: {len(np.unique(updates['track_id'][confirmed]))} "
                   "confirmed tracks", fontsize=10)
    axis.legend(fontsize=8, loc="best")
    figure.tight_layout()
    return png(figure)


def comparison_picture(runs: Mapping[Run, dict], intervals: Mapping[str, Mapping[str, list]] | None = None) -> bytes:
    """OSPA, MAE and ROCA of every tracker side by side, best OSPA on top, coloured by family: a dot per
    tracker with its confidence interval (`intervals`: the evaluation's per-run intervals by run name and
    metric, `pipeline.bench.intervals`), on axes spanning the values and intervals rather than from 0,
    so that the differences show and whether they are larger than the noise."""
    ordered = sorted(runs, key=lambda r: runs[r]["OSPA"], reverse=True)
    figure, axes = plt.subplots(1, 3, figsize=(13, 0.4 * len(ordered) + 1.5), sharey=True)
    rows = np.arange(len(ordered))
    for axis, (metric, label) in zip(axes, (("OSPA", "OSPA (m)"), ("MAE", "MAE of confirmed tracks (m)"),
                                            ("ROCA", "target plots in confirmed tracks (ROCA)"))):
        values = np.array([runs[r][metric] if runs[r][metric] is not None else np.nan for r in ordered], dtype=float)
        bounds = np.array([(intervals or {}).get(r.name, {}).get(metric, [np.nan, np.nan]) for r in ordered],
                          dtype=float).reshape(len(ordered), 2)
        for row, run in enumerate(ordered):
            colour = FAMILY_COLOURS[run.family]
            if np.isfinite(bounds[row]).all():
                axis.plot(bounds[row], [row, row], color=colour, linewidth=2.5, alpha=0.45, solid_capstyle="butt")
            axis.plot(values[row], row, "o", color=colour, markersize=6)
        shown = np.concatenate([values, bounds.ravel()])
        shown = shown[np.isfinite(shown)]
        if len(shown):
            low, high = shown.min(), shown.max()
            margin = 0.05 * (high - low) or 0.05 * max(abs(high), 1.0)
            axis.set_xlim(low - margin, high + margin)
        axis.set_xlabel(label)
        axis.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(rows, [r.name for r in ordered])
    axes[0].set_ylim(-0.6, len(ordered) - 0.4)
    noted = "; bars: confidence intervals over the routes and draws" if intervals else ""
    axes[0].set_title(f"blue: neural, orange: classical, grey: references{noted}", loc="left", fontsize=9)
    figure.tight_layout()
    return png(figure)


def initiation_picture(rows: list[tuple[Run, str, float, float, float]]) -> bytes:
    """Initiation time (mean, s) against false tracks per hour, a dot per run (`comparison_tables.initiation_rows`),
    coloured by family, shaped by track management rule, one method's runs under different rules joined: a
    rule trades one for the other, and a tracker that is faster at no more false tracks lies down and left.
    The false-track axis is linear up to 0.01 per hour and logarithmic beyond (most runs have almost none)."""
    figure, axis = plt.subplots(figsize=(9, 6))
    markers = dict(zip(sorted({rule for _, rule, *_ in rows}), "osD^v"))
    by_method: dict[tuple[str, float], list[tuple[float, float]]] = {}
    for run, rule, mean, _, per_hour in rows:
        axis.plot(per_hour, mean, markers[rule], color=FAMILY_COLOURS[run.family], markersize=7, alpha=0.85)
        axis.annotate(run.name, (per_hour, mean), fontsize=6, xytext=(4, 2), textcoords="offset points")
        by_method.setdefault((run.method, run.window_m), []).append((per_hour, mean))
    for points in by_method.values():
        if len(points) > 1:
            axis.plot(*zip(*sorted(points)), color="grey", linewidth=0.8, alpha=0.6)
    for rule, marker in markers.items():
        axis.plot([], [], marker, color="black", label=f"rule: {rule}")
    axis.set_xscale("symlog", linthresh=0.01, linscale=0.3)
    axis.set_xlabel("false tracks per hour of flying")
    axis.set_ylabel("initiation time, mean (s)")
    axis.set_title("Track initiation: blue neural, orange classical, grey references", loc="left", fontsize=9)
    axis.grid(alpha=0.3, which="both")
    axis.legend(fontsize=8, loc="upper right")
    figure.tight_layout()
    return png(figure)


def ospa_distribution(per_scan: Mapping[Run, np.ndarray], cutoff: float) -> bytes:
    """Share of scans at or below each OSPA, one line per tracker (dashed: the references): where
    the mean hides whether a tracker is often slightly off or sometimes missing (OSPA at the cutoff)."""
    figure, axis = plt.subplots(figsize=(9, 5.5))
    colours = plt.get_cmap("tab20").colors
    for index, run in enumerate(sorted(per_scan, key=lambda r: per_scan[r].mean())):
        values = np.sort(per_scan[run])
        style = "--" if run.reference else "-"
        axis.plot(values, np.arange(1, len(values) + 1) / len(values), style, label=run.name, linewidth=1.2,
                  color=colours[index % len(colours)])
    axis.set_xlim(0, cutoff * 1.02)
    axis.set_xlabel(f"OSPA of a scan (m); {cutoff:.0f} m = a missed or a false track")
    axis.set_ylabel("share of scans")
    axis.grid(alpha=0.3)
    axis.legend(fontsize=7, ncol=2, loc="lower right")
    figure.tight_layout()
    return png(figure)


def noise_scale_picture(result: dict) -> bytes:
    """Mean hold-out error of each filter against the factor on the radar's noise (`filter_holdout.compare`)."""
    figure, axes = plt.subplots(figsize=(7, 4.5))
    for name, errors in result["mean_error_by_noise_m"].items():
        axes.plot(result["noise_factors"], errors, marker="o", label=name)
    axes.set_xscale("log", base=2)
    axes.set_yscale("log")
    axes.set_xlabel("plot noise: the radar's sigmas times")
    axes.set_ylabel("mean position error at the window's last plot (m)")
    axes.set_title("Hold-out windows, noise level unknown to the filters")
    axes.grid(True, which="both", alpha=0.3)
    axes.legend(fontsize=7)
    return png(figure)


def scene_picture(scene: object, updates: dict[str, np.ndarray], scored: object, management: TrackManagement,
                  params: Params, run_name: str) -> bytes:
    """One multi-target scene (`scene_evaluation.Scene`) tracked by a run: the aircraft's true
    routes in grey, the confirmed tracks' states coloured by track identity (confirmed by the run's
    rule `management`), and a red cross where an aircraft's assigned track switched to another
    (`scored`, the scene's `gospa.ScanGospa`), at the aircraft's position in that scan. Left the
    whole scene, right the crossing pair's neighbourhood (50 km across)."""
    radar = params.radar

    def local_km(ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        east, north, _ = pymap3d.ecef2enu(ecef[:, 0], ecef[:, 1], ecef[:, 2], radar.latitude_deg,
                                          radar.longitude_deg, radar.height_m, ell=geodesy.WGS84_ELLIPSOID)
        return np.asarray(east) / 1000.0, np.asarray(north) / 1000.0

    period = radar.scan_period_s
    times = np.linspace(scene.plots.time.min(), scene.plots.time.max(), 2000)
    in_order = np.lexsort((scored.scan, scored.truth))
    truth, scan, track = scored.truth[in_order], scored.scan[in_order], scored.track[in_order]
    switched = np.flatnonzero((truth[1:] == truth[:-1]) & (track[1:] != track[:-1])) + 1
    switches = np.array([scene.trajectories[int(truth[k])](np.array([(scan[k] + 0.5) * period]))[0]
                         for k in switched]).reshape(-1, 3)
    crossing = [aircraft for aircraft, role in scene.roles.items() if role == "crossing"]
    first, second = (scene.trajectories[aircraft](times) for aircraft in crossing[:2])
    centre = local_km(first[[int(np.argmin(np.linalg.norm(first - second, axis=1)))]])
    confirmed = confirmed_associations(updates, management)
    states = positions(updates)
    track_ids = np.unique(updates["track_id"][confirmed])
    colours = plt.get_cmap("tab20").colors
    figure, axes = plt.subplots(1, 2, figsize=(15, 7.5))
    for axis in axes:
        for aircraft, trajectory in scene.trajectories.items():
            axis.plot(*local_km(trajectory(times)), color="0.6", lw=2.5, alpha=0.6,
                      label="aircraft (truth)" if aircraft == 0 else None)
        for number, track_id in enumerate(track_ids):
            rows = confirmed & (updates["track_id"] == track_id)
            axis.plot(*local_km(states[rows]), "-", lw=1.0, color=colours[number % len(colours)],
                      label="confirmed tracks (colour: identity)" if number == 0 else None)
        axis.scatter(*local_km(switches), marker="x", s=60, color="red", zorder=5,
                     label=f"track switches ({len(switches)})")
        axis.set_aspect("equal")
        axis.set_xlabel("east of radar (km)")
        axis.set_ylabel("north of radar (km)")
    axes[0].plot(0, 0, "k^", ms=8)
    axes[0].set_title(f"scene {scene.scenario_id}, {run_name}: {len(scene.trajectories)} aircraft, "
                      f"{len(track_ids)} confirmed tracks", fontsize=10)
    axes[0].legend(fontsize=8, loc="best")
    axes[1].set_xlim(centre[0][0] - 25.0, centre[0][0] + 25.0)
    axes[1].set_ylim(centre[1][0] - 25.0, centre[1][0] + 25.0)
    axes[1].set_title("around the crossing pair's closest approach", fontsize=10)
    figure.tight_layout()
    return png(figure)

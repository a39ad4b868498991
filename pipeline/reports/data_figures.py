"""Pictures of the simulated data (routes, the radar's plots, the windows' linearity), returned as PNG bytes
so the caller can write them atomically.

Apart from the tracking pictures (`pipeline.reports.figures`), which read the tracker's registry: the data
stages that draw these depend on no tracker module (their code deps in dvc.yaml), so a change to the
tracker does not run the data stages, and everything after them, again.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402
import pymap3d  # noqa: E402

from pipeline.figure_png import png  # noqa: E402
from pipeline.geometry import geodesy  # noqa: E402
from pipeline.params import STRATEGIES, Params  # noqa: E402
from pipeline.simulation.data_summary import target_plot_errors_m, target_plot_intervals_s  # noqa: E402


def _local_km(table: pa.Table, params: Params, prefix: str = "") -> tuple[np.ndarray, np.ndarray]:
    radar = params.radar
    east, north, _ = pymap3d.ecef2enu(table.column(f"{prefix}x_ecef_m").to_numpy(),
                                      table.column(f"{prefix}y_ecef_m").to_numpy(),
                                      table.column(f"{prefix}z_ecef_m").to_numpy(), radar.latitude_deg,
                                      radar.longitude_deg, radar.height_m, ell=geodesy.WGS84_ELLIPSOID)
    return np.asarray(east) / 1000.0, np.asarray(north) / 1000.0


def route_examples(routes: pa.Table, plots: pa.Table, params: Params, per_strategy: int) -> bytes:
    """A few routes of each strategy on the radar's plane, with their target and false plots; each
    route's altitude span is in its legend (climb_dive routes climb and dive)."""
    rows = -(-len(STRATEGIES) // 2)  # two strategies a row
    figure, axes = plt.subplots(rows, 2, figsize=(13, 6.4 * rows), squeeze=False)
    half = params.radar.range_max_m * np.sqrt(2.0) / 2000.0
    for axis, strategy in zip(axes.flat, STRATEGIES):
        ids = np.unique(routes.filter(pa.compute.equal(routes.column("strategy"), strategy))
                        .column("route_id").to_numpy())[:per_strategy]
        for colour, route_id in zip(plt.cm.tab10.colors, ids):
            route = routes.filter(pa.compute.equal(routes.column("route_id"), route_id))
            scenario = plots.filter(pa.compute.equal(plots.column("scenario_id"), route_id))
            false = scenario.filter(pa.compute.invert(scenario.column("is_target")))
            target = scenario.filter(scenario.column("is_target"))
            axis.scatter(*_local_km(false, params), s=1, color=colour, alpha=0.12, linewidths=0)
            altitude_km = route.column("altitude_m").to_numpy() / 1000.0
            axis.plot(*_local_km(route, params), color=colour, lw=1.4,
                      label=f"route {route_id} ({route.column('aircraft_type')[0].as_py()}, "
                            f"{altitude_km.min():.1f}-{altitude_km.max():.1f} km up)")
            axis.scatter(*_local_km(target, params), s=5, color="black", linewidths=0)
        axis.plot([-half, half, half, -half, -half], [-half, -half, half, half, -half], "k--", lw=0.8)
        axis.plot(0, 0, "k^", ms=8)
        axis.set_title(f"{strategy.replace('_', ' ')}: truth (line), target plots (black), false plots (faint)",
                       fontsize=9)
        axis.set_xlabel("east of radar (km)")
        axis.set_ylabel("north of radar (km)")
        axis.set_aspect("equal")
        axis.legend(fontsize=7, loc="lower left")
    figure.tight_layout()
    return png(figure)


def radar_statistics(plots: pa.Table, truth: pa.Table) -> bytes:
    """Inter-plot intervals, plot errors and detection rate against range."""
    figure, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    intervals = target_plot_intervals_s(plots)
    axes[0].hist(intervals, bins=np.arange(0.0, max(60.0, float(np.percentile(intervals, 99.5)) if len(intervals)
                                                    else 60.0), 0.5), color="tab:blue")
    axes[0].axvline(18.0, color="k", ls="--", lw=0.8, label="18 s segment gap")
    axes[0].set_yscale("log")
    axes[0].set_xlabel("interval between a target's consecutive plots (s)")
    axes[0].set_ylabel("count")
    axes[0].legend(fontsize=8)

    errors = target_plot_errors_m(plots)
    axes[1].hist(errors, bins=100, range=(0.0, float(np.percentile(errors, 99.5)) if len(errors) else 1.0),
                 color="tab:orange")
    axes[1].set_xlabel("target plot error, eqs 4.1-4.6 vs truth (m)")
    axes[1].set_ylabel("count")
    axes[1].set_title(f"mean {errors.mean():.1f} m, median {np.median(errors):.1f} m" if len(errors) else "",
                      fontsize=9)

    covered = truth.filter(truth.column("in_coverage"))
    ranges = covered.column("range_m").to_numpy() / 1000.0
    bins = np.linspace(0.0, max(float(ranges.max()) if len(ranges) else 1.0, 1.0), 21)
    which = np.digitize(ranges, bins) - 1
    counts = np.bincount(which, minlength=len(bins))[:-1]
    hits = np.bincount(which, weights=covered.column("detected").to_numpy(zero_copy_only=False).astype(float),
                       minlength=len(bins))[:-1]
    expected = np.bincount(which, weights=covered.column("detection_probability").to_numpy(), minlength=len(bins))[:-1]
    centres = 0.5 * (bins[1:] + bins[:-1])
    seen = counts > 0
    axes[2].plot(centres[seen], hits[seen] / counts[seen], "o-", label="simulated detections")
    axes[2].plot(centres[seen], expected[seen] / counts[seen], "k--", label="mean Pd from the radar model")
    axes[2].set_xlabel("slant range (km)")
    axes[2].set_ylabel("detection rate (targets in coverage)")
    axes[2].set_ylim(0.0, 1.02)
    axes[2].legend(fontsize=8)
    figure.tight_layout()
    return png(figure)


def linearity_histograms(materials: dict[str, tuple[np.ndarray, np.ndarray]], bins: int) -> bytes:
    """Linearity of each material's windows before and after balancing."""
    figure, axes = plt.subplots(1, len(materials), figsize=(5 * len(materials), 3.8))
    for axis, (name, (before, after)) in zip(np.atleast_1d(axes), materials.items()):
        edges = np.linspace(before.min(), before.max(), bins + 1) if len(before) else np.linspace(0, 1, bins + 1)
        axis.hist(before, bins=edges, color="tab:grey", alpha=0.6, label=f"before ({len(before):,})")
        axis.hist(after, bins=edges, color="tab:blue", alpha=0.8, label=f"after ({len(after):,})")
        axis.set_yscale("log")
        axis.set_xlabel("linearity (eq. 4.7), 1 = straight")
        axis.set_ylabel("windows")
        axis.set_title(name)
        axis.legend(fontsize=8, loc="upper left")
    figure.tight_layout()
    return png(figure)

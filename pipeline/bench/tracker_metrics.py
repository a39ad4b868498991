"""Tracker metrics exactly as thesis section 5.1 defines them (spec section 9).

Readings where the thesis is brief:

- An *association to a confirmed track* is a track update (not a track's start) after
  which the track has the confirmed weight (`pipeline.tracker.updates.confirmed_associations`,
  the one definition). NOPA counts them, NOFPA those whose plot is false.
- MAE is the mean distance between the state of a confirmed track and the target's true
  position at the time of each such update, pooled over all routes.
- NOMT is the number of tracks that ever became confirmed, averaged over routes.
- MMTL is the number of plots associated to a confirmed track while it was confirmed,
  averaged over the confirmed tracks of a route, then over the routes that have any.
- ROCA = target plots associated to confirmed tracks / all target plots;
  ROFA = false plots associated to confirmed tracks / all associations to confirmed tracks.

Ours, for track continuity (issue 13): `tracks_per_aircraft`, the confirmed tracks that
followed the aircraft (most of their confirmed associations are its plots), averaged over the
routes whose aircraft the radar saw (at least one target plot: a route flown wholly outside
coverage has no aircraft to track).
NOMT counts every confirmed track, false ones too; this counts how many pieces the aircraft's
track fell into: 1 is one unbroken track per route (more where the aircraft leaves coverage and
comes back, which the oracle's figure shows), 0 a route never tracked.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from pipeline.bench.runs import Run
from pipeline.tracker import registry
from pipeline.tracker.management import TrackManagement
from pipeline.tracker.updates import confirmed_associations, positions

# Thesis tables 5.1 and 5.2 (spec section 9).
THESIS = {
    "via_3000": {"MAE": 615.5, "NOFPA": 2, "NOPA": 22469, "NOMT": 7.25, "MMTL": 51.7, "ROCA": 0.903, "ROFA": 8.0e-5},
    "via_4000": {"MAE": 635.2, "NOFPA": 5, "NOPA": 22720, "NOMT": 6.83, "MMTL": 55.4, "ROCA": 0.913, "ROFA": 2.2e-4},
    "via_5000": {"MAE": 642.6, "NOFPA": 9, "NOPA": 22781, "NOMT": 6.68, "MMTL": 56.8, "ROCA": 0.915, "ROFA": 4.0e-4},
    "via_10000": {"MAE": 685.7, "NOFPA": 53, "NOPA": 22861, "NOMT": 6.68, "MMTL": 55.9, "ROCA": 0.919,
                  "ROFA": 2.3e-3},
    "mia_3000": {"MAE": 597.8, "NOFPA": 22, "NOPA": 22354, "NOMT": 6.25, "MMTL": 59.7, "ROCA": 0.898, "ROFA": 9.8e-4},
    "mia_4000": {"MAE": 624.7, "NOFPA": 23, "NOPA": 22678, "NOMT": 6.48, "MMTL": 58.4, "ROCA": 0.912, "ROFA": 1.0e-3},
    "mia_5000": {"MAE": 656.2, "NOFPA": 25, "NOPA": 22805, "NOMT": 6.48, "MMTL": 58.7, "ROCA": 0.916, "ROFA": 1.1e-3},
    "mia_10000": {"MAE": 697.4, "NOFPA": 26, "NOPA": 22856, "NOMT": 6.56, "MMTL": 58.0, "ROCA": 0.919,
                  "ROFA": 1.1e-3},
    "ae_5000": {"MAE": 810.0, "NOFPA": 448, "NOPA": 22721, "NOMT": 10.68, "MMTL": 36.1, "ROCA": 0.913, "ROFA": 1.9e-2},
}
THESIS_PLOTS = {"target": 24873, "false": 242419}
METRICS = ("MAE", "NOFPA", "NOPA", "NOMT", "MMTL", "ROCA", "ROFA")


@dataclass
class RouteCounts:
    """What one route contributes to the metrics."""

    target_plots: int
    false_plots: int
    confirmed_associations: int
    false_confirmed_associations: int
    target_confirmed_associations: int
    error_sum_m: float
    confirmed_tracks: int
    confirmed_track_lengths: list[int]
    aircraft_tracks: int    # confirmed tracks most of whose confirmed associations are the target's plots


def route_counts(updates: dict[str, np.ndarray], is_target_plot: dict[int, bool], truth_at: callable,
                 management: TrackManagement) -> RouteCounts:
    """Count one route's tracking result (an update table, `pipeline.tracker.updates`).
    `truth_at(times)` gives the target's true ECEF positions."""
    confirmed = confirmed_associations(updates, management)
    plot_ids = updates["plot_id"][confirmed]
    target = np.array([is_target_plot[int(p)] for p in plot_ids], dtype=bool)
    states = positions(updates)[confirmed]
    errors = np.linalg.norm(states - truth_at(updates["time_unix_s"][confirmed]), axis=1) if confirmed.any() \
        else np.empty(0)
    tracks, track_of, lengths = np.unique(updates["track_id"][confirmed], return_inverse=True, return_counts=True)
    target_share = np.bincount(track_of, weights=target, minlength=len(tracks)) / np.maximum(lengths, 1)
    total_target = int(sum(is_target_plot.values()))
    return RouteCounts(
        target_plots=total_target, false_plots=len(is_target_plot) - total_target,
        confirmed_associations=int(confirmed.sum()), false_confirmed_associations=int((~target).sum()),
        target_confirmed_associations=int(target.sum()), error_sum_m=float(errors.sum()),
        confirmed_tracks=len(tracks), confirmed_track_lengths=lengths.tolist(),
        aircraft_tracks=int((target_share > 0.5).sum()))


def confirmed_nees(updates: dict[str, np.ndarray], is_target_plot: dict[int, bool], truth_at: callable,
                   management: TrackManagement) -> np.ndarray:
    """Position NEES, (estimate - truth)' P^-1 (estimate - truth), of each confirmed-track update
    with a target plot: 3 on average for a tracker whose covariance tells the truth (NaN for
    trackers that give no covariance)."""
    confirmed = confirmed_associations(updates, management)
    confirmed &= np.array([is_target_plot[int(p)] for p in updates["plot_id"]], dtype=bool)
    if not confirmed.any():
        return np.empty(0)
    states = positions(updates)[confirmed]
    error = states - truth_at(updates["time_unix_s"][confirmed])
    covariance = updates["position_covariance"][confirmed]
    if np.isnan(covariance).any():
        return np.full(len(error), np.nan)
    return np.einsum("ni,ni->n", error, np.linalg.solve(covariance, error[:, :, None])[:, :, 0])


def summarise(routes: list[RouteCounts]) -> dict[str, float]:
    """The thesis's metrics over all routes."""
    nopa = sum(r.confirmed_associations for r in routes)
    nofpa = sum(r.false_confirmed_associations for r in routes)
    target_plots = sum(r.target_plots for r in routes)
    with_tracks = [np.mean(r.confirmed_track_lengths) for r in routes if r.confirmed_track_lengths]
    seen = [r.aircraft_tracks for r in routes if r.target_plots]
    return {
        "MAE": sum(r.error_sum_m for r in routes) / nopa if nopa else float("nan"),
        "NOFPA": nofpa,
        "NOPA": nopa,
        "NOMT": float(np.mean([r.confirmed_tracks for r in routes])) if routes else float("nan"),
        "MMTL": float(np.mean(with_tracks)) if with_tracks else float("nan"),
        "ROCA": sum(r.target_confirmed_associations for r in routes) / target_plots if target_plots else float("nan"),
        "ROFA": nofpa / nopa if nopa else float("nan"),
        "tracks_per_aircraft": float(np.mean(seen)) if seen else float("nan"),
        "target_plots": target_plots,
        "false_plots": sum(r.false_plots for r in routes),
    }


def markdown_table(results: Mapping[Run, dict]) -> str:
    """Thesis tables 5.1/5.2 layout, with the thesis's row under each of ours: by method in registry
    order, window and rule, each labelled by its method's label, window and the rule it names."""
    header = "| method (window) | source | " + " | ".join(METRICS) + " |"
    lines = [header, "|---|---|" + "---|" * len(METRICS)]

    def cells(values: dict) -> str:
        out = []
        for metric in METRICS:
            value = values.get(metric, float("nan"))
            form = "{:.0f}" if metric in ("NOFPA", "NOPA") else "{:.2e}" if metric == "ROFA" else \
                "{:.3f}" if metric == "ROCA" else "{:.2f}" if metric == "NOMT" else "{:.1f}"
            out.append("n/a" if value is None or (isinstance(value, float) and np.isnan(value)) else form.format(value))
        return " | ".join(out)

    order = list(registry.METHODS)

    def position(run: Run) -> tuple[int, float, str]:
        return (order.index(run.method) if run.method in order else len(order), run.window_m, run.management or "")

    for run in sorted(results, key=position):
        label = f"{run.registered.label if run.registered else run.method} {run.window_m:.0f}"
        label += f", {run.management}" if run.management else ""
        lines.append(f"| {label} | ours | {cells(results[run])} |")
        if run.name in THESIS:
            lines.append(f"| {label} | thesis | {cells(THESIS[run.name])} |")
    return "\n".join(lines)

"""Confidence intervals of the bench's metrics: the paired percentile bootstrap over the units.

A run's metrics come from its units (the scenarios of the test split, the scenes), each tracked with
its own draw of noise and clutter, so they carry the noise of which units were drawn. The bootstrap
(Efron and Tibshirani, "An Introduction to the Bootstrap", 1993: chapter 6 for resampling the
observed units, chapter 13 for the percentile interval) recomputes every metric of every run on
`replicates` resamples of the units, n of n drawn with replacement (a route's draws of noise and
clutter together, as one cluster: they share its manoeuvres), with the run's own metric
function (`evaluation.run_metrics`, `scene_evaluation.run_metrics`: each metric is written once and
the interval applies to it as it is, ratios and means of means included). The resamples are the same
for every run (paired: the runs tracked the same units), so the interval of a difference between two
runs is read off the differences of their replicates, unit for unit, and is much narrower than the
two runs' own intervals would suggest. A difference whose paired interval holds 0 is within the
noise: a tie, not a win.

The resamples come from `numpy.random.default_rng(seed)`, drawn once before any metric, so the
intervals are the same bytes on every machine and whatever the order the units were tracked in.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

METHOD = ("paired percentile bootstrap over the units (Efron and Tibshirani 1993, chapters 6 and 13): "
          "every run's metrics recomputed on the same resamples of the units")


def resamples(units: int, replicates: int, seed: int, clusters: Sequence[int] | None = None) -> list[np.ndarray]:
    """`replicates` resamples of `units` unit indices: each draws as many clusters as there are, with
    replacement, and takes every unit of each (`clusters`: each unit's cluster, say its route, whose
    draws of noise are not independent of each other; None: every unit its own cluster). ValueError for
    no unit or clusters of another length."""
    if units < 1:
        raise ValueError("a bootstrap needs at least one unit")
    labels = np.arange(units) if clusters is None else np.asarray(clusters)
    if len(labels) != units:
        raise ValueError(f"{len(labels)} cluster labels for {units} units")
    names, cluster_of = np.unique(labels, return_inverse=True)
    members = [np.flatnonzero(cluster_of == cluster) for cluster in range(len(names))]
    drawn = np.random.default_rng(seed).integers(0, len(names), size=(replicates, len(names)))
    return [np.concatenate([members[cluster] for cluster in row]) for row in drawn]


def replicate_metrics(units: Sequence[object], metrics_of: Callable[[list], dict[str, float]],
                      rows: Sequence[np.ndarray], names: Sequence[str]) -> np.ndarray:
    """(replicates, len(names)) values of metrics `names` of `metrics_of` on each resample `rows` of `units`."""
    values = np.empty((len(rows), len(names)))  # (0, M) for no rows
    for replicate, row in enumerate(rows):
        metrics = metrics_of([units[i] for i in row])
        values[replicate] = [float(metrics[name]) for name in names]
    return values


def percentile_interval(values: np.ndarray, level: float) -> list[float]:
    """The central `level` interval [low, high] of `values` (R,), NaN replicates left out (a metric
    undefined on some resamples: a run confirming no track on them); [NaN, NaN] when all are."""
    finite = values[np.isfinite(values)]
    if not len(finite):
        return [math.nan, math.nan]
    tail = 50.0 * (1.0 - level)
    low, high = np.percentile(finite, [tail, 100.0 - tail])
    return [float(low), float(high)]


def within_noise(interval: Sequence[float]) -> bool:
    """Whether a paired interval of a difference holds 0 (or is undefined): no winner."""
    low, high = interval
    return not (np.isfinite(low) and np.isfinite(high)) or low <= 0.0 <= high


def run_intervals(units_by_run: dict[str, Sequence[object]], metrics_of: Callable[[list], dict[str, float]],
                  names: Sequence[str], paired_names: Sequence[str], replicates: int, level: float, seed: int,
                  clusters: Sequence[int] | None = None) -> dict:
    """Intervals of every run's metrics `names`, and of the difference of every pair of runs in
    `paired_names` (run a minus run b, on the same resamples), from `replicates` resamples of their
    units (every run has the same units, in the same order; `clusters` as for `resamples`), NaN with a
    single cluster. JSON-ready:
    {"method", "level", "replicates", "units", "runs": {run: {metric: [low, high]}},
     "paired": {metric: {a: {b: [low, high]}}}}."""
    counts = {len(units) for units in units_by_run.values()}
    if len(counts) != 1:
        raise ValueError(f"the runs have different numbers of units: {sorted(counts)}")
    units = counts.pop()
    rows = resamples(units, replicates, seed, clusters)
    if len(set(range(units) if clusters is None else clusters)) < 2:
        rows = []  # one unit (or route) says nothing of the noise: every interval NaN
    values = {run: replicate_metrics(units, metrics_of, rows, names) for run, units in units_by_run.items()}
    paired_columns = [list(names).index(name) for name in paired_names]
    return {"method": METHOD, "level": level, "replicates": replicates, "units": units,
            "clusters": units if clusters is None else len(set(clusters)),
            "runs": {run: {name: percentile_interval(values[run][:, column], level)
                           for column, name in enumerate(names)} for run in units_by_run},
            "paired": {name: {a: {b: percentile_interval(values[a][:, column] - values[b][:, column], level)
                                  for b in units_by_run if b != a} for a in units_by_run}
                       for name, column in zip(paired_names, paired_columns)}}

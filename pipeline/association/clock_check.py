"""Evidence of a clock offset between two users' radars in an association's result (issue 27).

A radar whose time stamps are late by δ seconds places each of its tracks δ·v behind the aircraft (v its
velocity): two tracks of one aircraft then agree in velocity and differ in position along it, by more than the
gate allows once δ·v exceeds a few position sigmas (1 s at 200 m/s is 200 m). Every method but bias_robust
(which estimates δ, `bias_robust_association`) leaves such pairs unpaired, silently: the picture shows the
aircraft twice. This looks for them in what the method left (ours, the signature of the displacement model of
Stone Soup PR #1217's time-bias feeders):

a track pair, both unpaired at a common time, is alike when its horizontal velocities pass the chi-square gate
(2 degrees of freedom at `association.gate_probability`) and the second track's position (in the method's
registration) differs from the first's by at most `association.max_bias_m` across the velocity and at most
max_bias_m + max_time_offset_s·|v| along it. A pair alike at MIN_TIMES or more common times is evidence; each
of its times gives δ = -(Δp · v) / |v|² (Δp = p2 - p1, v the second track's velocity), and the evidence's
offset is the median of those (robust to the odd crossing of two aircraft).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from pipeline.association.association_memory import horizontal
from pipeline.association.bias_robust_association import registered
from pipeline.association.common_time_states import Snapshot
from pipeline.association.track_association import gate
from pipeline.params import Association

MIN_TIMES = 3  # a pair alike at one or two common times may be two aircraft crossing; a clock offset stays


@dataclass(frozen=True)
class ClockEvidence:
    """`pairs` distinct track pairs (first user's id, second user's id) alike at MIN_TIMES or more common times,
    `times` the common times with one, and `offset_s` the median clock offset they imply (the second user's time
    stamps that much late; NaN without evidence)."""

    pairs: int
    times: int
    offset_s: float


def _alike(snapshot: Snapshot, pairs: np.ndarray, bias_m: np.ndarray | None, time_offset_s: float | None,
           association: Association) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unpaired rows (K,), columns (K,) alike at one common time and the clock offset (K,) s each implies."""
    (x1, p1), (x2, p2) = (horizontal(x, p) for x, p in zip(snapshot.states, snapshot.covariances))
    rows = np.setdiff1d(np.arange(len(x1)), pairs[:, 0])
    columns = np.setdiff1d(np.arange(len(x2)), pairs[:, 1])
    x2 = registered(x2, bias_m, time_offset_s)
    i, j = (index.ravel() for index in np.meshgrid(rows, columns, indexing="ij"))
    dv = x2[j, 2:] - x1[i, 2:]
    summed = p1[i][:, 2:, 2:] + p2[j][:, 2:, 2:]
    matching = np.einsum("ki,ki->k", dv, np.linalg.solve(summed, dv[..., None])[..., 0]) <= gate(
        association.gate_probability, 2) if len(i) else np.zeros(0, dtype=bool)
    speed = np.linalg.norm(x2[j, 2:], axis=1)
    heading = x2[j, 2:] / np.maximum(speed, np.finfo(float).tiny)[:, None]
    displacement = x2[j, :2] - x1[i, :2]
    along = np.einsum("ki,ki->k", displacement, heading)
    across = np.abs(displacement[:, 0] * heading[:, 1] - displacement[:, 1] * heading[:, 0])
    keep = (matching & (speed > 0.0) & (across <= association.max_bias_m)
            & (np.abs(along) <= association.max_bias_m + association.max_time_offset_s * speed))
    return i[keep], j[keep], -along[keep] / np.maximum(speed[keep], np.finfo(float).tiny)


def clock_evidence(snapshots: list[Snapshot], pairs: list[np.ndarray], biases: list[np.ndarray | None],
                   time_offsets: list[float | None], association: Association) -> ClockEvidence:
    """The evidence of a clock offset (module docstring) in every common time's final pairs (K, 2) and the
    method's registration there (offset (2,) m and clock offset s, each or None)."""
    offsets: dict[tuple[int, int, int], list[float]] = defaultdict(list)
    times: dict[tuple[int, int, int], list[int]] = defaultdict(list)
    for index, (snapshot, found, bias, offset) in enumerate(zip(snapshots, pairs, biases, time_offsets)):
        rows, columns, implied = _alike(snapshot, found, bias, offset, association)
        for i, j, delta in zip(rows.tolist(), columns.tolist(), implied.tolist()):
            key = (snapshot.scenario_id, int(snapshot.ids[0][i]), int(snapshot.ids[1][j]))
            offsets[key].append(delta)
            times[key].append(index)
    lasting = [key for key, seen in times.items() if len(seen) >= MIN_TIMES]
    if not lasting:
        return ClockEvidence(0, 0, float("nan"))
    return ClockEvidence(len(lasting), len({t for key in lasting for t in times[key]}),
                         float(np.median([delta for key in lasting for delta in offsets[key]])))

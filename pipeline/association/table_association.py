"""Two users' tracks associated and fused at every common time (`common_time_states`): the pairs table and the
fused air picture that `python -m pipeline associate` writes.

Association reads the horizontal state [east, north, v_east, v_north] (the seed's and the trained network's;
heights of surveillance radars are poor and the chi-square gates of params `association` are for d = 4), each
method an associator (`associator.Associator`) of the registry (`pipeline.association.registry`):
- `statistical`: `track_association.associate_statistical` (chi-square gate, 2-D assignment);
- `double_threshold`: `track_association.associate_double_threshold` over the last track_points - 1 common
  times (params `association`), the tracks present at all of them; none at the first track_points - 2 times;
- `bias_robust`: `bias_robust_association.associate_bias_robust` (with a clock offset up to
  `association.max_time_offset_s`); its offset and clock offset estimates are removed from the second user's
  positions before fusing (`bias_robust_association.registered`; and from its unpaired tracks: the picture is in
  the first user's registration);
- `network`: the trained network (`association_net.associate_network`); beyond `association.scene_size` tracks
  of a user at a time, each first-user track is read in the scene of its nearest tracks
  (`association_net.scene_probabilities`).
Every method's pairs are then continued from the last common time's and the tracks it left unpaired that pass
the keep gate paired (`association_memory`, params `associate.keep_probability`), the same for every method.
Each pair's `statistic` is the chi-square statistic Δᵀ (P1 + P2)⁻¹ Δ of the pair at that time (d = 4, after the
offset's removal for bias_robust).

Fusion: each pair's full states [e, n, u, ve, vn, vu] by covariance intersection (`track_fusion.fuse_pairs`);
the picture is the fused pairs plus each user's unpaired tracks as they are, every row with its ECEF position,
geodetic position, ENU velocity and ECEF position covariance.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.association import association_net, registry
from pipeline.association.association_memory import horizontal, with_memory
from pipeline.association.associator import Decision, TrackSet
from pipeline.association.bias_robust_association import registered
from pipeline.association.common_time_states import Frame, Snapshot
from pipeline.association.track_association import statistical_distances
from pipeline.association.track_fusion import fuse_pairs
from pipeline.geometry import geodesy
from pipeline.params import Association
from pipeline.recordings.plot_table import NO_SCENARIO
from pipeline.tracker.recording import COVARIANCE_COLUMNS, POSITION_COLUMNS, covariance_columns

SOURCES = ("fused", "first", "second")  # a picture row: a fused pair, or one user's unpaired track

PAIRS_SCHEMA = io.schema(
    ("scenario_id", pa.int32(), True),
    ("time_unix_s", pa.float64()),
    ("track_id_1", pa.int64()),
    ("track_id_2", pa.int64()),
    ("statistic", pa.float64()),
    ("bias_east_m", pa.float64(), True),
    ("bias_north_m", pa.float64(), True),
    ("time_offset_s", pa.float64(), True),
)
FUSED_SCHEMA = io.schema(
    ("scenario_id", pa.int32(), True),
    ("time_unix_s", pa.float64()),
    ("source", pa.string()),
    ("track_id_1", pa.int64(), True),
    ("track_id_2", pa.int64(), True),
    *POSITION_COLUMNS,
    ("v_east_mps", pa.float64()),
    ("v_north_mps", pa.float64()),
    ("v_up_mps", pa.float64()),
    *((name, pa.float64()) for name in COVARIANCE_COLUMNS),
    ("weight_1", pa.float64(), True),
)


def _recent(snapshots: list[Snapshot], index: int, count: int) -> list[Snapshot]:
    """Snapshot `index` and those before it of the same scenario, `count` at most (a scenario's track ids are
    its own recording's)."""
    start = index
    scenario = snapshots[index].scenario_id
    while index - start + 1 < count and start > 0 and snapshots[start - 1].scenario_id == scenario:
        start -= 1
    return snapshots[start:index + 1]


def track_sets(history: list[Snapshot]) -> tuple[TrackSet, TrackSet]:
    """Each user's tracks at the common times of `history` (the current last), horizontal (`associator.TrackSet`)."""
    sets = []
    for user in (0, 1):
        parts = [horizontal(snapshot.states[user], snapshot.covariances[user]) for snapshot in history]
        sets.append(TrackSet(tuple(snapshot.ids[user] for snapshot in history), tuple(x for x, _ in parts),
                             tuple(p for _, p in parts)))
    return sets[0], sets[1]


def decide(snapshots: list[Snapshot], method: str, association: Association,
           model: association_net.AssociationNet | None, keep_probability: float) -> list[Decision]:
    """Each snapshot's pairs by `method`'s associator (`pipeline.association.registry`, module docstring), given
    as many of the latest common times of the snapshot's scenario as it reads, continued with memory
    (`association_memory`, keep gate at `keep_probability`); no pair where a user has no track. `model` is read
    by `network` only."""
    associator = registry.associator(method, association, model)
    decisions = []
    for index, snapshot in enumerate(snapshots):
        if not len(snapshot.ids[0]) or not len(snapshot.ids[1]):
            decisions.append(Decision(np.zeros((0, 2), dtype=np.int64), None))
            continue
        decision = associator.associate_tracks(*track_sets(_recent(snapshots, index, associator.common_times)))
        decisions.append(replace(decision, pairs=np.asarray(decision.pairs, dtype=np.int64).reshape(-1, 2)))
    continued = with_memory(snapshots, [d.pairs for d in decisions], [d.bias_m for d in decisions], keep_probability,
                            [d.time_offset_s for d in decisions])
    return [replace(decision, pairs=pairs) for pairs, decision in zip(continued, decisions)]


def _scenario_column(scenario_id: int, count: int) -> pa.Array:
    return pa.array(np.full(count, scenario_id, np.int32), mask=np.full(count, scenario_id == NO_SCENARIO))


def _ids_column(ids: np.ndarray, present: np.ndarray) -> pa.Array:
    return pa.array(ids, type=pa.int64(), mask=~present)


def pairs_table(snapshots: list[Snapshot], decisions: list[Decision]) -> pa.Table:
    """PAIRS_SCHEMA rows: every pair of every common time, with its statistic and the offset estimate."""
    parts = []
    for snapshot, decision in zip(snapshots, decisions):
        rows, columns = decision.pairs[:, 0], decision.pairs[:, 1]
        x1, p1 = horizontal(snapshot.states[0][rows], snapshot.covariances[0][rows])
        x2, p2 = horizontal(snapshot.states[1][columns], snapshot.covariances[1][columns])
        x2 = registered(x2, decision.bias_m, decision.time_offset_s)
        statistic = np.diagonal(statistical_distances(x1, p1, x2, p2)) if len(rows) else np.zeros(0)
        count = len(rows)
        bias = np.full((count, 2), np.nan) if decision.bias_m is None else np.tile(decision.bias_m, (count, 1))
        offset = np.full(count, np.nan if decision.time_offset_s is None else decision.time_offset_s)
        parts.append(pa.Table.from_pydict({
            "scenario_id": _scenario_column(snapshot.scenario_id, count),
            "time_unix_s": np.full(count, snapshot.time), "track_id_1": snapshot.ids[0][rows],
            "track_id_2": snapshot.ids[1][columns], "statistic": statistic,
            "bias_east_m": pa.array(bias[:, 0], mask=np.isnan(bias[:, 0])),
            "bias_north_m": pa.array(bias[:, 1], mask=np.isnan(bias[:, 1])),
            "time_offset_s": pa.array(offset, mask=np.isnan(offset))}, schema=PAIRS_SCHEMA))
    return pa.concat_tables(parts) if parts else PAIRS_SCHEMA.empty_table()


def picture(snapshot: Snapshot, decision: Decision, criterion: str) -> tuple[np.ndarray, ...]:
    """One time's picture: source index (R,), track ids (R, 2) (-1 where none), states (R, 6), covariances
    (R, 6, 6), weights (R,) (NaN for unpaired rows); fused pairs first, then each user's unpaired tracks."""
    (x1, x2), (p1, p2), pairs = snapshot.states, snapshot.covariances, decision.pairs
    x2 = registered(x2, decision.bias_m, decision.time_offset_s)
    fused, fused_covariances, weights = fuse_pairs(x1, p1, x2, p2, pairs, criterion)
    alone = [np.setdiff1d(np.arange(len(x)), pairs[:, user]) for user, x in enumerate((x1, x2))]
    ids = np.full((len(pairs) + len(alone[0]) + len(alone[1]), 2), -1, dtype=np.int64)
    ids[:len(pairs)] = np.stack([snapshot.ids[0][pairs[:, 0]], snapshot.ids[1][pairs[:, 1]]], axis=1)
    ids[len(pairs):len(pairs) + len(alone[0]), 0] = snapshot.ids[0][alone[0]]
    ids[len(pairs) + len(alone[0]):, 1] = snapshot.ids[1][alone[1]]
    source = np.repeat([0, 1, 2], [len(pairs), len(alone[0]), len(alone[1])])
    states = np.concatenate([fused, x1[alone[0]], x2[alone[1]]])
    covariances = np.concatenate([fused_covariances, p1[alone[0]], p2[alone[1]]])
    return source, ids, states, covariances, np.concatenate([weights, np.full(len(source) - len(pairs), np.nan)])


def fused_table(snapshots: list[Snapshot], decisions: list[Decision], frame: Frame, criterion: str) -> pa.Table:
    """FUSED_SCHEMA rows: the fused air picture at every common time (module docstring)."""
    parts = []
    for snapshot, decision in zip(snapshots, decisions):
        source, ids, states, covariances, weights = picture(snapshot, decision, criterion)
        position = frame.origin + states[:, :3] @ frame.rotation
        ecef_covariance = frame.rotation.T @ covariances[:, :3, :3] @ frame.rotation
        latitude, longitude, altitude = geodesy.ecef_to_geodetic(position)
        count = len(source)
        parts.append(pa.Table.from_pydict({
            "scenario_id": _scenario_column(snapshot.scenario_id, count), "time_unix_s": np.full(count, snapshot.time),
            "source": [SOURCES[s] for s in source], "track_id_1": _ids_column(ids[:, 0], ids[:, 0] >= 0),
            "track_id_2": _ids_column(ids[:, 1], ids[:, 1] >= 0), "x_ecef_m": position[:, 0],
            "y_ecef_m": position[:, 1], "z_ecef_m": position[:, 2], "latitude_deg": np.atleast_1d(latitude),
            "longitude_deg": np.atleast_1d(longitude), "altitude_m": np.atleast_1d(altitude),
            "v_east_mps": states[:, 3], "v_north_mps": states[:, 4], "v_up_mps": states[:, 5],
            **covariance_columns(ecef_covariance), "weight_1": pa.array(weights, mask=np.isnan(weights))},
            schema=FUSED_SCHEMA))
    return pa.concat_tables(parts) if parts else FUSED_SCHEMA.empty_table()

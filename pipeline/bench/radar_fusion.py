"""Two radars, one air picture (issue 19): the multi-target scenes seen by both radars of params `fusion`, each
radar tracked alone, their tracks associated by each method and fused, and every picture scored by GOSPA.

Per scene (the first `fusion.scenes` of `scenes.plan_scene`, planned around params' `radar`):
1. Each radar simulates the scene (`scenes.simulate_scene` with params' `radar` replaced by it and
   `simulate.seed` by the radar's seed, so the radars' detections, noise and clutter are independent);
   plots are tagged with the radar's id. Its registration bias is applied as a radar has it: every measured
   range is `bias_range_m` long and azimuth `bias_azimuth_deg` clockwise, and the tracker converts the
   plots from a site `bias_east_m`, `bias_north_m` away from the true one (the radar's surveyed position
   is wrong).
2. Each radar's plots alone are tracked with `fusion.tracker` (`pipeline.tracker.recording.track_recording`, the `track`
   command's code), giving a track table with position covariances.
3. Both tables at common times (`common_time_states`, params `associate`), associated by each of
   `fusion.methods` with memory (`table_association.decide`, `association_memory`) and by the oracle (a pair when both tracks' majority target, over their confirmed
   updates' plots, is the same aircraft), then fused (`table_association.picture`).
4. GOSPA (`gospa.gospa`, cutoff and order of params `evaluate`) at each common time between the truth and
   each picture: radar 1's tracks alone, radar 2's alone, each method's fused picture, the oracle's. The
   truth at a time is the aircraft some radar has detected within the last `associate.max_age_s`
   (positions from the route's trajectory, `simulate.trajectory_of`), in the common ENU frame, 3-D. GOSPA is
   also split into its localisation, missed and false shares (`gospa.shares_in_metres`, m, summing to it).
   And each picture's track switches and tracks per truth (`gospa.track_switches`, `gospa.tracks_per_truth`
   over the GOSPA assignments): a radar's track is its local track id, a fused picture's row its system track
   number (`system_tracks`: it lives while either of its local tracks does), so both mean the same for a
   fused picture as for one radar.
Association is scored against the oracle's pairs: accuracy = correct / oracle pairs, false and missed pairs.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa

from pipeline.association import association_net, table_association
from pipeline.association.associator import Decision
from pipeline.association.common_time_states import Frame, Snapshot, common_frame, common_snapshots
from pipeline.association.system_tracks import SystemTracks
from pipeline.association.track_tables import CONFIRMED, TrackTable, track_table
from pipeline.bench import gospa
from pipeline.geometry import geodesy
from pipeline.params import FusionRadar, Params, Radar
from pipeline.recordings.plot_table import NO_TARGET, PLOT_INPUT_SCHEMA, plot_table
from pipeline.simulation import scenes, simulate
from pipeline.surveillance import scorecard
from pipeline.tracker.recording import track_recording

log = logging.getLogger("pipeline")
ORACLE = "oracle"


def believed_radar(fusion_radar: FusionRadar) -> Radar:
    """The radar as its tracker believes it: its site moved by the position bias (east, north in its ENU)."""
    radar = fusion_radar.radar
    latitude, longitude, _ = geodesy.local_to_geodetic(np.array([fusion_radar.bias_east_m]),
                                                       np.array([fusion_radar.bias_north_m]),
                                                       np.array([radar.height_m]), radar)
    return dataclasses.replace(radar, latitude_deg=float(latitude[0]), longitude_deg=float(longitude[0]))


def radar_plots(params: Params, fusion_radar: FusionRadar, scene_id: int, routes: pa.Table) -> pa.Table:
    """One radar's plots of a scene (PLOT_INPUT_SCHEMA, time order, plot ids radar_id * 10⁷ + row), biased."""
    own = dataclasses.replace(params, radar=fusion_radar.radar, simulate_seed=fusion_radar.seed)
    plots, _ = scenes.simulate_scene(own, scene_id, routes)
    order = np.argsort(plots["time_unix_s"], kind="stable")
    count = len(order)
    radar_id = fusion_radar.radar.radar_id
    return pa.Table.from_pydict({
        "plot_id": radar_id * 10_000_000 + np.arange(count, dtype=np.int64),
        "radar_id": np.full(count, radar_id, np.int32), "time_unix_s": plots["time_unix_s"][order],
        "range_m": plots["range_m"][order] + fusion_radar.bias_range_m,
        "azimuth_deg": np.mod(plots["azimuth_deg"][order] + fusion_radar.bias_azimuth_deg, 360.0),
        "altitude_m": plots["altitude_m"][order], "scenario_id": plots["scenario_id"][order].astype(np.int32),
        "target_id": plots["target_id"][order].astype(np.int32)}, schema=PLOT_INPUT_SCHEMA)


def majority_targets(tracks: pa.Table, plots: pa.Table) -> dict[int, int]:
    """Each confirmed track's most frequent target over its confirmed updates' plots (NO_TARGET for clutter)."""
    target_of = dict(zip(plots.column("plot_id").to_pylist(), plots.column("target_id").to_pylist()))
    confirmed = np.asarray(tracks.column("status").to_pylist()) == CONFIRMED
    track_ids = tracks.column("track_id").to_numpy()[confirmed]
    targets = np.array([target_of[p] for p in tracks.column("plot_id").to_numpy()[confirmed]], dtype=np.int64)
    out = {}
    for track_id in np.unique(track_ids):
        values, counts = np.unique(targets[track_ids == track_id], return_counts=True)
        out[int(track_id)] = int(values[np.argmax(counts)])
    return out


def oracle_pairs(snapshot: Snapshot, targets: tuple[dict[int, int], dict[int, int]]) -> np.ndarray:
    """Pairs (K, 2) of rows whose tracks follow the same aircraft (module docstring)."""
    first = np.array([targets[0][int(i)] for i in snapshot.ids[0]], dtype=np.int64)
    second = np.array([targets[1][int(j)] for j in snapshot.ids[1]], dtype=np.int64)
    rows, columns = np.nonzero((first[:, None] == second[None, :]) & (first[:, None] != NO_TARGET))
    return np.stack([rows, columns], axis=1).astype(np.int64)


def truth_at(truth: scorecard.Truth, time: float, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """GOSPA's truth at common time `time`: the ids (T,) and ENU positions (T, 3) of the scene's aircraft in
    coverage then (`scene_truth`: detected by some radar within `associate.max_age_s` before)."""
    rows = (truth.time_s == time) & truth.in_coverage
    return truth.target_id[rows], (truth.position[rows].reshape(-1, 3) - frame.origin) @ frame.rotation.T


class PictureScore:
    """A picture's GOSPA and its shares summed over common times, the (time, truth, identity) pairs its
    assignments made, for the track switches and tracks per truth, and its rows at every common time for the
    surveillance scorecard (`card`)."""

    def __init__(self) -> None:
        self.gospa_sum = 0.0
        self.shares_sum = np.zeros(len(gospa.PARTS))
        self.assigned: list[np.ndarray] = []
        self.rows: list[tuple[np.ndarray, float, np.ndarray]] = []  # (identities (K,), time, ENU states (K, 6))
        self.card: scorecard.Parts | None = None

    def add(self, time_index: int, truth_ids: np.ndarray, truth: np.ndarray, identity: np.ndarray,
            states: np.ndarray, time: float, params: Params) -> None:
        """One common time `time` (Unix s): truths (T,) at (T, 3), the picture's identities (K,) with their ENU
        states (K, 6) (position m, velocity m/s)."""
        distances = np.linalg.norm(truth[:, None] - states[None, :, :3], axis=-1)
        parts, rows, columns = gospa.gospa_parts(distances, params.evaluate.gospa_cutoff_m, params.evaluate.gospa_order)
        self.gospa_sum += float(parts.sum() ** (1.0 / params.evaluate.gospa_order))
        self.shares_sum += gospa.shares_in_metres(parts[None], params.evaluate.gospa_order)[0]
        self.assigned.append(np.column_stack([np.full(len(rows), time_index), truth_ids[rows], identity[columns]]))
        self.rows.append((identity, time, states[:, :6]))

    def continuity(self) -> np.ndarray:
        """[track switches summed over truths, distinct (truth, track) pairs, truths ever assigned]."""
        assigned = np.concatenate(self.assigned) if self.assigned else np.zeros((0, 3), dtype=np.int64)
        truths = np.unique(assigned[:, 1])
        switches = gospa.track_switches(assigned[:, 1], assigned[:, 0], assigned[:, 2], truths)
        return np.array([switches.sum(), gospa.tracks_per_truth(assigned[:, 1], assigned[:, 2], truths).sum(),
                         len(truths)], dtype=np.int64)

    def score_card(self, truth: scorecard.Truth, frame: Frame, params: Params) -> None:
        """The scorecard's parts (`scorecard.parts`, params' `scorecard`) of the picture's rows, every one a
        confirmed update of its identity, against the scene's `truth` (`scene_truth`), the update interval
        `associate.step_s` (the picture is only seen at common times); the rows' memory is released."""
        identities = np.concatenate([ids for ids, _, _ in self.rows]) if self.rows else np.zeros(0, dtype=np.int64)
        times = np.concatenate([np.full(len(ids), time) for ids, time, _ in self.rows]) if self.rows else np.zeros(0)
        states = np.concatenate([state for _, _, state in self.rows]) if self.rows else np.zeros((0, 6))
        updates = scorecard.TrackUpdates(identities, times, frame.origin + states[:, :3] @ frame.rotation,
                                         states[:, 3:6] @ frame.rotation, np.ones(len(identities), dtype=bool))
        self.card = scorecard.parts(updates, truth, scorecard.Settings.from_params(params.associate.step_s,
                                                                                   params.scorecard))
        self.rows = []


def scene_truth(routes: pa.Table, detections: tuple[np.ndarray, np.ndarray], times: list[float], max_age_s: float
                ) -> scorecard.Truth:
    """The scorecard's truth of a scene at its common `times`: every aircraft whose route spans a time, at its
    ECEF position, in coverage where some radar detected it within `max_age_s` before (what GOSPA scores
    against at each time, `truth_at`)."""
    target, plot_time = detections
    ids, at, positions, covered = [], [], [], []
    for route in simulate.routes_by_id(routes):
        aircraft = int(route["route_id"][0])
        spanned = np.array([t for t in times if route["time_unix_s"][0] <= t <= route["time_unix_s"][-1]])
        if not len(spanned):
            continue
        seen = plot_time[target == aircraft]
        ids.append(np.full(len(spanned), aircraft, dtype=np.int64))
        at.append(spanned)
        positions.append(np.asarray(simulate.trajectory_of(route)(spanned)).reshape(-1, 3))
        covered.append(np.array([bool(np.any((seen <= t) & (seen >= t - max_age_s))) for t in spanned.tolist()]))
    if not ids:
        return scorecard.Truth(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros(0, dtype=bool))
    return scorecard.Truth(np.concatenate(ids), np.concatenate(at), np.concatenate(positions), np.concatenate(covered))


def _pair_counts(found: np.ndarray, oracle: np.ndarray) -> np.ndarray:
    """[correct, false, missed] pair counts of `found` against the oracle's pairs."""
    got, true = set(map(tuple, found.tolist())), set(map(tuple, oracle.tolist()))
    return np.array([len(got & true), len(got - true), len(true - got)])


class RadarTracks(NamedTuple):
    """One radar's view of a scene: its track table, each confirmed track's majority target, and its
    detections (target ids (D,), plot times (D,) s)."""

    table: TrackTable
    targets: dict[int, int]
    detections: tuple[np.ndarray, np.ndarray]


def radar_tracks(params: Params, fusion_radar: FusionRadar, scene_id: int, routes: pa.Table, models_dir: Path
                 ) -> RadarTracks:
    """One radar's track table of the scene of `routes`, tracked with `fusion.tracker`, each track's majority
    target, and its detections."""
    plots = radar_plots(params, fusion_radar, scene_id, routes)
    believed = believed_radar(fusion_radar)
    recording = plot_table(plots, {fusion_radar.radar.radar_id: believed}, f"scene {scene_id}")
    tracks = track_recording(recording, params.fusion.tracker, params.fusion.window_m, params, models_dir)
    radar_id = fusion_radar.radar.radar_id
    table = track_table(tracks, {radar_id: geodesy.radar_site_ecef(believed)},
                        Path(f"scene {scene_id} radar {radar_id} tracks"), params.associate.max_speed_mps,
                        {radar_id: believed.scan_period_s})
    return RadarTracks(table, majority_targets(tracks, plots), (plots.column("target_id").to_numpy(),
                                                                plots.column("time_unix_s").to_numpy()))


def scene_scores(params: Params, scene_id: int, routes: pa.Table, tracked: list[RadarTracks],
                 model: association_net.AssociationNet | None) -> tuple[dict[str, PictureScore], dict[str, np.ndarray]]:
    """One scene's score of each picture ("radar_<id>", "fused_<method>", "fused_oracle") and counts: "pairs_<method>"
    ([correct, false, missed]), "oracle_pairs" and "times" (the common times), from each radar's tracks of the
    scene's `routes` (`radar_tracks`, in `fusion.radars` order)."""
    tables, targets = [radar.table for radar in tracked], [radar.targets for radar in tracked]
    detected = tuple(np.concatenate(parts) for parts in zip(*(radar.detections for radar in tracked)))
    frame = common_frame(*tables)
    snapshots = common_snapshots(*tables, frame, params.associate)
    decisions = {method: table_association.decide(snapshots, method, params.association, model,
                                                    params.associate.keep_probability)
                 for method in params.fusion.methods}
    decisions[ORACLE] = [Decision(oracle_pairs(s, (targets[0], targets[1])), None) for s in snapshots]
    radar_names = [f"radar_{r.radar.radar_id}" for r in params.fusion.radars]
    pictures = {name: PictureScore() for name in [*radar_names, *(f"fused_{m}" for m in decisions)]}
    counts: dict[str, np.ndarray] = {"times": np.array(len(snapshots)), "oracle_pairs": np.array(0),
                                     **{f"pairs_{m}": np.zeros(3, dtype=np.int64) for m in params.fusion.methods}}
    numbering = {method: SystemTracks() for method in decisions}
    truth = scene_truth(routes, detected, [snapshot.time for snapshot in snapshots], params.associate.max_age_s)
    for index, snapshot in enumerate(snapshots):
        truth_ids, positions = truth_at(truth, snapshot.time, frame)
        for name, ids, states in zip(radar_names, snapshot.ids, snapshot.states):
            pictures[name].add(index, truth_ids, positions, ids, states, snapshot.time, params)
        oracle = decisions[ORACLE][index].pairs
        for method, made in decisions.items():
            _, ids, states, _, _ = table_association.picture(snapshot, made[index], params.associate.fusion_criterion)
            system_numbers = numbering[method].number(snapshot.scenario_id, ids)
            pictures[f"fused_{method}"].add(index, truth_ids, positions, system_numbers, states, snapshot.time, params)
            if method != ORACLE:
                counts[f"pairs_{method}"] += _pair_counts(made[index].pairs, oracle)
        counts["oracle_pairs"] += len(oracle)
    for score in pictures.values():
        score.score_card(truth, frame, params)
    log.info("fusion: scene %d, %d common times, %d oracle pairs", scene_id, len(snapshots),
             int(counts["oracle_pairs"]))
    return pictures, counts


def fusion_report(params: Params, scored: list[tuple[dict[str, PictureScore], dict[str, np.ndarray]]]) -> dict:
    """reports/fusion.json from every scene's `scene_scores`, in scene order: per picture the mean GOSPA (m) per
    common time and its localisation, missed and false shares (m), the track switches (summed over scenes) and
    tracks per truth (mean over the truths of every scene); each fused picture's GOSPA relative to the better
    radar's; per method association accuracy, false and missed pairs against the oracle's; per picture the
    surveillance scorecard (`scorecard.combined` of its scenes' parts, `PictureScore.score_card`)."""
    gospa_sums: dict[str, float] = {}
    shares: dict[str, np.ndarray] = {}
    continuity: dict[str, np.ndarray] = {}
    totals: dict[str, np.ndarray] = {}
    for pictures, counts in scored:
        for name, score in pictures.items():
            gospa_sums[name] = gospa_sums.get(name, 0.0) + score.gospa_sum
            shares[name] = shares.get(name, 0.0) + score.shares_sum
            continuity[name] = continuity.get(name, 0) + score.continuity()
        for key, value in counts.items():
            totals[key] = totals.get(key, 0) + value
    times = max(int(totals["times"]), 1)
    mean_gospa = {name: value / times for name, value in sorted(gospa_sums.items())}
    better = min(value for name, value in mean_gospa.items() if name.startswith("radar_"))
    oracle_pairs_count = max(int(totals["oracle_pairs"]), 1)
    association = {method: {"accuracy": float(totals[f"pairs_{method}"][0]) / oracle_pairs_count,
                            "false_pairs": int(totals[f"pairs_{method}"][1]),
                            "missed_pairs": int(totals[f"pairs_{method}"][2])} for method in params.fusion.methods}
    return {"scenes": params.fusion.scenes, "common_times": int(totals["times"]),
            "oracle_pairs": int(totals["oracle_pairs"]), "gospa_m": mean_gospa,
            "gospa_shares_m": {name: dict(zip(gospa.PARTS, (shares[name] / times).tolist()))
                               for name in sorted(shares)},
            "track_switches": {name: int(continuity[name][0]) for name in sorted(continuity)},
            "tracks_per_truth": {name: float(continuity[name][1]) / max(int(continuity[name][2]), 1)
                                 for name in sorted(continuity)},
            "fused_gospa_vs_better_radar": {name: value / better for name, value in mean_gospa.items()
                                            if name.startswith("fused_")},
            "association": association,
            "scorecard": {name: scorecard.combined([pictures[name].card for pictures, _ in scored])
                          for name in sorted(gospa_sums)}}

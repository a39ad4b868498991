"""Two radars, one air picture (issue 19): the multi-target scenes seen by both radars of params `fusion`, each
radar tracked alone, their tracks associated by each method and fused, and every picture scored by GOSPA.

Per scene (the first `fusion.scenes` of `scenes.plan_scene`, planned around params' `radar`):
1. Each radar simulates the scene (`scenes.simulate_scene` with params' `radar` replaced by it and
   `simulate.seed` by the radar's seed, so the radars' detections, noise and clutter are independent);
   plots are tagged with the radar's id. Its registration bias is applied as a radar has it: every measured
   range is `bias_range_m` long and azimuth `bias_azimuth_deg` clockwise, and the tracker converts the
   plots from a site `bias_east_m`, `bias_north_m` away from the true one (the radar's surveyed position
   is wrong).
2. Each radar's plots alone are tracked with `fusion.tracker` (`track_command.track_recording`, the `track`
   command's code), giving a track table with position covariances.
3. Both tables at common times (`common_time_states`, params `associate`), associated by each of
   `fusion.methods` and by the oracle (a pair when both tracks' majority target, over their confirmed
   updates' plots, is the same aircraft), then fused (`table_association.picture`).
4. GOSPA (`gospa.gospa`, cutoff and order of params `evaluate`) at each common time between the truth and
   each picture: radar 1's tracks alone, radar 2's alone, each method's fused picture, the oracle's. The
   truth at a time is the aircraft some radar has detected within the last `associate.max_age_s`
   (positions from the route's trajectory, `simulate.trajectory_of`), in the common ENU frame, 3-D.
Association is scored against the oracle's pairs: accuracy = correct / oracle pairs, false and missed pairs.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import association_net, geodesy, gospa, scenes, simulate, table_association
from pipeline.common_time_states import Frame, Snapshot, common_frame, common_snapshots
from pipeline.params import FusionRadar, Params, Radar
from pipeline.plot_table import NO_TARGET, PLOT_INPUT_SCHEMA, plot_table
from pipeline.table_association import Decision
from pipeline.track_command import track_recording
from pipeline.track_tables import CONFIRMED, TrackTable, track_table

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


def truth_positions(routes: pa.Table, detections: tuple[np.ndarray, np.ndarray], time: float, max_age_s: float,
                    frame: Frame) -> np.ndarray:
    """(T, 3) ENU positions at `time` of the aircraft detected (target ids (D,), plot times (D,)) within
    `max_age_s` before it by some radar."""
    target, plot_time = detections
    seen = set(target[(plot_time <= time) & (plot_time >= time - max_age_s)].tolist())
    positions = []
    for route in simulate.routes_by_id(routes):
        aircraft = int(route["route_id"][0])
        if aircraft in seen and route["time_unix_s"][0] <= time <= route["time_unix_s"][-1]:
            positions.append(simulate.trajectory_of(route)(time))
    return (np.asarray(positions).reshape(-1, 3) - frame.origin) @ frame.rotation.T


def picture_gospa(truth: np.ndarray, estimates: np.ndarray, params: Params) -> float:
    """GOSPA (m) of one picture's positions (K, 3) against the truth (T, 3), params `evaluate`'s cutoff and order."""
    distances = np.linalg.norm(truth[:, None] - estimates[None], axis=-1)
    return gospa.gospa(distances, params.evaluate.gospa_cutoff_m, params.evaluate.gospa_order)


def _pair_counts(found: np.ndarray, oracle: np.ndarray) -> np.ndarray:
    """[correct, false, missed] pair counts of `found` against the oracle's pairs."""
    got, true = set(map(tuple, found.tolist())), set(map(tuple, oracle.tolist()))
    return np.array([len(got & true), len(got - true), len(true - got)])


def scene_scores(params: Params, scene_id: int, models_dir: Path,
                 model: association_net.AssociationNet | None) -> dict[str, np.ndarray]:
    """One scene's sums over its common times: "gospa_<picture>" (GOSPA summed), "pairs_<method>" ([correct,
    false, missed]), "oracle_pairs" and "times" (the count of common times)."""
    fusion = params.fusion
    routes = scenes.scene_routes(params, scene_id, scenes.plan_scene(params, scene_id))
    tables: list[TrackTable] = []
    targets: list[dict[int, int]] = []
    detections = []
    for fusion_radar in fusion.radars:
        plots = radar_plots(params, fusion_radar, scene_id, routes)
        believed = believed_radar(fusion_radar)
        recording = plot_table(plots, {fusion_radar.radar.radar_id: believed}, f"scene {scene_id}")
        tracks = track_recording(recording, fusion.tracker, fusion.window_m, params, models_dir)
        tables.append(track_table(tracks, {fusion_radar.radar.radar_id: geodesy.radar_site_ecef(believed)},
                                  Path(f"scene {scene_id} radar {fusion_radar.radar.radar_id} tracks")))
        targets.append(majority_targets(tracks, plots))
        detections.append((plots.column("target_id").to_numpy(), plots.column("time_unix_s").to_numpy()))
    frame = common_frame(*tables)
    snapshots = common_snapshots(*tables, frame, params.associate)
    detected = tuple(np.concatenate(parts) for parts in zip(*detections))
    decisions = {method: table_association.decide(snapshots, method, params.association, model)
                 for method in fusion.methods}
    decisions[ORACLE] = [Decision(oracle_pairs(s, (targets[0], targets[1])), None) for s in snapshots]
    radar_names = [f"radar_{r.radar.radar_id}" for r in fusion.radars]
    scores: dict[str, np.ndarray] = {"times": np.array(len(snapshots))}
    for index, snapshot in enumerate(snapshots):
        truth = truth_positions(routes, detected, snapshot.time, params.associate.max_age_s, frame)
        for name, states in zip(radar_names, snapshot.states):
            scores[f"gospa_{name}"] = scores.get(f"gospa_{name}", 0.0) + picture_gospa(truth, states[:, :3], params)
        oracle = decisions[ORACLE][index].pairs
        for method, made in decisions.items():
            states = table_association.picture(snapshot, made[index], params.associate.fusion_criterion)[2]
            key = f"gospa_fused_{method}"
            scores[key] = scores.get(key, 0.0) + picture_gospa(truth, states[:, :3], params)
            if method != ORACLE:
                scores[f"pairs_{method}"] = scores.get(f"pairs_{method}", 0) + _pair_counts(made[index].pairs, oracle)
        scores["oracle_pairs"] = scores.get("oracle_pairs", 0) + len(oracle)
    log.info("fusion: scene %d, %d common times, %d oracle pairs", scene_id, len(snapshots),
             int(scores.get("oracle_pairs", 0)))
    return scores


def fusion_report(params: Params, models_dir: Path, model: association_net.AssociationNet | None) -> dict:
    """reports/fusion.json: mean GOSPA (m) per common time of each picture; per method association accuracy,
    false and missed pairs against the oracle's; each fused picture's GOSPA relative to the better radar's."""
    totals: dict[str, np.ndarray] = {}
    for scene_id in range(params.fusion.scenes):
        for key, value in scene_scores(params, scene_id, models_dir, model).items():
            totals[key] = totals.get(key, 0) + value
    times = max(int(totals["times"]), 1)
    pictures = {key[len("gospa_"):]: float(value) / times for key, value in sorted(totals.items())
                if key.startswith("gospa_")}
    better = min(value for key, value in pictures.items() if key.startswith("radar_"))
    oracle_pairs_count = max(int(totals.get("oracle_pairs", 0)), 1)
    association = {method: {"accuracy": float(totals[f"pairs_{method}"][0]) / oracle_pairs_count,
                            "false_pairs": int(totals[f"pairs_{method}"][1]),
                            "missed_pairs": int(totals[f"pairs_{method}"][2])} for method in params.fusion.methods}
    return {"scenes": params.fusion.scenes, "common_times": int(totals["times"]),
            "oracle_pairs": int(totals.get("oracle_pairs", 0)), "gospa_m": pictures,
            "fused_gospa_vs_better_radar": {key: value / better for key, value in pictures.items()
                                            if key.startswith("fused_")},
            "association": association}

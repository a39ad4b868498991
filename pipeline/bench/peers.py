"""The field's peers on the same plots (issue 33), scored as air-traffic surveillance scores a tracker (issue 32).

Runs, each on every recording of every material:

- Stone Soup's trackers (`pipeline.peers.stone_soup`, one per `peers.stone_soup.associations`: `stone_soup_gnn`,
  `stone_soup_jpda`), on our tuned CV model and our chi-square gate;
- our runs (`peers.runs`, runs of `evaluate.runs`), each under its own track management rule;
- the registered references of `evaluate.references` (the oracle: the tuned IMM given each plot's aircraft).

Materials (`MATERIALS`):

- `test`: the first `peers.scenarios_per_strategy` scenarios of each route strategy of `evaluate.split` whose
  aircraft is in coverage in the window, each from its first plot for `peers.window_s` (the simulate stage's
  plots, one draw): Stone Soup tracks about 100 plots a second, so the whole split (285,000 plots) would take
  hours a tracker;
- `scenes`: the first `peers.scenes` many-aircraft scenes of the scenes stage whose aircraft are seen, each from
  its first plot for `peers.scene_window_s` (30 aircraft in crossings, formations and manoeuvres: where JPDA is
  the classical answer);
- `real_traffic`: the aircraft of the OpenSky recording `peers.real_traffic.states` flown past params' radar moved
  to `peers.real_traffic`'s site (`pipeline.simulation.real_traffic`), one scene from its first plot for
  `peers.window_s`; each stretch of an aircraft's reports is a target of its own (an aircraft silent for
  `real_traffic.GAP_S` is a new track for any tracker).

Every unit (run, recording) is tracked, timed and scored as the scenes are (`scene_evaluation.scene_result`), on
the confirmed updates (ours by the run's track management rule, Stone Soup's from the update that confirms a track,
`min_points`, on):

- GOSPA with its parts, track switches, tracks per truth, fragmentation and purity, the missed part split by cause
  (`scene_evaluation.missed_causes`: undetected, before the first track, after a track) and the false part
  (`scene_evaluation.false_causes`: clutter, duplicate, astray);
- the surveillance scorecard's parts (`pipeline.surveillance.scorecard`, params' `scorecard`, the update interval
  the radar's scan period) against the per-scan truth.

A run's metrics on a material pool its recordings (`run_metrics`); on `test` their 95 % intervals and the
paired intervals of `PAIRED` between runs resample the scenarios (`pipeline.bench.intervals`), and so on `scenes`
the scenes; the real-traffic
scene is one recording, so it has none. Units run on the bench's engine (`pipeline.bench.engine`), largest
first; results are put together by run and recording, never in the order they finish.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.bench import engine, evaluation, intervals, scene_evaluation
from pipeline.bench.runs import Run, record
from pipeline.bench.scene_evaluation import Scene, SceneResult
from pipeline.filters import classical_filters
from pipeline.params import STRATEGIES, Params, Radar
from pipeline.peers import stone_soup
from pipeline.progress import progress_logger
from pipeline.recordings import opensky_states, plot_table
from pipeline.simulation import real_traffic, routes, scenes, simulate
from pipeline.surveillance import scorecard
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.run import track
from pipeline.tracker.updates import confirmed_associations

log = logging.getLogger("pipeline")

TEST, SCENES, REAL_TRAFFIC = "test", "scenes", "real_traffic"
MATERIALS = (TEST, SCENES, REAL_TRAFFIC)
RESAMPLED = (TEST, SCENES)  # the materials of several recordings, with intervals
STONE_SOUP = "stone_soup"      # the family of Stone Soup's runs, and their names' prefix
STONE_SOUP_COST = 60.0         # a Stone Soup run's cost per plot against a classical run's 1.5 (units largest first)
REAL_TRAFFIC_FOLDER = "pipeline-real-traffic"
PAIRED = ("GOSPA", "GOSPA_missed", "position_rms_m", "probability_of_update", "ratio_of_long_gaps",
          "tracks_per_aircraft")  # the verdicts'
INTERVAL_METRICS = ("GOSPA", "GOSPA_localisation", "GOSPA_missed", "GOSPA_false", "GOSPA_missed_undetected",
                    "GOSPA_missed_initiation", "GOSPA_missed_after_track", "GOSPA_false_clutter",
                    "GOSPA_false_duplicate", "GOSPA_false_astray", "track_switches",
                    "tracks_per_truth", "probability_of_update", "ratio_of_long_gaps", "position_error_mean_m",
                    "position_error_sigma_m", "position_rms_m", "along_track_rms_m", "across_track_rms_m",
                    "velocity_rms_straight_mps", "velocity_rms_manoeuvring_mps", "straight_within_0_25_nm",
                    "manoeuvring_within_1_nm", "tracks_per_aircraft", "false_tracks", "initiation_mean_s")


@dataclass(frozen=True)
class PeerRun:
    """A run of the peers stage: its name (the reports' key), family (`STONE_SOUP`, or the registry's family of
    our method, `registry.REFERENCE` for a reference), our run's record (None for Stone Soup's) or Stone Soup's
    association (None for ours), and its cost per plot relative to the others (units largest first)."""

    name: str
    family: str
    run: Run | None
    association: str | None
    cost: float


def peer_runs(params: Params) -> list[PeerRun]:
    """Stone Soup's runs, then ours (`peers.runs`), then the registered references, in params order; Stone Soup's
    left out, with a warning, where it is not installed (`stone_soup.missing`)."""
    ours = [record(run) for run in (*params.peers.runs_of(params.evaluate), *params.evaluate.reference_runs())
            if run.method in registry.METHODS]
    why = stone_soup.missing()
    if why and params.peers.stone_soup.associations:
        log.warning("peers: %s", why)
    return ([PeerRun(f"{STONE_SOUP}_{association}", STONE_SOUP, None, association, STONE_SOUP_COST)
             for association in params.peers.stone_soup.associations if not why]
            + [PeerRun(run.name, run.family, run, None, run.registered.relative_cost) for run in ours])


@dataclass
class Recording:
    """One recording a run tracks: its material, the scene (plots, scans, the aircraft in coverage at each scan,
    their trajectories, and the truth the scorecard reads, `Scene.surveillance`), the simulator's detection
    probability at each of that truth's rows, and the radar."""

    material: str
    scene: Scene
    detection_probability: np.ndarray  # (T,) of each truth row
    radar: Radar

    @property
    def truth(self) -> scorecard.Truth:
        """Each scan's true position of every aircraft (`scorecard.Truth`)."""
        return self.scene.surveillance

    @property
    def update_interval_s(self) -> float:
        """The radar's scan period: the scorecard's update interval."""
        return 60.0 / self.radar.rotation_rpm


Flown = Callable[[int], tuple[dict[int, dict[str, np.ndarray]], dict[int, str]]]  # scenario id -> routes, roles


def _recordings(params: Params, material: str, folder: Path, flown: Flown,
                chosen: Callable[[dict[int, tuple[Scene, scorecard.Truth]]], list[int]],
                window_s: float) -> list[Recording]:
    """The recordings of the simulated files in `folder` (simulate's plots, truth and radar), each scenario from
    its first plot for `window_s` (0: whole); `flown` gives a scenario's targets' routes and roles by target id;
    `chosen` picks the scenario ids kept from every candidate's scene and truth."""
    table = io.read_parquet(folder / "plots.parquet", simulate.PLOT_SCHEMA)
    plots = plot_table.read_parquet_plots(folder / "plots.parquet", folder / "radar.parquet", params.radar)
    scan_of_plot = dict(zip(table.column("plot_id").to_numpy().tolist(), table.column("scan").to_numpy().tolist()))
    truth = io.read_parquet(folder / "truth.parquet", simulate.TRUTH_SCHEMA)
    column = {name: truth.column(name).to_numpy(zero_copy_only=False)
              for name in ("scenario_id", "target_id", "scan", "time_unix_s", "in_coverage", "detection_probability")}
    candidates, detection = {}, {}
    for scenario_id, part in plots.scenarios():
        end = part.time[0] + window_s if window_s > 0 else np.inf
        part = part.take(np.flatnonzero(part.time < end))
        mine = (column["scenario_id"] == scenario_id) & (column["time_unix_s"] < end)
        covered = mine & column["in_coverage"]
        order = np.lexsort((column["target_id"][covered], column["scan"][covered]))
        scans = np.array([scan_of_plot[p] for p in part.plot_id.tolist()], dtype=np.int64)
        targets = np.unique(column["target_id"][mine]).tolist()
        surveillance = evaluation.surveillance_truth(truth, mine)
        routes_of, roles = flown(scenario_id)
        scene = Scene(scenario_id, part, scans, np.unique(np.concatenate([scans, column["scan"][covered]])),
                      column["scan"][covered][order], column["target_id"][covered][order],
                      {t: scene_evaluation.clipped(routes_of[t]) for t in targets}, {t: roles[t] for t in targets},
                      surveillance=surveillance)
        candidates[scenario_id] = scene, surveillance
        detection[scenario_id] = column["detection_probability"][mine]
    return [Recording(material, candidates[scenario_id][0], detection[scenario_id], params.radar)
            for scenario_id in chosen(candidates)]


def test_recordings(params: Params, simulated_dir: Path, routes_dir: Path) -> list[Recording]:
    """The `test` material (module docstring): scenarios of `evaluate.split`, `peers.scenarios_per_strategy` of
    each strategy whose aircraft is in coverage within `peers.window_s`, in scenario id order."""
    split = params.evaluate.split
    route_table = io.read_parquet(routes_dir / f"{split}.parquet", routes.ROUTE_SCHEMA)
    flown = {int(route["route_id"][0]): route for route in simulate.routes_by_id(route_table)}
    strategy = dict(zip(route_table.column("route_id").to_pylist(), route_table.column("strategy").to_pylist()))

    def chosen(candidates: dict[int, tuple[Scene, scorecard.Truth]]) -> list[int]:
        seen = [s for s in sorted(candidates) if candidates[s][1].in_coverage.any()]
        return sorted(s for kind in STRATEGIES
                      for s in [s for s in seen if strategy[s] == kind][:params.peers.scenarios_per_strategy])

    return _recordings(params, TEST, simulated_dir / split, lambda scenario_id: (flown, strategy), chosen,
                       params.peers.window_s)


def scene_recordings(params: Params, scenes_dir: Path) -> list[Recording]:
    """The `scenes` material (module docstring): the first `peers.scenes` scenes of `scenes_dir` (the scenes stage's
    plots, truth, radar and routes) whose aircraft are seen, each from its first plot for `peers.scene_window_s`;
    none when `peers.scenes` is 0."""
    if not params.peers.scenes:
        return []
    route_table = io.read_parquet(scenes_dir / "routes.parquet", scenes.SCENE_ROUTE_SCHEMA)
    scene_of = route_table.column("scene_id").to_numpy()

    def flown(scene_id: int) -> tuple[dict[int, dict[str, np.ndarray]], dict[int, str]]:
        """A scene's aircraft (route ids repeat from scene to scene) and their roles."""
        own = route_table.filter(pa.array(scene_of == scene_id))
        return ({int(route["route_id"][0]): route for route in simulate.routes_by_id(own)},
                dict(zip(own.column("route_id").to_pylist(), own.column("strategy").to_pylist())))

    def chosen(candidates: dict[int, tuple[Scene, scorecard.Truth]]) -> list[int]:
        return [s for s in sorted(candidates) if candidates[s][1].in_coverage.any()][:params.peers.scenes]

    return _recordings(params, SCENES, scenes_dir, flown, chosen, params.peers.scene_window_s)


def real_traffic_recordings(params: Params, root: Path) -> list[Recording]:
    """The `real_traffic` material (module docstring): one recording, or none when `peers.real_traffic.states` is
    ''. The states file is read relative to `root` (the repository)."""
    site = params.peers.real_traffic
    if not site.states:
        return []
    states, _ = opensky_states.read_states(root / site.states)
    moved = real_traffic.at_site(params, site.latitude_deg, site.longitude_deg, site.height_m)
    flown = [{**route, "target_id": route["route_id"].astype(np.int32)} for route in real_traffic.routes_of(states)]
    plots, truth = real_traffic.simulate_scene(moved, flown)
    by_target = {int(route["route_id"][0]): route for route in flown}
    with io.temporary_folder(REAL_TRAFFIC_FOLDER) as folder:
        simulate.write_split(plots, truth, simulate.radar_description(moved), folder)
        return _recordings(moved, REAL_TRAFFIC, folder, lambda scenario_id: (by_target,
                                                                           dict.fromkeys(by_target, REAL_TRAFFIC)),
                           lambda candidates: [s for s in sorted(candidates) if candidates[s][1].in_coverage.any()],
                           params.peers.window_s)


Tracked = tuple[dict[str, np.ndarray], np.ndarray]  # the updates (with `velocity`) and which are confirmed


@dataclass
class PeerBench:
    """What every unit reads: params, the recordings of every material, each run as name -> track(recording)
    (`Tracked`); and what worker processes prepare their own copy from (`prepare`'s arguments)."""

    params: Params
    arguments: tuple
    recordings: list[Recording]
    runs: dict[str, Callable[[Recording], Tracked]]
    peers: list[PeerRun]
    tuned: dict[str, classical_filters.FilterSettings]  # the tuned classical filters, by kind: the bound's models


def _tracker(params: Params, models, peer: PeerRun, cv: classical_filters.FilterSettings
             ) -> Callable[[Recording], Tracked]:
    """The run `peer` as recording -> (updates, confirmed)."""
    if peer.association is not None:
        settings = stone_soup.StoneSoupSettings.from_params(peer.association, params.peers.stone_soup, cv,
                                                            params.tracker.association.kalman_gate_probability)

        def stone_soup_run(recording: Recording) -> Tracked:
            updates = stone_soup.track_with_stone_soup(recording.scene.plots, settings)
            return updates, updates["confirmed"]
        return stone_soup_run
    run, rule = peer.run, evaluation.run_rule(params, peer.run)

    def our_run(recording: Recording) -> Tracked:
        plots = recording.scene.plots
        if run.reference:  # the oracle: the aircraft's plots alone, with their true association
            plots = plots.take(np.flatnonzero(plots.target_id != plot_table.NO_TARGET))
        composed = registry.compose(run.method, models, params.tracker, run.window_m,
                                    evaluation.tracker_seed(params, recording.scene), run.management)
        updates = track(plots, dataclasses.replace(composed, records_velocity=True))
        return updates, confirmed_associations(updates, rule)
    return our_run


def prepare(params: Params, simulated_dir: Path, routes_dir: Path, scenes_dir: Path, models_dir: Path, root: Path
            ) -> PeerBench:
    """The recordings of every material and every run (`peer_runs`), with what the runs need loaded."""
    peers = peer_runs(params)
    models = load_models(models_dir, params, [peer.run.method for peer in peers if peer.run is not None],
                         [None, *(peer.run.management for peer in peers if peer.run is not None)])
    cv = classical_filters.load_settings(models_dir / "kalman_tuned.json")["cv"]
    recordings = (test_recordings(params, simulated_dir, routes_dir) + scene_recordings(params, scenes_dir)
                  + real_traffic_recordings(params, root))
    return PeerBench(params, (params, simulated_dir, routes_dir, scenes_dir, models_dir, root), recordings,
                     {peer.name: _tracker(params, models, peer, cv) for peer in peers}, peers,
                     classical_filters.load_settings(models_dir / "kalman_tuned.json"))


def evaluate_unit(bench: PeerBench, name: str, index: int) -> SceneResult:
    """Track recording `index` (position in `bench.recordings`) with run `name`, and score it
    (`scene_evaluation.scene_result`: GOSPA with its parts by cause, the scorecard at the radar's scan period)."""
    recording = bench.recordings[index]
    start = time.perf_counter()
    updates, confirmed = bench.runs[name](recording)
    seconds = time.perf_counter() - start
    return scene_evaluation.scene_result(bench.params, recording.scene, updates, confirmed, seconds,
                                         update_interval_s=recording.update_interval_s)


def run_metrics(results: list[SceneResult], plots: int) -> dict[str, float]:
    """A run's metrics over the recordings of `results` (`scene_evaluation.run_metrics`: the scenes' metrics, the
    missed and false parts by cause, the scorecard's indicators), the recordings pooled; `plots` is theirs, for
    the speed."""
    return scene_evaluation.run_metrics(results, plots)


def metric_intervals(params: Params, recordings: list[Recording], units: dict[str, list[SceneResult]]) -> dict:
    """The intervals of INTERVAL_METRICS of every run and of the differences of PAIRED between runs over
    `recordings` (one material's), resampling the recordings (`intervals.run_intervals`)."""
    chosen = params.evaluate
    return intervals.run_intervals(units, lambda results: run_metrics(results, 0), INTERVAL_METRICS, PAIRED,
                                   chosen.bootstrap_replicates, chosen.confidence, chosen.bootstrap_seed,
                                   [recording.scene.scenario_id for recording in recordings])


def evaluate_all(bench: PeerBench, workers: int) -> dict[str, dict[str, list[SceneResult]]]:
    """Every run over every recording on `workers` workers (`engine.completed_units`): by material, by run name
    (in `bench.peers` order), each run's results in recording order."""
    recordings, cost = bench.recordings, {peer.name: peer.cost for peer in bench.peers}
    units = sorted(((peer.name, index) for peer in bench.peers for index in range(len(recordings))),
                   key=lambda unit: -cost[unit[0]] * len(recordings[unit[1]].scene.plots))
    workers = max(1, min(workers, len(units)))
    done_units: dict[tuple[str, int], SceneResult] = {}
    report = progress_logger(f"peers ({engine.where(workers)})")
    for done, ((name, index), result) in enumerate(engine.completed_units(
            units, workers, evaluate_unit, bench, prepare, bench.arguments), start=1):
        done_units[name, index] = result
        report(done, len(units))
    return {material: {peer.name: [done_units[peer.name, index] for index, recording in enumerate(recordings)
                                   if recording.material == material] for peer in bench.peers}
            for material in MATERIALS if any(recording.material == material for recording in recordings)}

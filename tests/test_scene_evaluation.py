"""Trackers on multi-target scenes (`pipeline.bench.scene_evaluation`, stage `evaluate_scenes`): scripted
scenes of two aircraft, and the stage on a tiny generated scene. Only the classical trackers and
the oracle, with the filters at params' start values (no network needed)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow.compute as pc
import pytest

from pipeline import io
from pipeline.bench import scene_evaluation
from pipeline.bench.gospa import ScanGospa
from pipeline.bench.runs import declared_runs, with_records
from pipeline.reports import comparison_tables
from pipeline.simulation import routes, scenes, simulate
from pipeline.simulation.routes import PlannedRoute
from pipeline.stages.evaluate_scenes_stage import run_evaluate_scenes
from pipeline.tracker.updates import confirmed_associations
from tests import tracker_fixtures as tf

SCENE_S = 600.0
CLASSICAL = {"evaluate.runs": [{"method": "kalman_cv", "window_m": 4000.0}, {"method": "imm_gnn", "window_m": 4000.0}],
             "evaluate.site_runs": [], "evaluate.scene_runs": [], "evaluate.example_run": "imm_gnn_4000",
             "evaluate.references": ["plots", "oracle"], "compute.workers": 1}


def straight(east_m: float, north_m: float, heading_deg: float, speed_mps: float = 220.0,
             altitude_m: float = 9000.0) -> PlannedRoute:
    """Straight and level flight over the whole scene from (east, north) m on the radar's plane."""
    return PlannedRoute(SCENE_S, routes.coordinated_turns(np.array([east_m, north_m, altitude_m]),
                                                          np.radians(heading_deg), speed_mps, np.zeros(1), np.zeros(1)))


def scripted_scene(folder: Path, params, flights: list[PlannedRoute]) -> Path:
    """One scene (id 0) of airliners flying `flights`, simulated and written as the scenes stage writes."""
    airliner = params.aircraft["airliner"]
    table = scenes.scene_routes(params, 0, [scenes.SceneAircraft(planned, 0.0, airliner, scenes.CROSSING)
                                            for planned in flights])
    plots, truth = simulate.tables(*([part] for part in scenes.simulate_scene(params, 0, table)))
    io.write_parquet(table, folder / "routes.parquet")
    simulate.write_split(plots, truth, simulate.radar_description(params), folder)
    return folder


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    return tf.write_tuned_filters(tmp_path_factory.mktemp("models"), tf.make_params())


def test_the_oracle_has_no_switch_where_two_aircraft_cross(tmp_path, models):
    """Two airliners at one altitude crossing at 15 deg, both at the crossing point 300 s into the
    scene (so within a few hundred metres of each other for several scans), with the radar's
    clutter: the oracle keeps each aircraft on one track, no switch; every aircraft in coverage."""
    params = tf.make_params({**CLASSICAL, "scenes.duration_s": SCENE_S})
    meet = np.array([60000.0, 80000.0])
    flights = [straight(*(meet - 220.0 * 300.0 * np.array([np.sin(np.radians(h)), np.cos(np.radians(h))])), h)
               for h in (40.0, 55.0)]
    evaluation = scene_evaluation.prepare(params, scripted_scene(tmp_path, params, flights), models)
    scene = evaluation.scenes[0]
    gap = np.linalg.norm(scene.trajectories[0](scene.plots.time) - scene.trajectories[1](scene.plots.time), axis=1)
    assert gap.min() < 100.0 and set(scene.truth_id.tolist()) == {0, 1}
    result = scene_evaluation.evaluate_unit(evaluation, declared_runs(params)["oracle_reference"], 0)
    assert result.track_switches == 0
    assert result.tracks_per_truth.tolist() == [1, 1] and (result.track_purity == 1.0).all()


def test_a_formation_1_km_apart_gives_two_confirmed_tracks_with_gnn(tmp_path, models):
    """Two airliners line abreast 1 km apart for 10 minutes, no clutter: the classical GNN tracker
    (IMM + GNN, filters at params' start values) confirms exactly two tracks, one per aircraft."""
    params = tf.make_params({**CLASSICAL, "scenes.duration_s": SCENE_S, "radar.false_plots_per_scan": 0.0})
    flights = [straight(50000.0, 90000.0, 120.0), straight(50000.0 + 1000.0 * np.cos(np.radians(120.0)),
                                                           90000.0 - 1000.0 * np.sin(np.radians(120.0)), 120.0)]
    evaluation = scene_evaluation.prepare(params, scripted_scene(tmp_path, params, flights), models)
    scene = evaluation.scenes[0]
    np.testing.assert_allclose(np.linalg.norm(scene.trajectories[0](scene.plots.time)
                                              - scene.trajectories[1](scene.plots.time), axis=1), 1000.0, rtol=2e-3)
    run = declared_runs(params)["imm_gnn_4000"]
    updates = evaluation.runs[run](scene)
    confirmed = confirmed_associations(updates, evaluation.management[run])
    assert len(np.unique(updates["track_id"][confirmed])) == 2
    result = scene_evaluation.evaluate_unit(evaluation, run, 0)
    assert result.track_switches == 0 and result.tracks_per_truth.tolist() == [1, 1]


def test_stage_writes_the_metrics_and_the_picture(tmp_path, models):
    """`evaluate_scenes` on two tiny generated scenes, each on two draws of noise and clutter: every run
    and the oracle (not the plots reference) with GOSPA's parts adding up to GOSPA; the plot counts those
    of the scenes stage's own draw; intervals over the scenes, the draws drawn again with the same
    layouts; the missed and false parts split by cause, adding up to them; the surveillance scorecard of every
    run, its counts per draw; the picture; the comparison's tables."""
    params = tf.make_params({**CLASSICAL, "scenes.count": 2, "scenes.aircraft": 8, "scenes.duration_s": 240.0,
                             "evaluate.seeds": 2})
    again = scene_evaluation.drawn_scenes(params, 1)
    assert [scene.scenario_id for scene in again] == [0, 1] and all(scene.draw == 1 for scene in again)
    route_table, plots, truth = scenes.generate_scenes(params)
    io.write_parquet(route_table, tmp_path / "scenes" / "routes.parquet")
    simulate.write_split(plots, truth, simulate.radar_description(params), tmp_path / "scenes")
    run_evaluate_scenes(params, tmp_path / "scenes", models, tmp_path / "reports")
    report = json.loads((tmp_path / "reports" / "scene_metrics.json").read_text())
    assert sorted(report["runs"]) == ["imm_gnn_4000", "kalman_cv_4000", "oracle_reference"]
    assert report["plots"]["target"] == int(pc.sum(plots.column("is_target")).as_py())
    for values in report["runs"].values():
        parts = sum(values[f"GOSPA_{part}"] for part in ("localisation", "missed", "false"))
        # each figure as the metrics file keeps it, to six significant digits (`io.write_metrics`)
        assert parts == pytest.approx(values["GOSPA"], rel=1e-5) and values["fragmentation"] >= 0.0
        for part, causes in (("missed", scene_evaluation.MISSED_CAUSES), ("false", scene_evaluation.FALSE_CAUSES)):
            assert sum(values[f"GOSPA_{part}_{cause}"] for cause in causes) == pytest.approx(values[f"GOSPA_{part}"],
                                                                                             rel=1e-5, abs=1e-9)
        assert 0.0 < values["probability_of_update"] <= 1.0 and values["position_rms_m"] > 0.0
        assert values["targets"] == 16  # 8 aircraft in each of 2 scenes, a mean over the 2 draws
    assert report["runs"]["imm_gnn_4000"]["velocity_rms_straight_mps"] > 0.0  # the updates carry their velocity
    intervals = json.loads((tmp_path / "reports" / "scene_intervals.json").read_text())
    assert intervals["units"] == 4 and intervals["clusters"] == 2
    for name, values in report["runs"].items():
        low, high = intervals["runs"][name]["GOSPA"]
        assert low <= values["GOSPA"] <= high
    assert (tmp_path / "reports" / "scene_example.png").read_bytes()[:4] == b"\x89PNG"
    table = comparison_tables.scenes_table(with_records(report["runs"], declared_runs(params), "scene_metrics.json"))
    assert table.splitlines()[0].startswith("| tracker | GOSPA (m) | localisation (m) | missed (m) | false (m) | track "
                                            "switches | fragmentation |")
    assert len(table.splitlines()) == 2 + 3
    detail = comparison_tables.scenes_detail(report["runs"], intervals["runs"])
    assert len(detail) == 8 and detail[1].startswith("| run | missed (m) | no plot of it (m) |")
    assert detail[3].startswith("| run | false (m) | clutter tracks (m) |") and "| oracle_reference |" in detail[5]
    assert comparison_tables.scenes_detail({"old": {"GOSPA": 1.0}}, None) == []
    read_back = json.loads(json.dumps(report["runs"]).replace("NaN", "null"))  # io.write_json writes NaN as null
    for values in read_back.values():
        values["manoeuvring_within_1_nm"] = None
    assert "| n/a |" in comparison_tables.scenes_detail(read_back, intervals["runs"])[7]


def test_the_missed_part_is_split_by_why_each_aircraft_scan_was_missed() -> None:
    """One aircraft over six scans, seen in all but scan 2, held by a track in scans 3 and 4: scans 0 and 1 are
    missed before its first track, scan 2 for want of a plot, scan 5 after a track; a scan's missed metres go to
    its causes in proportion (scan 1 also misses a second aircraft never seen: half each)."""
    scans = np.array([0, 1, 3, 4, 5])  # the plots' scans: none in scan 2
    plots = SimpleNamespace(target_id=np.array([7, 7, 7, 7, 7]))
    truth_scan, truth_id = np.array([0, 1, 1, 2, 3, 4, 5]), np.array([7, 7, 8, 7, 7, 7, 7])
    scene = scene_evaluation.Scene(0, plots, scans, np.arange(6), truth_scan, truth_id, {}, {})
    scored = ScanGospa(np.zeros((6, 3)), np.array([3, 4]), np.array([7, 7]), np.array([1, 1]))
    split = scene_evaluation.missed_causes(scene, scored, np.array([10.0, 20.0, 30.0, 0.0, 0.0, 40.0]))
    np.testing.assert_allclose(split, [[0, 10, 0], [10, 10, 0], [30, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 40]])
    assert scene_evaluation.MISSED_CAUSES == ("undetected", "initiation", "after_track")


def test_the_false_part_is_split_by_what_each_unassigned_estimate_is() -> None:
    """Scan 0: track 1 holds aircraft 7, track 2 (its plots aircraft 7's) is a duplicate, track 3 (mostly false
    plots) clutter; scan 1: track 2 alone, unassigned while no track holds aircraft 7, is astray. A scan's false
    metres go to its causes in proportion."""
    plots = SimpleNamespace(plot_id=np.arange(6), target_id=np.array([7, 7, -1, -1, 7, 7]))
    updates = {"track_id": np.array([1, 2, 3, 3, 2, 3]), "plot_id": np.arange(6)}
    confirmed = np.ones(6, dtype=bool)
    scene = scene_evaluation.Scene(0, plots, np.zeros(6, dtype=np.int64), np.arange(2), np.array([0, 1]),
                                   np.array([7, 7]), {}, {})
    origins = scene_evaluation._track_origins(scene, updates, confirmed)
    assert origins == {1: 7, 2: 7, 3: -1}
    estimates = SimpleNamespace(scan=np.array([0, 0, 0, 1]), track=np.array([1, 2, 3, 2]))
    scored = ScanGospa(np.zeros((2, 3)), np.array([0]), np.array([7]), np.array([1]))
    split = scene_evaluation.false_causes(scene, scored, estimates, origins, np.array([30.0, 12.0]))
    np.testing.assert_allclose(split, [[15, 15, 0], [0, 0, 12]])
    assert scene_evaluation.FALSE_CAUSES == ("clutter", "duplicate", "astray")

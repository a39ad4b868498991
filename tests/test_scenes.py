"""Multi-target scenes (`pipeline.simulation.scenes`): the placed situations in every scene, the others
apart when they appear, the same scenes for the same seed, and bad params stopped by name."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pytest

from pipeline import cli
from pipeline.params import ParamError
from pipeline.settings import parse_params
from pipeline.simulation import scenes
from tests import tracker_fixtures as tf
from tests.project import write_params

SMALL = {"scenes.count": 2, "scenes.aircraft": 12, "scenes.duration_s": 600.0}


@pytest.fixture(scope="module")
def params():
    return tf.make_params(SMALL)


@pytest.fixture(scope="module")
def generated(params):
    return scenes.generate_scenes(params)


def aircraft_of(table, scene_id: int, aircraft_id: int) -> dict[str, np.ndarray]:
    rows = table.filter(pc.and_(pc.equal(table.column("scene_id"), scene_id),
                                pc.equal(table.column("route_id"), aircraft_id)))
    return {name: rows.column(name).to_numpy(zero_copy_only=False) for name in rows.column_names}


def test_every_scene_has_its_situations(params, generated):
    """Each scene: aircraft 0 and 1 cross at one altitude at 10-30 deg, both at the crossing point at
    once; then a formation of 2-4 line abreast 0.5-3 km apart that later splits; one aircraft that
    enters coverage and one that leaves it; the others fly the route strategies."""
    route_table, _, truth = generated
    for scene_id in range(params.scenes.count):
        roles = {}
        for aircraft_id in np.unique(aircraft_of(route_table, scene_id, 0)["route_id"].tolist()
                                     + list(range(params.scenes.aircraft))):
            roles[int(aircraft_id)] = str(aircraft_of(route_table, scene_id, aircraft_id)["strategy"][0])
        assert len(roles) == params.scenes.aircraft
        first, second = aircraft_of(route_table, scene_id, 0), aircraft_of(route_table, scene_id, 1)
        assert roles[0] == roles[1] == scenes.CROSSING
        np.testing.assert_allclose(first["altitude_m"], second["altitude_m"][0])
        gap = np.hypot(first["east_m"] - second["east_m"], first["north_m"] - second["north_m"])
        assert gap.min() < 200.0 and gap[0] > 10000.0 and gap[-1] > 10000.0
        headings = [np.arctan2(np.diff(a["east_m"][:2]), np.diff(a["north_m"][:2]))[0] for a in (first, second)]
        angle = np.degrees(abs(np.angle(np.exp(1j * (headings[0] - headings[1])))))
        assert 10.0 - 1e-6 <= angle <= 30.0 + 1e-6

        formation = [i for i, role in roles.items() if role == scenes.FORMATION]
        assert formation == list(range(2, 2 + len(formation))) and 2 <= len(formation) <= 4
        members = [aircraft_of(route_table, scene_id, i) for i in formation]
        start = np.array([[m["east_m"][0], m["north_m"][0]] for m in members])
        end = np.array([[m["east_m"][-1], m["north_m"][-1]] for m in members])
        spacing = np.linalg.norm(np.diff(start, axis=0), axis=1)
        np.testing.assert_allclose(spacing, spacing[0])
        assert 500.0 <= spacing[0] <= 3000.0
        assert (np.linalg.norm(np.diff(end, axis=0), axis=1) > 10 * spacing).all()

        covered = {}
        for role in (scenes.ENTERING, scenes.LEAVING):
            aircraft_id = [i for i, r in roles.items() if r == role]
            assert len(aircraft_id) == 1
            rows = truth.filter(pc.and_(pc.equal(truth.column("scenario_id"), scene_id),
                                        pc.equal(truth.column("target_id"), aircraft_id[0])))
            covered[role] = rows.column("in_coverage").to_numpy(zero_copy_only=False)
        assert not covered[scenes.ENTERING][0] and covered[scenes.ENTERING][-1]
        assert covered[scenes.LEAVING][0] and not covered[scenes.LEAVING][-1]
        assert all(role in scenes.STRATEGIES for i, role in roles.items() if i >= 2 + len(formation) + 2)


def test_the_others_appear_apart_and_lifetimes_overlap(params):
    """An aircraft flying the route strategies appears at least separation_m from every aircraft
    flying then, at a time in the first half of the scene."""
    placed = scenes.plan_scene(params, 0)
    others = placed[2 + sum(a.role == scenes.FORMATION for a in placed) + 2:]
    assert len(others) == params.scenes.aircraft - len(placed) + len(others)
    for index, aircraft in enumerate(placed):
        if aircraft.role not in scenes.STRATEGIES:
            continue
        assert 0.0 <= aircraft.start_s <= params.scenes.start_spread * params.scenes.duration_s
        here = aircraft.planned.position(np.zeros(1))[0, :2]
        for other in placed[:index] + placed[index + 1:]:
            elapsed = aircraft.start_s - other.start_s
            if 0.0 <= elapsed <= other.planned.duration_s:
                there = other.planned.position(np.array([elapsed]))[0, :2]
                assert np.linalg.norm(there - here) >= params.scenes.separation_m
    assert len({round(a.start_s, 3) for a in others}) == len(others)


def test_scenes_are_deterministic_for_a_seed(params, generated):
    """The same params give the same routes, plots and truth (NaN where NaN: the false plots' truth);
    another scenes seed other scenes."""
    again = scenes.generate_scenes(params)
    for first, second in zip(generated, again):
        assert first.to_pandas().equals(second.to_pandas())
    other = scenes.generate_scenes(tf.make_params({**SMALL, "scenes.seed": params.scenes.seed + 1}))
    assert not other[0].to_pandas().equals(generated[0].to_pandas())
    assert not other[1].to_pandas().equals(generated[1].to_pandas())


def test_plots_carry_their_aircraft_and_clutter_spans_the_scene(params, generated):
    """Each target plot names its aircraft (a target id below scenes.aircraft); false plots have
    none; the clutter covers the scene at the radar's false plot rate."""
    _, plots, _ = generated
    target = plots.column("target_id").to_numpy()
    is_target = plots.column("is_target").to_numpy(zero_copy_only=False)
    assert (target[is_target] < params.scenes.aircraft).all() and (target[~is_target] == -1).all()
    assert len(np.unique(target[is_target])) > params.scenes.aircraft // 2
    scans_per_scene = params.scenes.duration_s / params.radar.scan_period_s
    expected = params.radar.false_plots_per_scan * scans_per_scene * params.scenes.count
    assert abs((~is_target).sum() - expected) < 5 * np.sqrt(expected)


@pytest.mark.parametrize("changes, message", [
    ({"scenes.aircraft": 7}, r"scenes.aircraft = 7: a scene needs at least 8"),
    ({"scenes.aircraft": 20, "scenes.separation_m": 200000.0},
     r"scenes.aircraft = 20: more than the 9 that fit the coverage box"),
    ({"scenes.formation_spacing_m": [300.0, 3000.0]},
     r"scenes.formation_spacing_m = \[300.0, 3000.0\]: the closest formation, 300 m apart, is within the radar's "
     r"resolution, 349 m at 250000 m"),
    ({"scenes.formation_size": [1, 3]}, r"scenes.formation_size.lower = 1"),
    ({"scenes.crossing_angle_deg": [10.0, 100.0]}, r"scenes.crossing_angle_deg = \[10.0, 100.0\]: must lie in"),
    ({"scenes.strategies": {"zigzag": 1.0}}, r"scenes.strategies.zigzag: unknown route strategy"),
])
def test_bad_scene_params_name_the_key(changes, message):
    with pytest.raises(ParamError, match=message):
        parse_params(tf.params_tree(changes))


def test_situations_beyond_a_types_coverage_are_refused(tmp_path: Path, caplog):
    """Situations placed beyond the radar horizon of a fighter at its lowest altitude (1 km: 162 km
    away): the scenes command stops with exit 2 naming the key and the type, and writes nothing."""
    tree = tf.params_tree({"scenes.situation_range_m": [200000.0, 250000.0]})
    with pytest.raises(ParamError, match=r"scenes.situation_range_m = \[200000.0, 250000.0\]: starts beyond the "
                                         r"coverage of aircraft.fighter at its lowest altitude 1000 m"):
        scenes.check_scenes(parse_params(tree))
    params_path = write_params(tree, tmp_path / "params.yaml")
    assert cli.main(["scenes", "--params", str(params_path), "--out", str(tmp_path / "scenes")]) == 2
    assert "aircraft.fighter" in caplog.text and not (tmp_path / "scenes").exists()

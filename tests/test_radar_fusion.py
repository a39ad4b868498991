"""The fusion stage's library (`radar_fusion`, run as units of the bench's engine by `fusion_bench`): the
multi-target scenes seen by two radars, tracked per radar, associated and fused; and the params of its radars."""

from __future__ import annotations

import re

import numpy as np
import pytest

import pyarrow as pa

from pipeline.association.common_time_states import Frame
from pipeline.bench import fusion_bench, radar_fusion
from pipeline.geometry import geodesy
from pipeline.params import ParamError
from pipeline.simulation import simulate
from pipeline.surveillance import scorecard
from tests import tracker_fixtures as tf

SMALL = {"scenes.aircraft": 8, "scenes.duration_s": 200.0, "fusion.scenes": 1, "fusion.sweep_scenes": 1,
         "fusion.methods": ["statistical", "bias_robust"]}


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    params = tf.make_params(SMALL)
    models = tf.write_tuned_filters(tmp_path_factory.mktemp("models"), params)
    return fusion_bench.fusion_reports(params, models, workers=1)[0]


def test_two_radars_tracks_are_paired_as_the_oracle_pairs_them_and_fusion_beats_the_better_radar(report):
    """One scene of 8 aircraft, two radars 100 km apart, the second biased: the statistical and the bias-robust
    methods find nearly all the oracle's pairs and few false ones; fusing the oracle's pairs gives a smaller GOSPA
    than the better radar alone."""
    assert report["common_times"] > 10 and report["oracle_pairs"] > 50
    for method in ("statistical", "bias_robust"):
        assert report["association"][method]["accuracy"] > 0.9
        assert report["association"][method]["false_pairs"] <= 0.05 * report["oracle_pairs"]
    assert set(report["gospa_m"]) == {"radar_1", "radar_2", "fused_statistical", "fused_bias_robust", "fused_oracle"}
    assert report["fused_gospa_vs_better_radar"]["fused_oracle"] < 1.0
    assert set(report["track_switches"]) == set(report["gospa_m"])
    assert all(count >= 0 for count in report["track_switches"].values())
    assert report["track_switches"]["fused_oracle"] <= report["track_switches"]["radar_1"] + \
        report["track_switches"]["radar_2"]  # system tracks: a fused track lives while either local track does
    assert all(value >= 1.0 for value in report["tracks_per_truth"].values())
    for name, shares in report["gospa_shares_m"].items():
        assert sum(shares.values()) == pytest.approx(report["gospa_m"][name], rel=1e-5)  # each to six digits
    assert set(report["scorecard"]) == set(report["gospa_m"])  # every picture scored as a tracker's output
    for card in report["scorecard"].values():
        assert 0.5 < card["probability_of_update"] <= 1.0 and card["targets"] >= 8
        assert card["position_rms_m"] < tf.make_params(SMALL).scorecard.association_m


def test_the_fusion_report_is_the_same_on_two_workers_as_on_one(tmp_path):
    """Two scenes, each a unit: merged in scene order, the report (the bias sweep's counts included) and its
    intervals over the scenes do not depend on which worker scored which scene, nor in which order they
    finished; each picture's interval holds its GOSPA, and a paired difference is the negative of its reverse."""
    params = tf.make_params({**SMALL, "scenes.duration_s": 120.0, "fusion.scenes": 2,
                             "fusion.sweep_scenes": 2, "fusion.sweep_bias_m": [0.0, 300.0]})
    models = tf.write_tuned_filters(tmp_path, params)
    alone, spread = fusion_bench.fusion_reports(params, models, workers=1)
    assert alone["scenes"] == 2 and alone["bias_sweep"]["scenes"] == 2
    assert (alone, spread) == fusion_bench.fusion_reports(params, models, workers=2)
    assert spread["pictures"]["units"] == 2 and set(spread["pictures"]["runs"]) == set(alone["gospa_m"])
    for name, value in alone["gospa_m"].items():
        low, high = spread["pictures"]["runs"][name]["GOSPA"]
        assert low <= value <= high
    low, high = spread["pictures"]["paired"]["GOSPA"]["radar_1"]["radar_2"]
    assert spread["pictures"]["paired"]["GOSPA"]["radar_2"]["radar_1"] == pytest.approx([-high, -low])
    assert set(spread["association"]["runs"]) == {"statistical", "bias_robust"}
    assert set(spread["scorecard"]["runs"]) == set(alone["scorecard"])
    for name, card in alone["scorecard"].items():
        low, high = spread["scorecard"]["runs"][name]["position_rms_m"]
        assert low <= card["position_rms_m"] <= high


def test_a_biased_radar_is_believed_where_its_position_bias_puts_it():
    params = tf.make_params()
    second = params.fusion.radars[1]
    believed = radar_fusion.believed_radar(second)
    offset = geodesy.radar_site_ecef(believed) - geodesy.radar_site_ecef(second.radar)
    east_north = geodesy.enu_rotation(second.radar.latitude_deg, second.radar.longitude_deg)[:2] @ offset
    np.testing.assert_allclose(east_north, [second.bias_east_m, second.bias_north_m], atol=0.5)


@pytest.mark.parametrize("radars, named", [
    ([{"bias_range_m": 0.0, "bias_azimuth_deg": 0.0, "bias_east_m": 0.0, "bias_north_m": 0.0, "seed": 1}],
     "fusion.radars = [{"),
    ([{"bias_range_m": 0.0, "bias_azimuth_deg": 0.0, "bias_east_m": 0.0, "bias_north_m": 0.0, "seed": 1}] * 2,
     "fusion.radars: both radars have id 1"),
    ([{"bias_range_m": 0.0, "bias_azimuth_deg": 0.0, "bias_east_m": 0.0, "bias_north_m": 0.0, "seed": 1},
      {"sic": 2, "sigma_rnage_m": 3.0, "bias_range_m": 0.0, "bias_azimuth_deg": 0.0, "bias_east_m": 0.0,
       "bias_north_m": 0.0, "seed": 2}], "fusion.radars[1].sigma_rnage_m: unknown key"),
    ([{"bias_range_m": 0.0, "bias_azimuth_deg": 0.0, "bias_east_m": 0.0, "bias_north_m": 0.0, "seed": 1},
      {"sic": 2, "latitude_deg": 95.0, "bias_range_m": 0.0, "bias_azimuth_deg": 0.0, "bias_east_m": 0.0,
       "bias_north_m": 0.0, "seed": 2}], "fusion.radars[1]: radar.latitude_deg = 95.0"),
])
def test_bad_fusion_radars_name_the_entry_key_and_value(radars, named):
    with pytest.raises(ParamError, match=re.escape(named)):
        tf.make_params({"fusion.radars": radars})


@pytest.mark.parametrize("changes, named", [
    ({"fusion.scenes": 1, "fusion.sweep_scenes": 2}, "fusion.sweep_scenes = 2: must be at most fusion.scenes = 1"),
    ({"fusion.sweep_bias_m": [0.0, -50.0]}, "fusion.sweep_bias_m = [0.0, -50.0]: must list non-negative numbers"),
    ({"fusion.sweep_bias_m": []}, "fusion.sweep_bias_m = []: must list non-negative numbers"),
])
def test_bad_bias_sweep_params_name_the_key_and_value(changes, named):
    with pytest.raises(ParamError, match=re.escape(named)):
        tf.make_params(changes)


def test_a_picture_score_counts_gospa_its_shares_and_a_switch_of_identity():
    """One aircraft at the origin, held by identity 5 then by identity 6 (say, a system track that ended):
    GOSPA is the localisation error at each time, all of it localisation, and the change is one switch, two
    tracks for one truth."""
    params = tf.make_params()
    score = radar_fusion.PictureScore()
    truth = np.zeros((1, 3))
    score.add(0, np.array([3]), truth, np.array([5]), np.array([[30.0, 40.0, 0.0, 0.0, 0.0, 0.0]]), 100.0, params)
    score.add(1, np.array([3]), truth, np.array([6]), np.array([[0.0, 10.0, 0.0, 0.0, 0.0, 0.0]]), 104.0, params)
    assert score.gospa_sum == pytest.approx(50.0 + 10.0)
    np.testing.assert_allclose(score.shares_sum, [60.0, 0.0, 0.0])
    assert score.continuity().tolist() == [1, 2, 1]


def test_a_picture_is_scored_as_a_tracker_at_the_common_times_in_the_frame_it_was_seen_in():
    """An aircraft flying east at 200 m/s, seen at common times 4 s apart (`associate.step_s`) by one identity
    100 m north of it in the common frame: the scorecard gives 100 m across track and nothing along, its
    velocity exact, every common time updated; the truth's last times, when no radar had seen it for longer than
    `associate.max_age_s`, are out of coverage."""
    params = tf.make_params({"associate.step_s": 4.0, "associate.max_age_s": 12.0})
    frame = common_frame_at(60.0, 25.0)
    times = [1000.0 + 4.0 * k for k in range(10)]
    east = np.array([[200.0 * (t - 1000.0), 0.0, 9000.0] for t in times])
    routes = route_table(7, times, east, frame)
    detections = (np.full(5, 7), np.array(times[:5]))  # last seen at 1016 s: from 1032 s on, out of coverage
    truth = radar_fusion.scene_truth(routes, detections, times, params.associate.max_age_s)
    assert truth.in_coverage.tolist() == [True] * 8 + [False] * 2
    score = radar_fusion.PictureScore()
    for index, (time, position) in enumerate(zip(times, east)):
        state = np.concatenate([position + [0.0, 100.0, 0.0], [200.0, 0.0, 0.0]])[None]
        score.add(index, np.array([7]), position[None], np.array([1]), state, time, params)
    score.score_card(truth, frame, params)
    card = scorecard.combined([score.card])
    assert card["across_track_rms_m"] == pytest.approx(100.0, abs=0.5)
    assert card["along_track_rms_m"] == pytest.approx(0.0, abs=0.5)
    assert card["velocity_rms_straight_mps"] == pytest.approx(0.0, abs=0.05)
    assert card["probability_of_update"] == 1.0 and card["confirmed_updates"] == 10 and card["false_tracks"] == 0


def common_frame_at(latitude_deg: float, longitude_deg: float) -> Frame:
    """The ENU frame at a point of the ellipsoid."""
    origin = geodesy.geodetic_to_ecef(np.array([latitude_deg]), np.array([longitude_deg]), np.array([0.0]))[0]
    return Frame(origin, geodesy.enu_rotations(np.array([latitude_deg]), np.array([longitude_deg]))[0])


def route_table(route_id: int, times: list[float], enu: np.ndarray, frame: Frame) -> pa.Table:
    """A route (`simulate.ROUTE_COLUMNS`) flying the `enu` positions (N, 3) of `frame` at `times`, straight and
    level at their mean velocity."""
    ecef = frame.origin + enu @ frame.rotation
    velocity = np.broadcast_to((enu[-1] - enu[0]) / (times[-1] - times[0]) @ frame.rotation, ecef.shape)
    columns = {"route_id": np.full(len(times), route_id), "aircraft_type": ["airliner"] * len(times),
               "time_unix_s": np.asarray(times),
               **{f"{axis}_ecef_m": ecef[:, i] for i, axis in enumerate("xyz")},
               **{f"v{axis}_ecef_mps": velocity[:, i] for i, axis in enumerate("xyz")}}
    return pa.table({name: columns[name] for name in simulate.ROUTE_COLUMNS})

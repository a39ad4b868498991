"""The fusion stage's library (`radar_fusion`): the multi-target scenes seen by two radars, tracked per radar,
associated and fused; and the params of its radars."""

from __future__ import annotations

import re

import numpy as np
import pytest

from pipeline import geodesy, radar_fusion
from pipeline.params import ParamError
from tests import tracker_fixtures as tf

SMALL = {"scenes.aircraft": 8, "scenes.duration_s": 200.0, "fusion.scenes": 1,
         "fusion.methods": ["statistical", "bias_robust"]}


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    params = tf.make_params(SMALL)
    models = tf.write_tuned_filters(tmp_path_factory.mktemp("models"), params)
    return radar_fusion.fusion_report(params, models, None)


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

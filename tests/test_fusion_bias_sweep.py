"""Association against radar 2's bias in our scenes: the bias moves every radar 2 track by one vector of the
asked length, and on one small scene the bias-robust method keeps its accuracy where the statistical loses it."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.association.common_time_states import Snapshot
from pipeline.bench import fusion_bench, fusion_bias_sweep
from tests import tracker_fixtures as tf


def test_a_bias_moves_every_second_user_track_by_one_vector_of_its_length():
    offset = fusion_bias_sweep.bias_offset(200.0, seed=7, scene_id=3, index=1)
    assert np.linalg.norm(offset) == pytest.approx(200.0)
    assert np.array_equal(offset, fusion_bias_sweep.bias_offset(200.0, 7, 3, 1))       # the same stream, the same
    assert not np.allclose(offset, fusion_bias_sweep.bias_offset(200.0, 7, 4, 1))      # another scene, another
    states = (np.zeros((1, 6)), np.array([[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [0.0] * 6]))
    covariances = (np.tile(np.eye(6), (1, 1, 1)), np.tile(np.eye(6), (2, 1, 1)))
    snapshot = Snapshot(0, 0.0, (np.array([1]), np.array([2, 3])), states, covariances)
    moved = fusion_bias_sweep.moved([snapshot], offset)[0]
    np.testing.assert_allclose(moved.states[1][:, :2] - states[1][:, :2], [offset, offset])
    np.testing.assert_array_equal(moved.states[1][:, 2:], states[1][:, 2:])   # heights and velocities unchanged
    np.testing.assert_array_equal(moved.states[0], states[0])                 # radar 1 untouched


def test_on_one_small_scene_the_bias_robust_method_holds_at_400_m_and_the_statistical_does_not(tmp_path):
    params = tf.make_params({"scenes.aircraft": 8, "scenes.duration_s": 200.0, "fusion.scenes": 1,
                             "fusion.sweep_scenes": 1, "fusion.sweep_bias_m": [0.0, 400.0],
                             "fusion.methods": ["statistical", "bias_robust"]})
    report = fusion_bench.fusion_reports(params, tf.write_tuned_filters(tmp_path, params), workers=1)[0]["bias_sweep"]
    unbiased, biased = report["by_bias_m"]["0"]["methods"], report["by_bias_m"]["400"]["methods"]
    assert unbiased["statistical"]["accuracy"] > 0.9 and unbiased["bias_robust"]["accuracy"] > 0.9
    assert biased["bias_robust"]["accuracy"] > 0.9
    assert biased["statistical"]["accuracy"] < biased["bias_robust"]["accuracy"] - 0.1
    for measures in (unbiased, biased):
        for method in measures.values():
            assert method["accuracy"] + method["missed_pairs"] == pytest.approx(1.0)
    assert fusion_bias_sweep.sweep_figure(report).startswith(b"\x89PNG")

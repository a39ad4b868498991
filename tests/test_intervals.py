"""`pipeline.bench.intervals`: the paired bootstrap behind every metric's interval and every verdict.

Units are scenes as `pipeline.bench.scene_evaluation` scores them (each scan's GOSPA parts), scored by
its own `run_metrics`: a tracker against itself differs by exactly 0 on every resample; one made worse
on purpose (40 m more localisation error in every scan) is worse beyond the noise, though the scenes
differ from each other by far more than 40 m; two trackers of the same quality with independent errors
tie. The comparison's verdict says which.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.bench import intervals
from pipeline.bench.runs import declared_runs
from pipeline.bench.scene_evaluation import SceneResult, run_metrics
from pipeline.reports.comparison_tables import verdict
from tests import tracker_fixtures as tf

NAMES = ["GOSPA", "GOSPA_localisation", "GOSPA_missed", "GOSPA_false", "track_switches"]


def scenes(rng: np.random.Generator, localisation: np.ndarray, extra_m: float = 0.0) -> list[SceneResult]:
    """One scene per entry of `localisation` (m), 50 scans each with that error (and noise), plus `extra_m`."""
    return [SceneResult(np.column_stack([np.abs(level + extra_m + rng.normal(0.0, 20.0, 50)),
                                         rng.uniform(0.0, 300.0, 50), np.zeros(50)]),
                        int(rng.integers(0, 5)), np.ones(3), np.ones(3), 1.0, None) for level in localisation]


def report(units: dict[str, list[SceneResult]], replicates: int = 400) -> dict:
    return intervals.run_intervals(units, lambda results: run_metrics(results, 0), NAMES, NAMES, replicates, 0.95, 7)


@pytest.fixture()
def levels() -> np.ndarray:
    return np.random.default_rng(0).uniform(100.0, 900.0, 12)  # scenes far apart in difficulty


def test_a_tracker_against_itself_differs_by_exactly_zero(levels):
    units = scenes(np.random.default_rng(1), levels)
    result = report({"a": units, "same": units})
    assert all(result["paired"][name]["a"]["same"] == [0.0, 0.0] for name in NAMES)
    assert intervals.within_noise(result["paired"]["GOSPA"]["a"]["same"])
    low, high = result["runs"]["a"]["GOSPA"]
    assert low < run_metrics(units, 0)["GOSPA"] < high and high - low > 100.0  # the scenes' spread is wide


def test_a_tracker_made_worse_on_purpose_is_worse_beyond_the_noise(levels):
    good = scenes(np.random.default_rng(1), levels)
    worse = scenes(np.random.default_rng(1), levels, extra_m=40.0)
    result = report({"good": good, "worse": worse})
    low, high = result["paired"]["GOSPA_localisation"]["worse"]["good"]
    assert 30.0 < low < high < 50.0
    assert not intervals.within_noise([low, high])
    assert result["paired"]["GOSPA_localisation"]["good"]["worse"] == pytest.approx([-high, -low])
    good_low, good_high = result["runs"]["good"]["GOSPA_localisation"]
    assert good_high - good_low > 2 * (high - low)  # paired: far narrower than either run's own interval


def test_two_trackers_of_one_quality_tie_and_the_intervals_repeat_to_the_bit(levels):
    units = {"a": scenes(np.random.default_rng(1), levels), "b": scenes(np.random.default_rng(2), levels)}
    assert intervals.within_noise(report(units)["paired"]["GOSPA"]["a"]["b"])
    assert report(units) == report(units)


def test_a_routes_draws_are_resampled_together_and_one_route_gives_no_interval():
    rows = intervals.resamples(6, 50, 3, clusters=[10, 10, 10, 20, 20, 20])
    assert all(len(row) == 6 and {tuple(sorted(row[:3])), tuple(sorted(row[3:]))} <= {(0, 1, 2), (3, 4, 5)}
               for row in rows)
    units = scenes(np.random.default_rng(0), np.array([300.0, 500.0]))
    alone = intervals.run_intervals({"a": units, "b": units[::-1]}, lambda results: run_metrics(results, 0), NAMES,
                                    NAMES, 50, 0.95, 1, clusters=[7, 7])
    assert np.isnan(alone["paired"]["GOSPA"]["a"]["b"]).all() and alone["clusters"] == 1


def test_runs_with_different_units_are_refused():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="different numbers of units"):
        report({"a": scenes(rng, np.ones(3)), "b": scenes(rng, np.ones(4))})


def test_the_verdict_calls_a_difference_inside_its_interval_a_tie():
    params = tf.make_params({"evaluate.runs": [{"method": "via", "window_m": 4000.0},
                                               {"method": "imm_gnn", "window_m": 4000.0}],
                             "evaluate.example_run": "via_4000", "evaluate.site_runs": [], "evaluate.scene_runs": []})
    declared = declared_runs(params)
    metrics = {"via_4000": {"OSPA": 239.7, "ROCA": 0.95, "MAE": 150.0},
               "imm_gnn_4000": {"OSPA": 240.2, "ROCA": 0.90, "MAE": 160.0}}
    runs = {declared[name]: values for name, values in metrics.items()}
    paired = {"OSPA": {"via_4000": {"imm_gnn_4000": [-3.1, 2.2]}},
              "ROCA": {"via_4000": {"imm_gnn_4000": [0.03, 0.07]}},
              "MAE": {"via_4000": {"imm_gnn_4000": [-14.0, -6.0]}}}
    holdout = {"filter_error_m": {}}
    said = "\n".join(verdict(runs, holdout, {"level": 0.95, "paired": paired}))
    assert ("OSPA: best of the thesis's networks via_4000 239.7; tuned classical filters imm_gnn_4000 240.2. Best "
            "against the next family's best: **a tie within the noise** (paired 95% interval of via_4000 − "
            "imm_gnn_4000: [-3.1, 2.2] holds 0).") in said
    assert "**via_4000** wins (paired 95% interval of via_4000 − imm_gnn_4000: [0.03, 0.07])." in said
    assert "**via_4000** wins (paired 95% interval of via_4000 − imm_gnn_4000: [-14, -6])." in said
    assert "**via_4000** wins." in "\n".join(verdict(runs, holdout))  # reports before intervals: the bare verdict


def test_the_verdict_names_the_best_of_each_of_the_three_families_and_backs_the_winner_against_the_next():
    """The thesis's networks, the learned Kalman hybrids and the tuned classical filters each by their best run;
    the winner is compared with the best of the next family, not with a run of its own family."""
    params = tf.make_params({"evaluate.runs": [{"method": name, "window_m": 4000.0}
                                               for name in ("via", "lstm_update", "kalman_net", "imm_gnn")],
                             "evaluate.example_run": "via_4000", "evaluate.site_runs": [], "evaluate.scene_runs": []})
    declared = declared_runs(params)
    metrics = {"via_4000": {"OSPA": 260.0, "ROCA": 0.95, "MAE": 170.0},
               "lstm_update_4000": {"OSPA": 230.0, "ROCA": 0.96, "MAE": 140.0},
               "kalman_net_4000": {"OSPA": 235.0, "ROCA": 0.96, "MAE": 141.0},
               "imm_gnn_4000": {"OSPA": 240.0, "ROCA": 0.97, "MAE": 150.0}}
    runs = {declared[name]: values for name, values in metrics.items()}
    paired = {"OSPA": {"lstm_update_4000": {"imm_gnn_4000": [-14.0, -6.0], "kalman_net_4000": [-9.0, -1.0]}}}
    said = "\n".join(verdict(runs, {"filter_error_m": {}}, {"level": 0.95, "paired": paired}))
    assert ("OSPA: best of the thesis's networks via_4000 260; learned Kalman hybrids lstm_update_4000 230; tuned "
            "classical filters imm_gnn_4000 240. Best against the next family's best: **lstm_update_4000** wins "
            "(paired 95% interval of lstm_update_4000 − imm_gnn_4000: [-14, -6]).") in said
    assert "ROCA): best of the thesis's networks via_4000 0.95; learned Kalman hybrids lstm_update_4000 0.96" in said

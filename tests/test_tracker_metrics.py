"""The tracker metrics (thesis 5.1) on a hand-built tracking result whose every number is worked out below.

Three routes, each an update table as the tracker gives it (`pipeline.tracker.updates`), the plots'
target/false flags and the target's true position as a function of time:

Route A (truth: x = 100 t, on the x axis), 11 target plots and 3 false plots:
  track 1: plots 0, 1, 2 (start 0.4, 0.6, 0.8: no confirmed association yet), then confirmed (1.0)
           associations of target plot 3 (state 50 m off the truth), FALSE plot 4 (120 m off) and
           target plot 5 (10 m off).
  track 2: false plots 10 (start) and 11 (associated at 0.6: not confirmed, must not count).
  track 3: target plots 6, 7, 8 (0.4, 0.6, 0.8), then confirmed associations of 9 (30 m) and 12 (20 m).
  plot 13: a target plot that only starts a track.
  -> confirmed associations 5 (1 false, 4 target), error sum 230 m, 2 confirmed tracks of 3 and 2.
Route B (truth: y = 200 t, z = 1000), 6 target plots and 1 false plot:
  track 7: target plots 100-102 (0.4, 0.6, 0.8), then confirmed 103 (40 m) and 104 (60 m).
  plot 105 (false) and plot 106 (target) only start tracks.
  -> confirmed associations 2 (both target), error sum 100 m, 1 confirmed track of 2.
Route C: target plot 200 and false plot 201, each only a start: no confirmed track.

Overall: NOPA = 5 + 2 = 7; NOFPA = 1; MAE = (230 + 100) / 7 = 47.142857 m;
NOMT = mean(2, 1, 0) = 1 (averaged over all routes); MMTL = mean(mean(3, 2), 2) = 2.25 (over the
routes that have confirmed tracks); ROCA = (4 + 2) / (11 + 6 + 1) = 1/3; ROFA = 1/7.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.bench.tracker_metrics import METRICS, RouteCounts, route_counts, summarise
from pipeline.settings import parse_params
from pipeline.reports import comparison_tables
from pipeline.tracker.management import ThesisWeights
from pipeline.tracker.tracks import LiveTracks
from pipeline.tracker.updates import COLUMNS
from tests import tracker_fixtures as tf
from tests.project import default_params_tree

RULE = ThesisWeights(start=0.4, candidate=0.8, confirmed_weight=1.0, step=0.2, silence_s=12.0, silence_scans=2.0)
# The weights the tracker reaches by adding 0.2 in floating point (0.4 + 0.2 = 0.6000000000000001).
W = [0.4, 0.4 + 0.2, 0.4 + 0.2 + 0.2, min(0.4 + 0.2 + 0.2 + 0.2, 1.0)]


def truth_a(t: np.ndarray) -> np.ndarray:
    t = np.asarray(t, float)
    return np.column_stack([100.0 * t, np.zeros_like(t), np.zeros_like(t)])


def truth_b(t: np.ndarray) -> np.ndarray:
    t = np.asarray(t, float)
    return np.column_stack([np.zeros_like(t), 200.0 * t, np.full_like(t, 1000.0)])


def updates_of(rows: list[tuple], truth) -> dict[str, np.ndarray]:
    """Updates from (track_id, time, plot_id, offset of the state from the truth, weight, association) rows."""
    columns = {name: [] for name in COLUMNS}
    for track_id, time, plot_id, offset, weight, association in rows:
        state = truth(np.array([time]))[0] + np.asarray(offset, float)
        columns["track_id"].append(track_id)
        columns["time_unix_s"].append(time)
        columns["plot_id"].append(plot_id)
        for axis, value in zip(("x_ecef_m", "y_ecef_m", "z_ecef_m"), state):
            columns[axis].append(value)
        columns["radar_id"].append(1)
        columns["weight"].append(weight)
        columns["association"].append(association)
        columns["association_error"].append(np.nan if association == "start" else 0.5)
        columns["position_covariance"].append(np.full((3, 3), np.nan))
    return {name: np.asarray(values) for name, values in columns.items()}


NEAR = (0.0, 0.0, 0.0)

ROUTE_A = [  # (track, time, plot, state offset from truth, weight, association), in time order
    (1, 0.0, 0, (5000.0, 0.0, 0.0), W[0], "start"),
    (2, 3.0, 10, (0.0, 9000.0, 0.0), W[0], "start"),
    (1, 6.0, 1, (700.0, 0.0, 0.0), W[1], "radius"),
    (2, 9.0, 11, (0.0, 8000.0, 0.0), W[1], "radius"),        # not confirmed: does not count
    (1, 12.0, 2, (0.0, 300.0, 0.0), W[2], "via"),           # candidate: does not count
    (1, 18.0, 3, (30.0, 40.0, 0.0), W[3], "via"),           # confirmed, 50 m
    (1, 24.0, 4, (0.0, 0.0, 120.0), 1.0, "via"),            # confirmed, FALSE plot, 120 m
    (1, 30.0, 5, (6.0, 8.0, 0.0), 1.0, "via"),              # confirmed, 10 m
    (3, 36.0, 6, NEAR, W[0], "start"),
    (3, 42.0, 7, (400.0, 0.0, 0.0), W[1], "radius"),
    (3, 48.0, 8, (0.0, 0.0, 250.0), W[2], "via"),
    (3, 54.0, 9, (0.0, 30.0, 0.0), W[3], "via"),            # confirmed, 30 m
    (3, 60.0, 12, (0.0, 0.0, -20.0), 1.0, "via"),           # confirmed, 20 m
    (4, 61.0, 13, NEAR, W[0], "start"),
]
TARGET_A = {0: True, 1: True, 2: True, 3: True, 4: False, 5: True, 6: True, 7: True, 8: True, 9: True,
            10: False, 11: False, 12: True, 13: True}

ROUTE_B = [
    (7, 100.0, 100, NEAR, W[0], "start"),
    (7, 106.0, 101, (100.0, 0.0, 0.0), W[1], "radius"),
    (8, 107.0, 105, NEAR, W[0], "start"),
    (7, 112.0, 102, (0.0, 90.0, 0.0), W[2], "mia"),
    (7, 118.0, 103, (0.0, 0.0, 40.0), W[3], "mia"),         # confirmed, 40 m
    (7, 124.0, 104, (36.0, 48.0, 0.0), 1.0, "mia"),          # confirmed, 60 m
    (9, 125.0, 106, NEAR, W[0], "start"),
]
TARGET_B = {100: True, 101: True, 102: True, 103: True, 104: True, 105: False, 106: True}

ROUTE_C = [
    (0, 5.0, 200, NEAR, W[0], "start"),
    (1, 6.0, 201, NEAR, W[0], "start"),
]
TARGET_C = {200: True, 201: False}


@pytest.fixture(scope="module")
def counts() -> list[RouteCounts]:
    return [route_counts(updates_of(ROUTE_A, truth_a), TARGET_A, truth_a, RULE),
            route_counts(updates_of(ROUTE_B, truth_b), TARGET_B, truth_b, RULE),
            route_counts(updates_of(ROUTE_C, truth_a), TARGET_C, truth_a, RULE)]


def test_the_hand_built_weights_are_the_trackers():
    """W is what LiveTracks holds after a start and three associations, floating point and all, and
    RULE is the default params' rule."""
    params = parse_params(default_params_tree())
    assert ThesisWeights.from_params(params.tracker.management) == RULE
    live = LiveTracks(tf.plots_of(np.tile([0.0, 1.0, 2.0, 3.0, 4.0], (4, 1)), np.arange(4), params.radar), RULE,
                      latest_plots=0)
    slot = live.start(0)
    weights = [live.weight[slot]]
    for row in range(1, 4):
        live.associate(slot, row, live.plots.position[row])
        weights.append(live.weight[slot])
    assert weights == W


def test_route_with_two_confirmed_tracks_and_a_false_plot_counts_by_hand(counts):
    """Route A: 11 target and 3 false plots; 5 confirmed associations (plot 4 false), errors
    50 + 120 + 10 + 30 + 20 = 230 m, confirmed tracks 1 and 3 with 3 and 2 confirmed plots. The
    association of false plot 11 to a 0.6 track and the candidate association of plot 2 do not count."""
    assert counts[0] == RouteCounts(target_plots=11, false_plots=3, confirmed_associations=5,
                                    false_confirmed_associations=1, target_confirmed_associations=4,
                                    error_sum_m=pytest.approx(230.0), confirmed_tracks=2,
                                    confirmed_track_lengths=[3, 2], aircraft_tracks=2)


def test_second_and_third_routes_count_by_hand(counts):
    assert counts[1] == RouteCounts(target_plots=6, false_plots=1, confirmed_associations=2,
                                    false_confirmed_associations=0, target_confirmed_associations=2,
                                    error_sum_m=pytest.approx(100.0), confirmed_tracks=1,
                                    confirmed_track_lengths=[2], aircraft_tracks=1)
    assert counts[2] == RouteCounts(target_plots=1, false_plots=1, confirmed_associations=0,
                                    false_confirmed_associations=0, target_confirmed_associations=0,
                                    error_sum_m=0.0, confirmed_tracks=0, confirmed_track_lengths=[],
                                    aircraft_tracks=0)


@pytest.mark.parametrize("metric, expected", [
    ("MAE", 330.0 / 7.0),     # pooled over all confirmed associations of all routes
    ("NOFPA", 1),
    ("NOPA", 7),
    ("NOMT", 1.0),            # (2 + 1 + 0) / 3 routes
    ("MMTL", 2.25),           # ((3 + 2) / 2 + 2 / 1) / 2 routes with confirmed tracks
    ("ROCA", 6.0 / 18.0),     # target plots associated to confirmed tracks / all target plots
    ("ROFA", 1.0 / 7.0),      # false confirmed associations / all confirmed associations
    ("tracks_per_aircraft", 1.0),  # (2 + 1 + 0) / 3 routes: track 1 of route A holds 2 target plots of 3
])
def test_each_metric_by_hand(counts, metric, expected):
    assert summarise(counts)[metric] == pytest.approx(expected, rel=1e-12)


def test_a_route_the_radar_never_saw_has_no_aircraft_to_count(counts):
    """A route flown wholly outside coverage (no target plot) leaves tracks_per_aircraft as it was:
    (2 + 1 + 0) / 3 routes seen; NOMT still averages over every route."""
    unseen = RouteCounts(target_plots=0, false_plots=4, confirmed_associations=0, false_confirmed_associations=0,
                         target_confirmed_associations=0, error_sum_m=0.0, confirmed_tracks=0,
                         confirmed_track_lengths=[], aircraft_tracks=0)
    summary = summarise([*counts, unseen])
    assert summary["tracks_per_aircraft"] == pytest.approx(1.0) and summary["NOMT"] == pytest.approx(3 / 4)


def test_summary_has_every_metric_and_the_plot_totals(counts):
    summary = summarise(counts)
    assert set(METRICS) <= set(summary)
    assert (summary["target_plots"], summary["false_plots"]) == (18, 5)


def test_mmtl_and_nomt_average_differently_over_routes(counts):
    """Dropping route C (no confirmed track) changes NOMT (3 tracks over 2 routes) but not MMTL."""
    summary = summarise(counts[:2])
    assert summary["NOMT"] == pytest.approx(1.5)
    assert summary["MMTL"] == pytest.approx(2.25)
    assert summary["ROCA"] == pytest.approx(6.0 / 17.0)


def test_a_single_route(counts):
    summary = summarise(counts[1:2])
    assert (summary["MAE"], summary["NOPA"], summary["NOFPA"], summary["NOMT"], summary["MMTL"], summary["ROCA"],
            summary["ROFA"]) == pytest.approx((50.0, 2, 0, 1.0, 2.0, 2.0 / 6.0, 0.0))


def test_no_confirmed_association_gives_nan_ratios(counts):
    """Only route C: nothing confirmed, so MAE, MMTL and ROFA are undefined (NaN), NOMT and ROCA are 0."""
    summary = summarise(counts[2:])
    assert (summary["NOPA"], summary["NOFPA"], summary["NOMT"], summary["ROCA"]) == (0, 0, 0.0, 0.0)
    assert np.isnan(summary["MAE"]) and np.isnan(summary["MMTL"]) and np.isnan(summary["ROFA"])


def test_a_confirmed_track_of_mostly_false_plots_is_not_one_of_the_aircrafts_tracks():
    """A clutter track confirmed on false plots that once takes a target plot counts in NOMT (every
    confirmed track) but not in tracks_per_aircraft; the aircraft's own track does."""
    route = [(5, 0.0, 300, NEAR, W[0], "start"), (6, 1.0, 310, NEAR, W[0], "start"),
             (5, 6.0, 301, NEAR, W[1], "radius"), (6, 7.0, 311, NEAR, W[1], "radius"),
             (5, 12.0, 302, NEAR, W[2], "via"), (6, 13.0, 312, NEAR, W[2], "via"),
             (5, 18.0, 303, NEAR, W[3], "via"), (6, 19.0, 313, NEAR, W[3], "via"),     # both confirmed
             (5, 24.0, 304, NEAR, 1.0, "via"), (6, 25.0, 314, NEAR, 1.0, "via"),
             (5, 30.0, 305, NEAR, 1.0, "via")]
    is_target = {plot: plot in (305, 310, 311, 312, 313, 314) for plot in (*range(300, 306), *range(310, 315))}
    counts = route_counts(updates_of(route, truth_a), is_target, truth_a, RULE)
    assert (counts.confirmed_tracks, counts.aircraft_tracks) == (2, 1)
    assert summarise([counts])["NOMT"] == 2 and summarise([counts])["tracks_per_aircraft"] == 1


def test_continuity_table_puts_a_run_under_both_rules_side_by_side():
    """The comparison's continuity table: references first, then runs by method and window with the
    m_of_n run right after its thesis-rule twin; a strategy a run has no figures for reads n/a."""
    runs = {"imm_4000_m_of_n": {"tracks_per_aircraft": 1.1, "ROCA": 0.96}, "via_4000": {"ROCA": 0.9},
            "imm_4000": {"tracks_per_aircraft": 1.2, "ROCA": 0.95}, "oracle_reference": {"tracks_per_aircraft": 1.0}}
    by_strategy = {"imm_4000": {"random_turns": {"tracks_per_aircraft": 1.5, "ROCA": 0.9},
                                "sustained_turns": {"tracks_per_aircraft": 1.0, "ROCA": 0.875}}}
    lines = comparison_tables.continuity_table(tf.run_records(runs), by_strategy).splitlines()
    assert lines[0] == "| tracker | all routes | random_turns | sustained_turns |"
    assert [line.split(" | ")[0] for line in lines[2:]] == ["| oracle_reference", "| via_4000", "| imm_4000",
                                                              "| imm_4000_m_of_n"]
    assert lines[4] == "| imm_4000 | 1.20 · 0.950 | 1.50 · 0.900 | 1.00 · 0.875 |"
    assert lines[3] == "| via_4000 | n/a · 0.900 | n/a · n/a | n/a · n/a |"

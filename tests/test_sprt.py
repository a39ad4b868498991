"""The SPRT track management rule (`pipeline.tracker.sprt`), alone and in the tracking loop with the stub
parts of `tests/test_tracker_loop.py` (no networks).

The params' test: P_D = 0.9, P_F = 0.05, alpha = 0.001, beta = 0.1, so a hit adds ln 18 = 2.89 nats, a miss
ln(0.1 / 0.95) = -2.25, confirmation is at ln 900 = 6.80 (the third hit in a row) and deletion of a tentative
track at ln(0.1 / 0.999) = -2.30. One opportunity is one 6 s scan (the stub plots' radar's): a miss is
recorded 9 s after a hit, then every 6 s.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pipeline.params import ParamError
from pipeline.settings import parse_params
from pipeline.tracker import registry
from pipeline.tracker.sprt import QUANTUM, SequentialRatioTest
from pipeline.tracker.run import track
from tests import tracker_fixtures as tf
from tests.test_tracker_loop import composition, plots

RULE = SequentialRatioTest.from_probabilities(0.9, 0.05, 0.001, 0.1)
HIT, MISS = math.log(0.9 / 0.05), math.log(0.1 / 0.95)
UPPER, LOWER = math.log(0.9 / 0.001), math.log(0.1 / 0.999)


def sprt(**parts):
    """The stub composition of tests/test_tracker_loop.py under RULE."""
    return dataclasses.replace(composition(**parts), management=RULE)


def test_the_weight_is_the_log_likelihood_ratio_of_hits_and_misses():
    """A new track holds one hit; a second hit adds ln(P_D / P_F), a miss ln((1 - P_D) / (1 - P_F)); the third
    hit in a row passes T2 = ln((1 - beta) / alpha), and the track's weight jumps to T2 plus the test's width."""
    one = RULE.start
    assert one == pytest.approx(HIT, abs=QUANTUM)
    two = RULE.associated(one)
    assert two == pytest.approx(2 * HIT, abs=QUANTUM) and RULE.status(two) == "tentative"
    missed = RULE.lowered(two)
    assert missed == pytest.approx(2 * HIT + MISS, abs=QUANTUM) and RULE.status(missed) == "tentative"
    three = RULE.associated(two)
    assert RULE.status(three) == "confirmed" and three == pytest.approx(UPPER + (UPPER - LOWER), abs=QUANTUM)


def test_a_miss_is_recorded_one_and_a_half_scans_after_a_hit_then_every_scan():
    assert RULE.silence(RULE.start, 6.0) == 9.0
    assert RULE.silence(RULE.lowered(RULE.start), 6.0) == 6.0
    assert RULE.silence(RULE.associated(RULE.lowered(RULE.start)), 6.0) == 9.0


def test_a_tentative_track_is_deleted_when_its_score_falls_to_t1_and_a_confirmed_one_after_the_tests_width():
    """One hit, then misses: 2.89, 0.64, -1.61, -3.86 <= T1, deleted at the third miss. Confirmed: its score
    falls 2.25 a miss from T2 + 9.10 and the track is deleted at the fifth, which takes it to T2 or below."""
    weight, misses = RULE.start, 0
    while weight is not None:
        weight, misses = RULE.lowered(weight), misses + 1
    assert misses == 3
    weight = RULE.associated(RULE.associated(RULE.start))
    statuses = []
    while weight is not None:
        statuses.append(RULE.status(weight))
        weight = RULE.lowered(weight)
    assert statuses == ["confirmed"] * 5  # confirmed at every weight it held, deleted at the fifth miss


def test_a_confirmed_track_that_hits_again_is_capped():
    full = RULE.associated(RULE.associated(RULE.start))
    assert RULE.associated(full) == full
    assert RULE.associated(RULE.lowered(full)) == full


def test_confirmed_reads_an_array_of_weights():
    weights = np.array([RULE.start, RULE.associated(RULE.start), RULE.associated(RULE.associated(RULE.start))])
    assert RULE.confirmed(weights).tolist() == [False, False, True]


def test_in_the_loop_three_plots_a_scan_apart_confirm_and_a_lone_plots_track_dies_at_its_third_miss():
    """Plots at 0, 6 and 12 s: confirmed by the third. A lone plot's track records misses at 9, 15 and 21 s
    and is deleted at 21 s: a plot at the same place at 20.9 s joins it, one at 21.1 s starts a new track."""
    updates = track(plots([0, 6, 12], [0, 100, 200]), sprt())
    assert tf.tracks_of(updates) == {0: [0, 1, 2]}
    assert [RULE.status(w) for w in updates["weight"]] == ["tentative", "tentative", "confirmed"]
    assert track(plots([0, 20.9], [0, 100]), sprt())["track_id"].tolist() == [0, 0]
    assert track(plots([0, 21.1], [0, 100]), sprt())["track_id"].tolist() == [0, 1]


@pytest.mark.parametrize("probabilities", [(0.9, 0.9, 0.001, 0.1), (0.05, 0.1, 0.001, 0.1), (0.9, 0.05, 0.5, 0.5)])
def test_probabilities_that_make_no_test_are_refused(probabilities):
    with pytest.raises(ValueError, match="the SPRT needs"):
        SequentialRatioTest.from_probabilities(*probabilities)


def test_params_name_the_rule_and_refuse_a_false_plot_probability_above_the_detection_probability(params_tree):
    params_tree["tracker"]["management"]["rule"] = "sprt"
    params = parse_params(params_tree)
    assert isinstance(registry.management(params.tracker.management.rule, params.tracker), SequentialRatioTest)
    params_tree["tracker"]["management"]["sprt_false_plot_probability"] = 0.95
    with pytest.raises(ParamError, match=r"tracker.management.sprt_false_plot_probability = 0.95: must be below "
                                         r"tracker.management.sprt_detection_probability = 0.9"):
        parse_params(params_tree)

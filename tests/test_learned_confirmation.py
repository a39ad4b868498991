"""The learned confirmation rule (`pipeline.tracker.learned_confirmation`), its scorer
(`pipeline.learning.confirmation`) and the evidence the loop hands a rule, with the stub parts of
`tests/test_tracker_loop.py` (no networks but the scorer's own)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from pipeline.learning.confirmation import ConfirmationConfig, HitScorer, Scorer, features
from pipeline.params import ParamError
from pipeline.settings import parse_params
from pipeline.tracker import registry
from pipeline.tracker.learned_confirmation import LEVELS, MAX_N, LearnedConfirmation, level, threshold_for
from pipeline.tracker.m_of_n import MOfN
from pipeline.tracker.management import Evidence
from pipeline.tracker.models import Models
from pipeline.tracker.run import track
from tests.test_tracker_loop import ORIGIN, composition, plots

EVIDENCE = Evidence(0.1, 1.0, 1, 200.0, 5.0)


def constant(m: int, n: int, score: float = 1.0) -> LearnedConfirmation:
    return LearnedConfirmation(n, m * LEVELS, 20.0, 3.25, lambda evidence: score)


@pytest.mark.parametrize("m, n", [(1, 1), (2, 3), (3, 5), (4, 4), (5, 13)])
def test_with_a_constant_score_it_is_m_of_n(m, n):
    """Every hit at the top level and the threshold m levels-full: the rule confirms, deletes and waits exactly as
    M-of-N with (m, n), on random sequences of hits and misses."""
    learned, counted = constant(m, n), MOfN(m, n, 20.0, 3.25)
    rng = np.random.default_rng(m * 100 + n)
    for _ in range(200):
        ours, theirs = learned.start, counted.start
        for hit in rng.random(12) < 0.6:
            assert learned.status(ours) == counted.status(theirs)
            assert learned.silence(ours, 6.0) == counted.silence(theirs, 6.0)
            ours, theirs = ((learned.associated(ours, EVIDENCE), counted.associated(theirs)) if hit
                            else (learned.lowered(ours), counted.lowered(theirs)))
            assert (ours is None) == (theirs is None)
            if ours is None:
                break


def test_in_the_loop_a_constant_score_gives_m_of_ns_tracks():
    """The stub tracker on plots a scan apart with a gap and a lone plot: the same tracks and confirmations as
    M-of-N (3 of 5)."""
    scenario = plots([0, 6, 12, 24, 30, 31, 60], [0, 500, 1000, 2000, 2500, 9000, 5000])
    ours = track(scenario, dataclasses.replace(composition(), management=constant(3, 5)))
    theirs = track(scenario, dataclasses.replace(composition(), management=MOfN(3, 5, 20.0, 3.25)))
    assert ours["track_id"].tolist() == theirs["track_id"].tolist()
    assert constant(3, 5).confirmed(ours["weight"]).tolist() == MOfN(3, 5, 20.0, 3.25).confirmed(
        theirs["weight"]).tolist()


def test_a_low_score_delays_confirmation_and_a_high_one_hastens_it():
    """Threshold 2.5 hits' worth: hits scored 1 confirm at the third plot (the start counts as a top-level hit);
    hits scored 0 count one level each, so the track is still tentative after ten of them."""
    threshold = round(2.5 * LEVELS)
    fast = LearnedConfirmation(5, threshold, 20.0, 3.25, lambda e: 1.0)
    slow = LearnedConfirmation(5, threshold, 20.0, 3.25, lambda e: 0.0)
    weight = fast.associated(fast.associated(fast.start, EVIDENCE), EVIDENCE)
    assert fast.status(fast.associated(fast.start, EVIDENCE)) == "tentative" and fast.status(weight) == "confirmed"
    weight = slow.start
    for _ in range(10):
        weight = slow.associated(weight, EVIDENCE)
    assert slow.status(weight) == "tentative" and slow.window_sum(weight) == 5


def test_levels_and_the_weights_grid():
    assert [level(s) for s in (-1.0, 0.0, 0.5, 1.0, 2.0)] == [1, 1, 8, LEVELS, LEVELS]
    rule = constant(MAX_N, MAX_N)  # the longest window, every hit in it needed
    weight = rule.start
    for _ in range(MAX_N - 2):
        weight = rule.associated(weight, EVIDENCE)
    assert rule.window_sum(weight) == (MAX_N - 1) * LEVELS and rule.status(weight) == "tentative"
    assert rule.status(rule.associated(weight, EVIDENCE)) == "confirmed"
    with pytest.raises(ValueError, match="must be 1..13"):
        LearnedConfirmation(MAX_N + 1, 1.0, 20.0, 3.25, lambda e: 1.0)


def test_the_threshold_confirms_at_most_the_asked_share_of_clutters_tracks():
    maxima = np.arange(1, 101)  # 100 clutter tracks, the k-th at most k levels
    for probability in (0.001, 0.01, 0.05, 0.5):
        threshold = threshold_for(maxima, probability)
        assert np.mean(maxima >= threshold) <= probability
        assert np.mean(maxima >= threshold - 1) > probability  # the least such threshold
    with pytest.raises(ValueError, match=r"must lie in \(0, 1\)"):
        threshold_for(maxima, 1.0)
    with pytest.raises(ValueError, match="no clutter tracks"):
        threshold_for(np.array([]), 0.01)


def test_the_numpy_scorer_is_the_network():
    torch.manual_seed(0)
    network = HitScorer(ConfirmationConfig(8)).double()  # float64: the scorer's arithmetic
    inputs = features(np.array([0.0, 0.3, 0.99, np.inf]), np.array([1.0, 2.0, 0.0, 7.0]), np.array([1, 4, 20, 2]),
                      np.array([250.0, 30.0, np.inf, 0.0]), np.array([0.0, 12.0, np.inf, 40.0]))
    expected = torch.sigmoid(network(torch.from_numpy(inputs))).detach().numpy()
    scorer = Scorer(network)
    np.testing.assert_allclose(scorer.scores(inputs), expected, rtol=1e-12)
    one = Evidence(0.3, 2.0, 4, 30.0, 12.0)
    assert scorer(one) == pytest.approx(expected[1], rel=1e-12)
    assert scorer(Evidence(0.99, 0.0, 20, math.inf, math.inf)) == pytest.approx(expected[2], rel=1e-12)


def test_the_loop_hands_the_rule_each_associations_evidence():
    """Plots 1.5 km apart a 6 s scan apart (250 m/s), then one 1.5 km on after a missed scan (125 m/s), along ECEF
    x, which climbs at the stub's place (x . up = 0.45): the rule sees the gate's error, the gap in scans, the
    plots the track had, and the two plots' speed split into horizontal and vertical."""
    seen: list[Evidence] = []
    rule = LearnedConfirmation(5, math.inf, 20.0, 3.25, lambda e: seen.append(e) or 1.0)
    track(plots([0, 6, 18], [0, 1500, 3000]), dataclasses.replace(composition(), management=rule))
    assert [e.plots for e in seen] == [1, 2]
    assert [e.gap_scans for e in seen] == pytest.approx([6.0 / 6.0, 12.0 / 6.0], rel=1e-9)
    assert [math.hypot(e.speed_mps, e.climb_mps) for e in seen] == pytest.approx([250.0, 125.0], rel=1e-9)
    up = (ORIGIN + [750.0, 0.0, 0.0]) / np.linalg.norm(ORIGIN + [750.0, 0.0, 0.0])  # between the first two plots
    assert seen[0].climb_mps == pytest.approx(250.0 * up[0], rel=1e-9)
    assert 0.0 <= seen[0].error < 1.0 and 0.0 <= seen[1].error < 1.0
    seen.clear()  # a second plot at the first's time: no aircraft's next plot, infinitely fast
    track(plots([0, 0], [0, 300]), dataclasses.replace(composition(), management=rule))
    assert seen == [Evidence(seen[0].error, 0.0, 1, math.inf, math.inf)]


def test_the_registry_needs_the_network_for_the_learned_rule(params_tree):
    params = parse_params(params_tree)
    with pytest.raises(ValueError, match="train_confirmation"):
        registry.management("learned", params.tracker, Models({}))
    reading = registry.management("learned", params.tracker)  # scoring reads weights without the network
    assert reading.confirmed(np.array([0.5, 1.0])).tolist() == [False, True]
    with pytest.raises(ValueError, match="train_confirmation"):
        reading.associated(reading.start, EVIDENCE)
    assert registry.rule_needs(["thesis", None]) == set() and registry.rule_needs(["learned"]) == {"confirmation"}


def test_params_refuse_a_false_track_probability_outside_0_1_and_a_window_the_weight_cannot_hold(params_tree):
    params_tree["tracker"]["management"]["learned_false_track_probability"] = 1.0
    with pytest.raises(ParamError, match="tracker.management.learned_false_track_probability = 1.0"):
        parse_params(params_tree)
    params_tree["tracker"]["management"].update(learned_false_track_probability=0.01, rule="learned",
                                                confirm_n=MAX_N + 1)
    with pytest.raises(ParamError, match=f"tracker.management.confirm_n = {MAX_N + 1}: the learned rule keeps at "
                                         f"most {MAX_N}"):
        parse_params(params_tree)

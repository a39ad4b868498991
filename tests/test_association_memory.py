"""Association with memory: a pair the method misses is kept while it passes the keep gate, two tracks the method
left unpaired that pass it are paired, and the memory does not cross scenarios."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from pipeline.association.association_memory import continue_pairs, pair_statistics, with_memory
from pipeline.association.common_time_states import Snapshot

KEEP = 0.999999
KEEP_GATE = chi2.ppf(KEEP, 4)   # 33.4


def snapshot(first_east_m: list[float], second_east_m: list[float], scenario_id: int = 0) -> Snapshot:
    """Tracks at east positions (m) flying north at 200 m/s, position variance 100 m², velocity 25 (m/s)², per
    axis; ids 10, 11, ... for the first user and 20, 21, ... for the second."""
    def user(east: list[float], first_id: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        states = np.array([[e, 0.0, 0.0, 0.0, 200.0, 0.0] for e in east]).reshape(-1, 6)
        covariances = np.tile(np.diag([100.0, 100.0, 100.0, 25.0, 25.0, 25.0]), (len(east), 1, 1))
        return first_id + np.arange(len(east)), states, covariances
    (ids1, x1, p1), (ids2, x2, p2) = user(first_east_m, 10), user(second_east_m, 20)
    return Snapshot(scenario_id, 0.0, (ids1, ids2), (x1, x2), (p1, p2))


def test_the_statistic_is_the_horizontal_chi_square_after_the_offset():
    # 100 m east apart, S = 200 m² on east: 100² / 200 = 50; less a 60 m offset: 40² / 200 = 8
    assert pair_statistics(snapshot([0.0], [100.0]), None)[0, 0 ] == 50.0
    assert pair_statistics(snapshot([0.0], [100.0]), np.array([60.0, 0.0]))[0, 0] == 8.0


def test_a_held_pair_is_kept_while_it_passes_the_keep_gate_and_dropped_beyond():
    near = 0.9 * np.sqrt(KEEP_GATE * 200.0)   # statistic 0.81 x the keep gate: over the 0.999 gate, under the keep
    far_away = 5000.0                          # a third track the held pair cannot reach
    held = {(10, 20)}
    none = np.zeros((0, 2), dtype=np.int64)
    kept = continue_pairs(snapshot([0.0, far_away], [near]), none, None, held, KEEP)
    assert kept.tolist() == [[0, 0]]
    broken = continue_pairs(snapshot([0.0, far_away], [1.2 * np.sqrt(KEEP_GATE * 200.0)]), none, None, held, KEEP)
    assert broken.tolist() == []


def test_a_held_pair_wins_over_the_methods_conflicting_pair_and_the_method_keeps_the_rest():
    # the method pairs first 0 with second 1 and first 1 with second 2; the held pair (ids 10, 20: rows 0, 0)
    # takes first 0, so the method's first pair goes and its second stays
    scene = snapshot([0.0, 3000.0], [10.0, 40.0, 3010.0])
    kept = continue_pairs(scene, np.array([[0, 1], [1, 2]]), None, {(10, 20)}, KEEP)
    assert kept.tolist() == [[0, 0], [1, 2]]


def test_tracks_left_unpaired_that_pass_the_keep_gate_are_paired_far_ones_are_not():
    scene = snapshot([0.0, 3000.0], [70.0, 9000.0])          # 70 m: statistic 24.5, over 18.5, under 33.4
    kept = continue_pairs(scene, np.zeros((0, 2), dtype=np.int64), None, set(), KEEP)
    assert kept.tolist() == [[0, 0]]


def test_memory_holds_within_a_scenario_and_is_emptied_at_a_new_one():
    # ids 10 and 20 paired at time 0; at time 1 the method prefers second 21 (row 1): memory keeps (10, 20);
    # in scenario 1 the same ids are other aircraft, so the method's choice stands
    snapshots = [snapshot([0.0], [0.0]), snapshot([0.0], [10.0, 20.0]), snapshot([0.0], [10.0, 20.0], scenario_id=1)]
    method = [np.array([[0, 0]]), np.array([[0, 1]]), np.array([[0, 1]])]
    out = with_memory(snapshots, method, [None] * 3, KEEP)
    assert [pairs.tolist() for pairs in out] == [[[0, 0]], [[0, 0]], [[0, 1]]]

"""GOSPA (alpha = 2) with its parts, and the identity metrics on its assignment (`pipeline.bench.gospa`),
on hand-computed examples; GOSPA's metric properties on random sets; its wiring into the
single-target evaluation.

Unless a test says otherwise: cutoff c = 1000 m, order p = 2, so a missed truth or a false track
costs c^p/2 = 500 000 m^2, and alone gives GOSPA = sqrt(500 000) = 707.1 m.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from pipeline.bench import evaluation, gospa, ospa
from pipeline.bench.tracker_metrics import RouteCounts
from pipeline.reports import comparison_tables
from pipeline.tracker.management import ThesisWeights
from tests import tracker_fixtures as tf

C, P = 1000.0, 2.0
HALF = C ** P / 2.0  # 500 000 m^2


def parts(distances: list[list[float]] | np.ndarray, cutoff: float = C, order: float = P) -> np.ndarray:
    """One scan's parts (3,) m^p from its distances (truths x tracks) m."""
    return gospa.gospa_parts(np.asarray(distances, dtype=float), cutoff, order)[0]


# ----------------------------------------------------------------------------- one scan

def test_an_empty_scan_costs_nothing():
    assert parts(np.empty((0, 0))).tolist() == [0.0, 0.0, 0.0]
    assert gospa.gospa(np.empty((0, 0)), C, P) == 0.0


def test_a_truth_without_a_track_is_missed_only():
    """GOSPA = (c^p/2)^(1/p), not OSPA's c."""
    assert parts(np.empty((1, 0))).tolist() == [0.0, HALF, 0.0]
    assert gospa.gospa(np.empty((1, 0)), C, P) == pytest.approx(np.sqrt(HALF))
    assert gospa.gospa(np.empty((1, 0)), C, 1.0) == pytest.approx(500.0)


def test_a_track_without_a_truth_is_false_only():
    assert parts(np.empty((0, 1))).tolist() == [0.0, 0.0, HALF]
    assert gospa.gospa(np.empty((0, 3)), C, P) == pytest.approx(np.sqrt(3 * HALF))


def test_a_pair_within_the_cutoff_is_localisation_beyond_it_a_miss_and_a_false_track():
    assert parts([[300.0]]).tolist() == [90_000.0, 0.0, 0.0]
    assert gospa.gospa(np.array([[300.0]]), C, P) == pytest.approx(300.0)
    for beyond in (1000.0, 1500.0):  # at the cutoff or beyond: unpaired, c^p/2 + c^p/2 = c^p
        distances = np.array([[beyond]])
        assert parts(distances).tolist() == [0.0, HALF, HALF]
        assert gospa.gospa(distances, C, P) == pytest.approx(C)
        assert len(gospa.gospa_parts(distances, C, P)[1]) == 0


def test_two_truths_and_two_tracks_take_the_best_assignment_not_the_nearest_pair():
    """Truth 0 is 100 m from track 0 and 200 m from track 1; truth 1 150 m from track 0 and 900 m
    from track 1. Pairing the nearest first (100, then 900) costs 820 000 m^2; the assignment
    (200, 150) costs 62 500 m^2: GOSPA 250 m."""
    distances = np.array([[100.0, 200.0], [150.0, 900.0]])
    scan_parts, rows, columns = gospa.gospa_parts(distances, C, P)
    assert scan_parts.tolist() == [62_500.0, 0.0, 0.0]
    assert sorted(zip(rows.tolist(), columns.tolist())) == [(0, 1), (1, 0)]
    assert gospa.gospa(distances, C, P) == pytest.approx(250.0)


def test_more_truths_than_tracks_and_a_pair_beyond_the_cutoff():
    """Three truths, two tracks: truth 0 at 300 m from track 0, truth 2 at 5000 m from track 1, the
    rest far: one pair (300 m), two missed truths, one false track."""
    distances = np.array([[300.0, 4000.0], [3000.0, 6000.0], [2000.0, 5000.0]])
    assert parts(distances).tolist() == [90_000.0, 2 * HALF, HALF]
    assert gospa.gospa(distances, C, P) == pytest.approx(np.sqrt(90_000.0 + 3 * HALF))


def test_order_one_parts_add_up_to_gospa():
    distances = np.array([[300.0], [5000.0]])
    assert parts(distances, order=1.0).tolist() == [300.0, 500.0, 0.0]
    assert gospa.gospa(distances, C, 1.0) == pytest.approx(800.0)


def test_shares_in_metres_split_each_scans_gospa_in_proportion_to_its_parts():
    """Scan 0: a pair at 300 m and a missed truth, GOSPA sqrt(590 000) = 768.1 m, of which
    90/590 localisation and 500/590 missed; scan 1: nothing, 0; scan 2: a false track only,
    707.1 m all false. With p = 1 the shares are the parts."""
    scan_parts = np.array([[90_000.0, HALF, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, HALF]])
    shares = gospa.shares_in_metres(scan_parts, P)
    total = np.sqrt(590_000.0)
    np.testing.assert_allclose(shares, [[total * 90 / 590, total * 500 / 590, 0.0], [0.0, 0.0, 0.0],
                                        [0.0, 0.0, np.sqrt(HALF)]])
    np.testing.assert_allclose(shares.sum(axis=1), [total, 0.0, np.sqrt(HALF)])
    linear = np.array([[300.0, 500.0, 0.0]])
    np.testing.assert_allclose(gospa.shares_in_metres(linear, 1.0), linear)


# ----------------------------------------------------------------------------- metric properties

def random_set(rng: np.random.Generator) -> np.ndarray:
    """0 to 4 points in a 3 km cube: some pairs nearer than the cutoff, some beyond."""
    return rng.uniform(0.0, 3000.0, size=(rng.integers(0, 5), 3))


def distance(x: np.ndarray, y: np.ndarray, order: float) -> float:
    return gospa.gospa(cdist(x, y) if len(x) and len(y) else np.empty((len(x), len(y))), C, order)


@pytest.mark.parametrize("order", [1.0, 2.0, 3.0])
def test_gospa_is_a_metric_on_random_sets(order):
    """Symmetric, zero exactly for equal sets, and the triangle inequality on random triples."""
    rng = np.random.default_rng(16)
    for _ in range(200):
        x, y, z = random_set(rng), random_set(rng), random_set(rng)
        assert distance(x, y, order) == pytest.approx(distance(y, x, order), abs=1e-9)
        assert distance(x, x, order) == 0.0
        if len(x):
            assert distance(x, x[::-1], order) == 0.0                  # a set: the order of its points is none
            assert distance(x, x + [1.0, 0.0, 0.0], order) > 0.0      # any change is seen
            assert distance(x, x[1:], order) > 0.0
        assert distance(x, z, order) <= distance(x, y, order) + distance(y, z, order) + 1e-9


# ----------------------------------------------------------------------------- identity over scans

CROSSING_SCANS = np.arange(12)


def crossing(swapping: bool) -> gospa.ScanGospa:
    """Two aircraft (truths 1 and 2) flying east 1 km per scan and crossing north-south between
    scans 4 and 5 (truth 1 at y = 900 - 200 k m, truth 2 at y = -900 + 200 k m). Tracks 7 and 8
    follow them 30 m behind; the swapping tracker's tracks bounce off each other at the crossing,
    so from scan 5 track 7 is on truth 2 and track 8 on truth 1."""
    k = CROSSING_SCANS.astype(float)
    truth = {1: np.column_stack([1000.0 * k, 900.0 - 200.0 * k]), 2: np.column_stack([1000.0 * k, -900.0 + 200.0 * k])}
    swapped = swapping & (k >= 5)
    followed = {7: np.where(swapped, 2, 1), 8: np.where(swapped, 1, 2)}
    truth_positions = np.stack([truth[1], truth[2]], axis=1).reshape(-1, 2)   # rows by scan: truth 1, truth 2
    track_positions = np.stack([np.where(followed[t][:, None] == 1, truth[1], truth[2]) - [30.0, 0.0]
                                for t in (7, 8)], axis=1).reshape(-1, 2)
    return gospa.scan_gospa(CROSSING_SCANS, np.repeat(CROSSING_SCANS, 2), np.tile([1, 2], 12),
                            np.repeat(CROSSING_SCANS, 2), np.tile([7, 8], 12),
                            lambda truths, tracks: cdist(truth_positions[truths], track_positions[tracks]), C, P)


def test_a_crossing_where_the_tracks_swap_is_two_switches_one_per_truth():
    """Every scan both truths are tracked 30 m off: GOSPA 2 x 30^2 per scan before the root. The
    swapping tracker: truth 1 is on track 7 for scans 0-4, on 8 for 5-11 (one switch), truth 2 the
    other way round; each track spends 5 scans on one truth, 7 on the other (purity 7/12); two
    tracks per truth. The tracker that keeps identities: no switch, purity 1, one track each."""
    truths = np.array([1, 2])
    for swapping, switches, per_truth, purity in ((True, [1, 1], [2, 2], [7 / 12, 7 / 12]),
                                                  (False, [0, 0], [1, 1], [1.0, 1.0])):
        scored = crossing(swapping)
        np.testing.assert_allclose(scored.parts, np.tile([2 * 30.0 ** 2, 0.0, 0.0], (12, 1)))
        assert gospa.track_switches(scored.truth, scored.scan, scored.track, truths).tolist() == switches
        assert gospa.tracks_per_truth(scored.truth, scored.track, truths).tolist() == per_truth
        np.testing.assert_allclose(gospa.track_purity(scored.truth, scored.track), purity)


def test_scans_without_a_track_neither_reset_nor_count_as_a_switch():
    """Assigned pairs (scan, truth, track), shuffled: truth 1 goes A(10), none, B(11): one switch;
    truth 2 A(12), none, A: none; truth 3 A(13), B(14), A: two; truth 4 is never tracked: 0 switches,
    0 tracks; truth 5 has track 12 once. Purity, tracks 10 to 14: each keeps to one truth but
    track 12, 2 scans on truth 2 and 1 on truth 5: 2/3."""
    pairs = np.array([(0, 1, 10), (2, 1, 11), (0, 2, 12), (2, 2, 12), (0, 3, 13), (1, 3, 14), (2, 3, 13),
                      (5, 5, 12)])
    pairs = pairs[np.random.default_rng(0).permutation(len(pairs))]
    scan, truth, track = pairs.T
    truths = np.array([1, 2, 3, 4, 5])
    assert gospa.track_switches(truth, scan, track, truths).tolist() == [1, 0, 2, 0, 0]
    assert gospa.tracks_per_truth(truth, track, truths).tolist() == [2, 1, 2, 0, 1]
    np.testing.assert_allclose(gospa.track_purity(truth, track), [1.0, 1.0, 2 / 3, 1.0, 1.0])


def test_scans_with_one_side_empty_solve_no_assignment():
    """Scan 0: a truth alone; scan 1: two tracks alone; scan 2: nothing: the distances are never asked."""
    def never(truths, tracks):
        raise AssertionError("no scan has both truths and tracks")

    scored = gospa.scan_gospa(np.arange(3), np.array([0]), np.array([1]), np.array([1, 1]), np.array([7, 8]),
                              never, C, P)
    assert scored.parts.tolist() == [[0.0, HALF, 0.0], [0.0, 0.0, 2 * HALF], [0.0, 0.0, 0.0]]
    assert len(scored.scan) == len(scored.truth) == len(scored.track) == 0


# ----------------------------------------------------------------------------- the single-target evaluation

def test_single_target_gospa_uses_ospas_sets():
    """The OSPA test's run (tests/test_classical.py), cutoff 1000 m: scan 0 the target in coverage
    with only an unconfirmed track -> missed; scan 1 a confirmed track whose last update is 300 m
    off -> 300 m; scan 2 nothing -> 0; scan 3 a confirmed track, the target out of coverage ->
    false; scan 4 in coverage, the track below the confirmed weight -> missed."""
    def truth_at(times):
        return np.column_stack([100.0 * times, np.zeros_like(times), np.full_like(times, 9000.0)])

    rows = [(0, 1, 1.0, 50.0, 0.2, "start"), (1, 1, 6.5, 700.0, 0.8, "imm"), (1, 1, 7.0, 300.0, 0.8, "imm"),
            (3, 1, 19.0, 10.0, 0.8, "imm"), (4, 2, 25.0, 10.0, 0.4, "radius")]
    times = np.array([r[2] for r in rows])
    positions = truth_at(times) + np.column_stack([np.zeros(len(rows)), [r[3] for r in rows], np.zeros(len(rows))])
    updates = {"track_id": np.array([r[1] for r in rows]), "time_unix_s": times, "plot_id": np.arange(len(rows)),
               "x_ecef_m": positions[:, 0], "y_ecef_m": positions[:, 1], "z_ecef_m": positions[:, 2],
               "weight": np.array([r[4] for r in rows]), "association": np.array([r[5] for r in rows])}
    rule = ThesisWeights(start=0.2, candidate=0.6, confirmed_weight=0.8, step=0.2, silence_s=12.0)
    estimates = ospa.scan_estimates(updates, np.array([r[0] for r in rows]), rule)
    scenario = evaluation.Scenario(0, None, {}, truth_at, np.arange(5), np.array([0, 1, 4]), "constant_jerk")
    scored = evaluation.target_gospa(scenario, estimates, np.arange(5), C, P)
    np.testing.assert_allclose(scored.parts, [[0.0, HALF, 0.0], [90_000.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                                              [0.0, 0.0, HALF], [0.0, HALF, 0.0]])
    assert (scored.scan.tolist(), scored.truth.tolist(), scored.track.tolist()) == ([1], [0], [1])


def unit(shares: list[list[float]], switches: int, per_truth: list[int], purity: list[float]) -> evaluation.UnitResult:
    return evaluation.UnitResult(RouteCounts(1, 0, 0, 0, 0, 0.0, 0, [], 0), np.zeros(len(shares)),
                                 np.array(shares), switches, np.array(per_truth), np.array(purity), np.empty(0), 1.0,
                                 None)


def test_run_metrics_gospa_parts_add_up_to_gospa():
    """Three scans over two routes: GOSPA means (300 + 0 + 707.1) / 3; each part the mean of its
    shares; switches summed; tracks per truth over the routes with a target in coverage (the
    second has none); purity over the tracks of both routes."""
    metrics = evaluation.run_metrics([unit([[300.0, 0.0, 0.0], [0.0, 0.0, 0.0]], 1, [2], [0.5, 1.0]),
                                      unit([[0.0, 0.0, 707.1]], 0, [], [1.0])], plots=10)
    assert metrics["GOSPA"] == pytest.approx(1007.1 / 3)
    assert (metrics["GOSPA_localisation"], metrics["GOSPA_missed"], metrics["GOSPA_false"]) == pytest.approx(
        (100.0, 0.0, 707.1 / 3))
    assert metrics["GOSPA_localisation"] + metrics["GOSPA_missed"] + metrics["GOSPA_false"] == pytest.approx(
        metrics["GOSPA"])
    assert (metrics["track_switches"], metrics["tracks_per_truth"]) == (1, 2.0)
    assert metrics["track_purity"] == pytest.approx(2.5 / 3)


# ----------------------------------------------------------------------------- the comparison's table

def test_gospa_table_best_first_and_none_for_reports_before_gospa():
    """The compare report's GOSPA table: best GOSPA first, the parts in metres, n/a where a metric is
    undefined; no table from reports written before GOSPA (docs/results.md keeps its other tables)."""
    runs = {"via_4000": {"GOSPA": 300.4, "GOSPA_localisation": 100.0, "GOSPA_missed": 150.2, "GOSPA_false": 50.2,
                         "track_switches": 3, "tracks_per_truth": 1.5, "track_purity": 0.9876},
            "oracle_reference": {"GOSPA": 120.0, "GOSPA_localisation": 60.0, "GOSPA_missed": 60.0, "GOSPA_false": 0.0,
                                 "track_switches": 0, "tracks_per_truth": 1.0, "track_purity": float("nan")},
            "via_5000": {"OSPA": 250.0}}
    lines = comparison_tables.gospa_table(tf.run_records(runs)).splitlines()
    assert lines[0] == ("| tracker | GOSPA (m) | localisation (m) | missed (m) | false (m) | track switches | "
                        "tracks assigned per aircraft | track purity |")
    assert lines[2:] == ["| oracle_reference | 120 | 60 | 60 | 0 | 0 | 1.00 | n/a |",
                         "| via_4000 | 300 | 100 | 150 | 50 | 3 | 1.50 | 0.988 |"]
    assert comparison_tables.gospa_table(tf.run_records({"via_4000": {"OSPA": 250.0, "GOSPA": None}})) == ""

"""The surveillance scorecard (`pipeline.surveillance.scorecard`) on hand-made tracks whose answers are known:
an offset across track, a gap of exactly 3.3 scans and one a little longer, a swap, a false track."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry import geodesy
from pipeline.surveillance import scorecard
from pipeline.surveillance.scorecard import Settings, TrackUpdates, Truth
from tests.tracker_fixtures import make_params

SCAN_S = 6.0
SETTINGS = Settings.from_params(SCAN_S, make_params().scorecard)  # ED-129C's 3.3 scans, 2 km, 1 m/s^2
ROTATION = geodesy.enu_rotation(52.0, 4.0)
ORIGIN = geodesy.geodetic_to_ecef(52.0, 4.0, 9000.0)


def ecef(east_north_up: np.ndarray) -> np.ndarray:
    """Local east-north-up offsets (N, 3) m about ORIGIN as ECEF (flat: what the tests need)."""
    return ORIGIN + np.asarray(east_north_up, dtype=float) @ ROTATION


def straight_truth(target: int, times: np.ndarray, north_m: float = 0.0, heading_east: bool = True) -> Truth:
    """A target flying east (or west) at 200 m/s, `north_m` north of ORIGIN, sampled at `times`, in coverage."""
    sign = 1.0 if heading_east else -1.0
    enu = np.stack([sign * 200.0 * (times - times[0]) - (0.0 if heading_east else -60e3), np.full_like(times, north_m),
                    np.zeros_like(times)], axis=1)
    return Truth(np.full(len(times), target), times, ecef(enu), np.ones(len(times), bool))


def joined(*truths: Truth) -> Truth:
    return Truth(*(np.concatenate([getattr(t, name) for t in truths]) for name in ("target_id", "time_s", "position",
                                                                                     "in_coverage")))


def updates_of(track: int, truth: Truth, rows: np.ndarray, offset_enu=(0.0, 0.0, 0.0), confirmed: bool = True
               ) -> TrackUpdates:
    """A track at the truth's samples `rows`, moved by `offset_enu`, with the true velocity."""
    velocity = np.gradient(truth.position[rows], truth.time_s[rows], axis=0) if len(rows) > 1 else np.zeros((1, 3))
    return TrackUpdates(np.full(len(rows), track), truth.time_s[rows], truth.position[rows] + np.asarray(offset_enu) @ ROTATION,
                        velocity, np.full(len(rows), confirmed))


def together(*parts: TrackUpdates) -> TrackUpdates:
    return TrackUpdates(*(np.concatenate([getattr(p, name) for p in parts]) for name in
                          ("track_id", "time_s", "position", "velocity", "confirmed")))


TIMES = np.arange(0.0, 600.0 + SCAN_S, SCAN_S)  # 101 scans


def test_a_track_offset_100_m_across_track_has_100_m_across_and_nothing_along() -> None:
    truth = straight_truth(0, TIMES)
    card = scorecard.scorecard(updates_of(5, truth, np.arange(len(TIMES)), (0.0, 100.0, 0.0)), truth, SETTINGS)
    assert card["across_track_rms_m"] == pytest.approx(100.0, abs=0.5)
    assert card["along_track_rms_m"] == pytest.approx(0.0, abs=0.5)
    assert card["position_error_mean_m"] == pytest.approx(100.0, abs=0.5)
    assert card["position_error_sigma_m"] == pytest.approx(0.0, abs=0.5)
    assert card["probability_of_update"] == 1.0 and card["ratio_of_long_gaps"] == 0.0
    assert card["straight_within_0_25_nm"] == 1.0 and card["manoeuvring_updates"] == 0
    assert card["velocity_rms_straight_mps"] == pytest.approx(0.0, abs=0.1)
    assert (card["tracks_per_aircraft"], card["false_tracks"], card["track_swaps"], card["initiation_mean_s"]) == \
        (1.0, 0, 0, 0.0)
    judged = {(row["figures"], row["indicator"]): row["passes"] for row in scorecard.judged(card)}
    assert judged[("single-radar", "position_error_mean_m")] and judged[("multi-radar", "position_error_mean_m")]


def test_a_lagging_track_has_a_negative_along_track_mean() -> None:
    truth = straight_truth(0, TIMES)
    card = scorecard.scorecard(updates_of(1, truth, np.arange(len(TIMES)), (-150.0, 0.0, 0.0)), truth, SETTINGS)
    assert card["along_track_mean_m"] == pytest.approx(-150.0, abs=0.5)
    assert card["across_track_rms_m"] == pytest.approx(0.0, abs=0.5)


@pytest.mark.parametrize("gap_scans, long", [(3.3, False), (3.31, True)])
def test_a_gap_of_exactly_3_3_scans_is_not_long_and_a_longer_one_is(gap_scans: float, long: bool) -> None:
    """ED-129C: a long gap is longer than 3 x 1.1 update intervals. Updates every scan, then one gap of
    `gap_scans` scans, then every scan again: the gap's time less one update interval is missed either way."""
    before = np.arange(0.0, 60.0 + SCAN_S, SCAN_S)
    after = 60.0 + gap_scans * SCAN_S + np.arange(0.0, 300.0, SCAN_S)
    times = np.concatenate([before, after])
    truth = straight_truth(0, np.append(np.arange(0.0, times[-1], 0.5), times[-1]))  # the aircraft, seen all along
    on_track = straight_truth(0, times)
    card = scorecard.scorecard(updates_of(1, on_track, np.arange(len(times))), truth, SETTINGS)
    duration, gap = times[-1] - times[0], gap_scans * SCAN_S
    assert card["probability_of_update"] == pytest.approx(1.0 - (gap - SCAN_S) / duration)
    assert card["ratio_of_long_gaps"] == pytest.approx((gap - SCAN_S) / duration if long else 0.0)


def test_initiation_counts_as_missed_time_and_as_initiation_time() -> None:
    """A track confirmed at the fourth scan (tentative before): three scans unseen."""
    truth = straight_truth(0, TIMES)
    updates = together(updates_of(1, truth, np.arange(3), confirmed=False), updates_of(1, truth, np.arange(3, len(TIMES))))
    card = scorecard.scorecard(updates, truth, SETTINGS)
    assert card["initiation_mean_s"] == 3 * SCAN_S and card["confirmed_updates"] == len(TIMES) - 3
    assert card["probability_of_update"] == pytest.approx(1.0 - 2 * SCAN_S / 600.0)
    assert card["ratio_of_long_gaps"] == 0.0


def test_a_track_that_moves_from_one_aircraft_to_another_is_a_swap_and_a_far_track_is_false() -> None:
    """Two aircraft 1 km apart, flying opposite ways; track 1 follows the first, then from scan 52 the
    second; track 2 is the second's own; track 3 is 30 km from both."""
    first, second = straight_truth(0, TIMES), straight_truth(1, TIMES, north_m=1000.0, heading_east=False)
    swapped = together(updates_of(1, first, np.arange(52)), updates_of(1, second, np.arange(52, len(TIMES))))
    own = updates_of(2, second, np.arange(len(TIMES)))
    far = updates_of(3, first, np.arange(20), (0.0, 30e3, 0.0))
    card = scorecard.scorecard(together(swapped, own, far), joined(first, second), SETTINGS)
    assert card["track_swaps"] == 1
    assert card["false_tracks"] == 1 and card["confirmed_tracks"] == 3
    assert card["targets"] == 2 and card["targets_never_tracked"] == 0
    # track 1 is the first aircraft's (52 of its updates against 49); its last 49 updates are scored against
    # the first aircraft, kilometres away: large errors, not dropped
    assert card["straight_within_0_25_nm"] == pytest.approx((52 + len(TIMES)) / (2 * len(TIMES)))
    assert card["extra_track_ratio"] == 0.0 and card["tracks_per_aircraft"] == 1.0


def test_a_second_track_on_one_aircraft_is_an_extra_track() -> None:
    truth = straight_truth(0, TIMES)
    card = scorecard.scorecard(together(updates_of(1, truth, np.arange(60)),
                                        updates_of(2, truth, np.arange(40, len(TIMES)), (0.0, 50.0, 0.0))),
                               truth, SETTINGS)
    assert card["tracks_per_aircraft"] == 2.0 and card["extra_track_ratio"] == 0.5
    assert card["probability_of_update"] == 1.0


def test_a_turning_aircraft_scores_its_updates_as_manoeuvring() -> None:
    """A 3 deg/s turn (10.5 m/s^2 at 200 m/s): every update is manoeuvring; a track 1 km off is outside 0.25 NM
    and inside 1 NM."""
    rate = np.radians(3.0)
    radius = 200.0 / rate
    angle = rate * TIMES
    enu = np.stack([radius * np.sin(angle), radius * (1.0 - np.cos(angle)), np.zeros_like(angle)], axis=1)
    truth = Truth(np.zeros(len(TIMES), int), TIMES, ecef(enu), np.ones(len(TIMES), bool))
    card = scorecard.scorecard(updates_of(1, truth, np.arange(len(TIMES)), (0.0, 0.0, 0.0)), truth, SETTINGS)
    assert card["manoeuvring_updates"] == len(TIMES) and card["straight_updates"] == 0
    assert card["velocity_rms_manoeuvring_mps"] < 6.0  # the track's velocity: a central difference of the samples
    shifted = TrackUpdates(np.ones(len(TIMES), int), TIMES, truth.position + np.array([900.0, 0.0, 0.0]) @ ROTATION,
                           np.zeros((len(TIMES), 3)), np.ones(len(TIMES), bool))
    card = scorecard.scorecard(shifted, truth, SETTINGS)
    assert card["manoeuvring_within_1_nm"] == 1.0 and np.isnan(card["straight_within_0_25_nm"])


def test_settings_and_truth_out_of_bounds_are_named() -> None:
    with pytest.raises(ValueError, match="update_interval_s = 0.0"):
        Settings.from_params(0.0, make_params().scorecard)
    truth = straight_truth(0, TIMES)
    blind = Truth(truth.target_id, truth.time_s, truth.position, np.zeros(len(TIMES), bool))
    with pytest.raises(ValueError, match="no target in coverage"):
        scorecard.scorecard(updates_of(1, truth, np.arange(3)), blind, SETTINGS)


def test_the_declared_names_are_those_combined_gives() -> None:
    """INDICATORS and COUNTS, which the bench divides per draw and the comparison copies, name every figure."""
    truth = straight_truth(0, TIMES)
    card = scorecard.combined([scorecard.parts(updates_of(1, truth, np.arange(len(TIMES))), truth, SETTINGS)])
    assert sorted(card) == sorted(scorecard.INDICATORS + scorecard.COUNTS)


def test_a_recording_without_a_target_in_coverage_adds_its_tracks_as_false_and_no_time() -> None:
    """A bench route flown wholly outside coverage: a confirmed track on clutter (50 km from the aircraft) counts
    as false, the recording adds no time to the probability of update, and pooled with a covered recording it
    leaves that one's figures unchanged."""
    truth = straight_truth(0, TIMES)
    blind = Truth(truth.target_id, truth.time_s, truth.position, np.zeros(len(TIMES), bool))
    blind_parts = scorecard.parts(updates_of(1, truth, np.arange(3), (0.0, 50e3, 0.0)), blind, SETTINGS)
    assert (blind_parts.targets, blind_parts.confirmed_tracks, blind_parts.false_tracks, blind_parts.duration_s) == \
        (0, 1, 1, 0.0)
    covered = scorecard.parts(updates_of(2, truth, np.arange(len(TIMES))), truth, SETTINGS)
    alone, pooled = scorecard.combined([covered]), scorecard.combined([covered, blind_parts])
    assert pooled["probability_of_update"] == alone["probability_of_update"]
    assert (pooled["false_tracks"], pooled["confirmed_tracks"]) == (1, 2)


def test_two_recordings_combined_score_as_one_recording_of_both() -> None:
    """The bench's units: the parts of two recordings, combined, give what one recording holding both (the second
    moved far in time, its ids its own) gives."""
    first_truth, second_truth = straight_truth(0, TIMES), straight_truth(0, TIMES, north_m=500.0, heading_east=False)
    first = together(updates_of(1, first_truth, np.arange(3, 80)), updates_of(2, first_truth, np.arange(85, 101)))
    second = updates_of(1, second_truth, np.arange(2, 101), (30.0, -40.0, 0.0))
    pieces = [scorecard.parts(first, first_truth, SETTINGS), scorecard.parts(second, second_truth, SETTINGS)]
    shift = 1e7
    both_truth = joined(first_truth, Truth(second_truth.target_id + 1, second_truth.time_s + shift,
                                           second_truth.position, second_truth.in_coverage))
    both = together(first, TrackUpdates(second.track_id + 10, second.time_s + shift, second.position, second.velocity,
                                        second.confirmed))
    alone = scorecard.scorecard(both, both_truth, SETTINGS)
    pooled = scorecard.combined(pieces)
    assert pooled.keys() == alone.keys()
    for name, value in alone.items():
        assert pooled[name] == pytest.approx(value, rel=1e-9, nan_ok=True), name
    assert pooled["tracks_per_aircraft"] == 1.5 and pooled["targets"] == 2

"""Track life counted in revolutions of each plot's own radar (issue 27, case 25), under both track
management rules, and at most one plot of a radar per revolution (`tracker.association.revisit_scans`).

The recordings are built here: a radar's beam turns clockwise from north at T0, so a target is
plotted when the beam meets its azimuth, a little more than a scan after its last plot when it
moves clockwise (12.07 s at 12 s for 230 m/s 60 km out, as in case 25). Plots carry the radar's
measurement errors (radar.sigma_*) and are placed in ECEF as the plot table places them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.geometry import geodesy
from pipeline.params import Radar
from pipeline.recordings import plot_table
from pipeline.recordings.plot_table import Plots
from pipeline.tracker import registry
from pipeline.tracker.assigner import GlobalNearestPerScan
from pipeline.tracker.m_of_n import MOfN
from pipeline.tracker.management import ThesisWeights
from pipeline.tracker.models import Models
from pipeline.tracker.run import track, track_chunks
from pipeline.tracker.updates import confirmed_associations
from tests import tracker_fixtures as tf
from tests.test_m_of_n import TUNED
from tests.test_tracker_loop import ORIGIN, composition

RULES = [registry.THESIS_RULE, registry.M_OF_N_RULE]
SECOND_SITE = (60.3172, 26.05, 60.0)  # about 60 km east of the default radar (case 26's radar 2)


def radar_turning(radar: Radar, sic: int, period_s: float, site: tuple[float, float, float] | None = None) -> Radar:
    """`radar` as radar `sic` (its id: SAC * 256 + SIC) with scan period `period_s`, at `site` if given."""
    if site is not None:
        radar = tf.radar_at(radar, *site)
    return dataclasses.replace(radar, sic=sic, rotation_rpm=60.0 / period_s)


def beam_plots(radar: Radar, start_enu: tuple[float, float, float], velocity_enu: tuple[float, float, float],
               scans: int, seed: int, first_plot_id: int = 0) -> Plots:
    """A constant-velocity target (ENU of the default radar's site, m and m/s, from T0) plotted by
    `radar` once per scan, when its beam (clockwise from north at T0) meets the target's azimuth
    (the target must not cross north); measured with the radar's errors."""
    home = tf.make_params().radar
    scan_s = radar.scan_period_s
    times = tf.T0 + np.arange(scans) * scan_s
    for _ in range(4):  # the beam's time at the target's azimuth: converges in a few steps
        enu = np.asarray(start_enu) + np.outer(times - tf.T0, velocity_enu)
        azimuth = geodesy.true_measurement(tf.enu_to_features(times, enu, home)[:, 1:4], radar)[1]
        times = tf.T0 + (np.arange(scans) + azimuth / 360.0) * scan_s
    truth = tf.enu_to_features(times, enu, home)[:, 1:4]
    slant, azimuth, altitude = geodesy.true_measurement(truth, radar)
    rng = np.random.default_rng(seed)
    slant = slant + rng.normal(0.0, radar.sigma_range_m, scans)
    azimuth = azimuth + rng.normal(0.0, radar.sigma_azimuth_deg, scans)
    altitude = altitude + rng.normal(0.0, radar.sigma_altitude_m, scans)
    features = np.column_stack([times, geodesy.plot_to_ecef(slant, azimuth, altitude, radar), slant])
    return tf.plots_of(features, first_plot_id + np.arange(scans), radar)


def merged(*parts: Plots) -> Plots:
    """The plots of several radars as one recording, in time order."""
    joined = plot_table.joined(list(parts))
    return joined.take(np.argsort(joined.time, kind="stable"))


def slow_radar_plots(scans: int = 30) -> Plots:
    """Case 25's kind: one target at 9 km, 230 m/s, seen by a 12 s radar as it flies from 60 km east
    and 40 km north of it due south (azimuth 56 to 125 degrees, clockwise)."""
    return beam_plots(radar_turning(tf.make_params().radar, 1, 12.0), (60000.0, 40000.0, 9000.0),
                      (0.0, -230.0, 0.0), scans, seed=31)


def tracks_by_plot(plots: Plots, method: str, rule: str, changes: dict | None = None
                   ) -> tuple[dict[int, int], set[int]]:
    """Each plot's track id (by plot id) and the confirmed tracks, of `method` (tuned filters, 4 km
    window) under management rule `rule`, the params changed by the dotted `changes`."""
    params = tf.make_params(changes)
    tracker = registry.compose(method, Models({"kalman_tuned": TUNED}), params.tracker, 4000.0, params.tracker.seed,
                               rule)
    updates = track(plots, tracker)
    confirmed = set(updates["track_id"][confirmed_associations(updates, tracker.management)].tolist())
    return dict(zip(updates["plot_id"].tolist(), updates["track_id"].tolist())), confirmed


def test_each_rule_counts_its_silence_in_scans_of_the_latest_plots_radar():
    """The params' rules: the thesis lowers a track after 12 s, or 2 scans if longer; M-of-N records
    a miss 1.5 scans after a hit and deletes a confirmed track after 32 s, or 5.25 scans if longer."""
    params = tf.make_params().tracker.management
    thesis, m_of_n = ThesisWeights.from_params(params), MOfN.from_params(params)
    assert [thesis.silence(thesis.start, period) for period in (4.0, 6.0, 12.0)] == [12.0, 12.0, 24.0]
    assert [m_of_n.silence(m_of_n.start, period) for period in (4.0, 6.0, 12.0)] == [6.0, 9.0, 18.0]
    assert [m_of_n.silence(1.0, period) for period in (4.0, 6.0, 12.0)] == [32.0, 32.0, 63.0]
    assert ThesisWeights(0.4, 0.8, 1.0, 0.2, silence_s=12.0).silence(0.4, 12.0) == 12.0  # 0 scans: seconds only


@pytest.mark.parametrize("rule", RULES)
@pytest.mark.parametrize("method", ["kalman_cv", "imm", "imm_gnn"])
def test_a_target_seen_by_a_12_s_radar_is_one_confirmed_track(method, rule):
    """Case 25: 30 plots, each 12.06-12.08 s after the last, a hair more than tracker.management.silence_s; counted in
    seconds alone the thesis deleted every track before its second plot (30 tracks, none
    confirmed); counted in the radar's scans it is one confirmed track under either rule."""
    plots = slow_radar_plots()
    assert (np.diff(plots.time) > 12.06).all()
    track_of, confirmed = tracks_by_plot(plots, method, rule)
    assert set(track_of.values()) == confirmed == {0}
    assert len(track_of) == 30


def test_counted_in_seconds_alone_the_12_s_radar_gives_a_track_per_plot():
    """What the scans fix: with tracker.management.silence_scans 0 the thesis's 12 s lowers every new track of
    the 12 s radar before its second plot."""
    track_of, confirmed = tracks_by_plot(slow_radar_plots(), "kalman_cv", registry.THESIS_RULE,
                                         {"tracker.management.silence_scans": 0.0})
    assert len(set(track_of.values())) == 30 and not confirmed


def two_radar_plots() -> tuple[Plots, list[int], list[int]]:
    """A 4 s radar (the default site) and a 12 s one (60 km east): target A, flying south 200 m/s
    from 30 km east and 40 km north of the first, seen by both for 6 minutes (clockwise in the
    first's azimuth, counter-clockwise in the second's: its plots a little less than a scan apart);
    target B, which the first radar misses, flying east 150 m/s from 50 km east and 80 km north of
    the second, by the 12 s radar alone. Returns the recording and A's and B's plot ids."""
    home = tf.make_params().radar
    fast, slow = radar_turning(home, 1, 4.0), radar_turning(home, 2, 12.0, SECOND_SITE)
    a_fast = beam_plots(fast, (30000.0, 40000.0, 8000.0), (0.0, -200.0, 0.0), 90, seed=1)
    a_slow = beam_plots(slow, (30000.0, 40000.0, 8000.0), (0.0, -200.0, 0.0), 30, seed=2, first_plot_id=1000)
    b_slow = beam_plots(slow, (110000.0, 80000.0, 10000.0), (150.0, 0.0, 0.0), 30, seed=3, first_plot_id=2000)
    plots = merged(a_fast, a_slow, b_slow)
    return plots, [*a_fast.plot_id.tolist(), *a_slow.plot_id.tolist()], b_slow.plot_id.tolist()


@pytest.mark.parametrize("rule", RULES)
@pytest.mark.parametrize("method", ["kalman_cv", "imm_gnn"])
def test_a_4_s_and_a_12_s_radar_each_keep_their_targets_track(method, rule):
    """Two radars of different periods in one recording: A (both radars, 120 plots) and B (the 12 s
    radar's 30 plots alone) are two confirmed tracks, each target's plots all in its own. B's
    revisits are counted in the 12 s radar's scans, not in the recording's shortest (4 s: M-of-N
    recorded two misses between two of B's plots, never had 3 hits in 5 and left B tentative)."""
    plots, a, b = two_radar_plots()
    track_of, confirmed = tracks_by_plot(plots, method, rule)
    assert {track_of[plot] for plot in a} == {0}
    assert len({track_of[plot] for plot in b}) == 1
    assert set(track_of.values()) == confirmed and len(confirmed) == 2


def test_a_two_radar_recording_read_in_chunks_gives_the_updates_of_one_read_whole():
    """The revisit times by radar travel with the live tracks from one chunk to the next, also when a
    radar's first plot comes in a later chunk (the 4 s radar's plots of A from the fifth minute on,
    each chunk's plot table describing only its own plots' radars)."""
    plots, _, _ = two_radar_plots()
    fast = radar_turning(tf.make_params().radar, 1, 4.0).radar_id
    later = plots.take(np.flatnonzero((plots.radar_id != fast) | (plots.time > tf.T0 + 240.0)))
    tracker_params = tf.make_params({"tracker.association.revisit_scans": 0.5}).tracker

    def compose():
        return registry.compose("kalman_cv", Models({"kalman_tuned": TUNED}), tracker_params, 4000.0, 1, registry.M_OF_N_RULE)

    def chunk(begin: int) -> Plots:
        part = later.take(np.arange(begin, min(begin + 10, len(later))))
        return dataclasses.replace(part, radars={r: later.radars[r] for r in np.unique(part.radar_id).tolist()})
    whole = track(later, compose())
    chunks = [chunk(begin) for begin in range(0, len(later), 10)]
    assert fast not in chunks[0].radars
    parts = list(track_chunks(chunks, compose()))
    for key, values in whole.items():
        np.testing.assert_array_equal(np.concatenate([part[key] for part in parts]), values)


def revisit_plots(times: list[float], offsets_m: list[float], radar_sics: list[int]) -> Plots:
    """Plots at `times` (s after T0), `offsets_m` metres along ECEF x from tests/test_tracker_loop.py's
    ORIGIN, each of radar `sic` at the default site turning every 6 s."""
    home = tf.make_params().radar
    parts = []
    for k, (time, offset, sic) in enumerate(zip(times, offsets_m, radar_sics)):
        features = np.array([[tf.T0 + time, *(ORIGIN + [offset, 0.0, 0.0]), 1e5]])
        parts.append(tf.plots_of(features, np.array([k]), radar_turning(home, sic, 6.0)))
    return plot_table.joined(parts)


@pytest.mark.parametrize("revisit_scans, tracks", [(0.0, [0, 0, 0]), (0.5, [0, 1, 0])])
def test_a_second_plot_of_one_radar_within_half_a_scan_starts_a_track(revisit_scans, tracks):
    """A young track (one plot) and a plot of the same radar 0.2 s later, 100 m off (a split plot):
    without the revisit limit the young-track radius gives it to the track; with 0.5 scans it
    starts a track of its own, and the next scan's plot (20 m off the first) joins the first track."""
    tracker = dataclasses.replace(composition(), revisit_scans=revisit_scans)
    updates = track(revisit_plots([0.0, 0.2, 6.0], [0.0, 100.0, 20.0], [1, 1, 1]), tracker)
    assert updates["track_id"].tolist() == tracks


def test_a_plot_of_another_radar_within_half_a_scan_still_joins():
    """The limit is per radar: the second radar's plot of the target 0.2 s after the first radar's
    joins the track, and the first radar's next plot too."""
    tracker = dataclasses.replace(composition(), revisit_scans=0.5)
    updates = track(revisit_plots([0.0, 0.2, 6.0], [0.0, 100.0, 20.0], [1, 2, 1]), tracker)
    assert updates["track_id"].tolist() == [0, 0, 0]


@pytest.mark.parametrize("revisit_scans, tracks", [(0.0, [0, 0, 0, 0]), (0.5, [0, 0, 1, 0])])
def test_global_nearest_neighbour_takes_one_plot_per_revolution_across_its_batches(revisit_scans, tracks):
    """GNN gives a track one plot per batch (one scan of a radar, counted from its first plot), but a
    scan's last plot (11.9 s) and the next scan's first (12.1 s, 50 m off: clutter beside the
    target) are in two batches: without the limit the track takes both; with 0.5 scans the second
    starts a track and the target's next plot (18 s) joins the first."""
    tracker = dataclasses.replace(composition(assigner=GlobalNearestPerScan()), revisit_scans=revisit_scans)
    updates = track(revisit_plots([0.0, 11.9, 12.1, 18.0], [0.0, 0.0, 50.0, 0.0], [1, 1, 1, 1]), tracker)
    assert updates["track_id"].tolist() == tracks

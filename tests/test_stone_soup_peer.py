"""Stone Soup as a peer on our plots (`pipeline.peers.stone_soup`): two aircraft in clutter, each one track with
its own plots, under GNN and JPDA; the first updates before confirmation are marked."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.filters.classical_filters import FilterSettings
from pipeline.peers import stone_soup
from pipeline.peers.stone_soup import StoneSoupSettings
from tests import tracker_fixtures as tf


@pytest.mark.parametrize("association", ["gnn", "jpda"])
def test_two_aircraft_in_clutter_are_two_tracks_of_their_own_plots(association: str) -> None:
    params = tf.make_params()
    radar = params.radar
    first = tf.straight_features(radar, (40e3, 60e3, 9000.0), (180.0, 90.0, 0.0), 20)
    second = tf.straight_features(radar, (-50e3, 30e3, 7000.0), (-150.0, 120.0, 0.0), 20, t_offset=1.5)
    clutter = tf.clutter_features(radar, 20, 3.0, np.random.default_rng(4), half_width_m=150e3)
    ids = np.arange(40 + len(clutter))
    features, plot_ids = tf.merge((first, ids[:20]), (second, ids[20:40]), (clutter, ids[40:]))
    plots = tf.plots_of(features, plot_ids, radar)
    settings = StoneSoupSettings(association, noise_std=2.0, velocity_std_mps=300.0, gate_probability=0.999,
                                 min_points=3, delete_after_s=20.0, batch_window_s=0.05, detection_probability=0.9,
                                 clutter_density=1e-12)
    updates = stone_soup.track_with_stone_soup(plots, settings)
    confirmed = updates["confirmed"]
    tracks = tf.tracks_of({name: values[confirmed] for name, values in updates.items()})
    aircraft = [sorted(plot_ids) for plot_ids in tracks.values() if len(plot_ids) >= 10]
    assert len(aircraft) == 2
    assert aircraft[0] == list(range(2, 20)) or aircraft[0] == list(range(22, 40))
    assert sorted(sum(aircraft, [])) == list(range(2, 20)) + list(range(22, 40))  # each from its third plot on
    assert not confirmed[updates["track_id"] == updates["track_id"][np.flatnonzero(confirmed)[0]]][:2].any()
    assert updates["position_covariance"].shape == (len(confirmed), 3, 3)
    firsts = [updates["time_unix_s"][updates["track_id"] == k][0] for k in np.unique(updates["track_id"])]
    assert firsts == sorted(firsts)  # tracks numbered by their first plot, not Stone Soup's random ids
    late = np.isin(updates["plot_id"], np.arange(10, 20))  # the first aircraft's, settled: 201 m/s
    assert np.linalg.norm(updates["velocity"][late], axis=1) == pytest.approx(np.hypot(180.0, 90.0), abs=15.0)


def test_settings_come_from_params_and_our_tuned_cv() -> None:
    params = tf.make_params()
    cv = FilterSettings("cv", (12.5,), 140.0, 10.0, 0.05, 0.9)
    settings = StoneSoupSettings.from_params("jpda", params.peers.stone_soup, cv, 0.999)
    assert (settings.noise_std, settings.velocity_std_mps, settings.min_points) == (12.5, 140.0,
                                                                                     params.peers.stone_soup.min_points)
    assert settings.gate_distance == pytest.approx(np.sqrt(16.266), abs=1e-3)  # chi-square 0.999, 3 dof
    with pytest.raises(ValueError, match="association 'pda'"):
        StoneSoupSettings.from_params("pda", params.peers.stone_soup, cv, 0.999)


@pytest.mark.parametrize("association", ["gnn", "jpda"])
def test_a_silent_track_is_deleted_and_a_later_aircraft_there_is_a_new_track(association: str) -> None:
    """An aircraft tracked for 10 scans falls silent; a minute later another flies the same line: a track without a
    plot for `delete_after_s` is deleted (JPDA's missed-detection hypotheses are no update), so the second aircraft
    starts its own track rather than feeding the first's."""
    params = tf.make_params()
    radar = params.radar
    first = tf.straight_features(radar, (40e3, 60e3, 9000.0), (180.0, 90.0, 0.0), 10)
    second = tf.straight_features(radar, (40e3 + 180.0 * 120.0, 60e3 + 90.0 * 120.0, 9000.0), (180.0, 90.0, 0.0), 10,
                                  t_offset=120.0)
    clutter = tf.clutter_features(radar, 30, 2.0, np.random.default_rng(5), half_width_m=150e3)
    ids = np.arange(20 + len(clutter))
    features, plot_ids = tf.merge((first, ids[:10]), (second, ids[10:20]), (clutter, ids[20:]))
    settings = StoneSoupSettings(association, noise_std=2.0, velocity_std_mps=300.0, gate_probability=0.999,
                                 min_points=3, delete_after_s=20.0, batch_window_s=0.05, detection_probability=0.9,
                                 clutter_density=1e-12)
    updates = stone_soup.track_with_stone_soup(tf.plots_of(features, plot_ids, radar), settings)
    track_of = dict(zip(updates["plot_id"].tolist(), updates["track_id"].tolist()))
    assert track_of[5] != track_of[15]
    assert {track_of[p] for p in range(12, 20)} == {track_of[15]} and {track_of[p] for p in range(2, 10)} == {track_of[5]}

"""Stone Soup as a peer on our plots (`pipeline.peers.stone_soup`): two aircraft in clutter, each one track with
its own plots, under GNN and JPDA; the first updates before confirmation are marked."""

from __future__ import annotations

import numpy as np
import pytest

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
    updates = stone_soup.track_with_stone_soup(plots, StoneSoupSettings(association, noise_std=2.0,
                                                                        velocity_std_mps=300.0))
    confirmed = updates["confirmed"]
    tracks = tf.tracks_of({name: values[confirmed] for name, values in updates.items()})
    aircraft = [sorted(plot_ids) for plot_ids in tracks.values() if len(plot_ids) >= 10]
    assert len(aircraft) == 2
    assert aircraft[0] == list(range(2, 20)) or aircraft[0] == list(range(22, 40))
    assert sorted(sum(aircraft, [])) == list(range(2, 20)) + list(range(22, 40))  # each from its third plot on
    assert not confirmed[updates["track_id"] == updates["track_id"][np.flatnonzero(confirmed)[0]]][:2].any()
    assert updates["position_covariance"].shape == (len(confirmed), 3, 3)
    late = np.isin(updates["plot_id"], np.arange(10, 20))  # the first aircraft's, settled: 201 m/s
    assert np.linalg.norm(updates["velocity"][late], axis=1) == pytest.approx(np.hypot(180.0, 90.0), abs=15.0)

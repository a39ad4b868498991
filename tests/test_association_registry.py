"""Track-to-track associators as components (`pipeline.association.associator`) with one registry
(`pipeline.association.registry`): a stub associator, registered as one entry, runs through
`table_association.decide` as the registered methods do, given each user's horizontal tracks at as many of
the scenario's latest common times as it declares.

User 1 has tracks 1, 2, 3 and user 2 tracks 2, 3, 9, 10 km apart along east, track 9 50 km from all: the
stub pairs equal ids, and the memory (`association_memory`) finds nothing to add.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.association import registry, table_association
from pipeline.association.associator import Decision, TrackSet
from pipeline.association.common_time_states import Snapshot
from tests import tracker_fixtures as tf

EAST_M = {1: 0.0, 2: 10e3, 3: 20e3, 9: 70e3}  # each track's east position, m


class SameIdAssociator:
    """A stub associator: pairs the tracks of equal ids at the current common time, and records what it is given."""

    common_times = 2

    def __init__(self) -> None:
        self.given: list[tuple[TrackSet, TrackSet]] = []

    def associate_tracks(self, tracks1: TrackSet, tracks2: TrackSet) -> Decision:
        self.given.append((tracks1, tracks2))
        ids1, ids2 = tracks1.ids[-1], tracks2.ids[-1]
        rows = np.flatnonzero(np.isin(ids1, ids2))
        return Decision(np.stack([rows, np.searchsorted(ids2, ids1[rows])], axis=1), None)


def tracks_of(ids: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ids (N,), states (N, 6) [e, n, u, ve, vn, vu] (up 9 km, flying north at 200 m/s) and covariances (N, 6, 6)."""
    states = np.array([[EAST_M[i], 0.0, 9000.0, 0.0, 200.0, 0.0] for i in ids]).reshape(-1, 6)
    return np.array(ids, dtype=np.int64), states, np.broadcast_to(np.diag([100.0] * 3 + [25.0] * 3),
                                                                   (len(ids), 6, 6)).copy()


def snapshot(scenario_id: int, time: float, second: list[int]) -> Snapshot:
    (ids1, x1, p1), (ids2, x2, p2) = tracks_of([1, 2, 3]), tracks_of(second)
    return Snapshot(scenario_id, time, (ids1, ids2), (x1, x2), (p1, p2))


def test_a_registered_stub_associator_is_run_by_decide_over_its_scenarios_latest_times(monkeypatch):
    """Three common times of scenario 4, then three of scenario 5, the last without a track of user 2: the stub
    is given one, two, two, then (a new scenario) one and two common times, their horizontal states; the last
    time has no pair and is not its to decide; every other time's pairs are the stub's."""
    stub = SameIdAssociator()
    monkeypatch.setitem(registry.ASSOCIATORS, "same_id", registry.AssociationMethod("same_id", lambda a, n: stub))
    snapshots = [snapshot(4, 0.0, [2, 3, 9]), snapshot(4, 6.0, [2, 3, 9]), snapshot(4, 12.0, [2, 3, 9]),
                 snapshot(5, 0.0, [2, 3, 9]), snapshot(5, 6.0, [2, 3, 9]), snapshot(5, 12.0, [])]
    params = tf.make_params()
    decisions = table_association.decide(snapshots, "same_id", params.association, None,
                                         params.associate.keep_probability)
    assert [len(tracks1.ids) for tracks1, _ in stub.given] == [1, 2, 2, 1, 2]
    first, second = stub.given[2]
    assert [ids.tolist() for ids in second.ids] == [[2, 3, 9], [2, 3, 9]]
    np.testing.assert_array_equal(first.current[0], [[0.0, 0.0, 0.0, 200.0], [10e3, 0.0, 0.0, 200.0],
                                                     [20e3, 0.0, 0.0, 200.0]])
    assert first.current[1].shape == (3, 4, 4)
    assert [d.pairs.tolist() for d in decisions] == [[[1, 0], [2, 1]]] * 5 + [[]]
    assert all(d.bias_m is None for d in decisions)


def test_an_unknown_method_is_named_with_the_registered_ones():
    params = tf.make_params()
    with pytest.raises(registry.UnknownAssociator, match=r"'nearest': must be one of \['statistical', "
                                                         r"'double_threshold', 'bias_robust', 'network'\]"):
        table_association.decide([], "nearest", params.association, None, params.associate.keep_probability)


def test_each_registered_method_is_built_from_params_and_declares_the_times_it_reads():
    """Only the network needs the trained network; the double threshold reads a track segment's common times
    (track_points - 1), the others the current one."""
    association = tf.make_params().association
    built = {name: registry.associator(name, association, object()) for name in registry.ASSOCIATORS}
    assert {name: b.common_times for name, b in built.items()} == {
        "statistical": 1, "double_threshold": association.track_points - 1, "bias_robust": 1, "network": 1}
    assert [name for name in registry.NAMES if registry.needs_network([name])] == ["network"]

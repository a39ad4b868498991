"""Evidence of a clock offset: track pairs alike in velocity, left unpaired, displaced along their velocity at
several common times, give their number and the offset they imply; pairs displaced across it, or alike only
briefly, do not."""

from __future__ import annotations

import numpy as np

from pipeline.association.clock_check import MIN_TIMES, clock_evidence
from pipeline.association.common_time_states import Snapshot
from tests import tracker_fixtures as tf

ASSOCIATION = tf.make_params().association   # max_bias_m 600 m, max_time_offset_s 5 s, gate 0.999
NONE = np.zeros((0, 2), dtype=np.int64)


def snapshot(time: float, velocities: np.ndarray, displacements: np.ndarray) -> Snapshot:
    """Aircraft 20 km apart with `velocities` (N, 2) m/s; the second user's tracks displaced by `displacements`
    (N, 2) m; position variance 100 m², velocity 25 (m/s)², per axis; ids 10, 11, ... and 20, 21, ..."""
    count = len(velocities)
    positions = np.column_stack([20e3 * np.arange(count), np.zeros(count)])

    def states(offset: np.ndarray) -> np.ndarray:
        return np.column_stack([positions + offset, np.zeros(count), velocities, np.zeros(count)])
    covariances = np.tile(np.diag([100.0, 100.0, 100.0, 25.0, 25.0, 25.0]), (count, 1, 1))
    return Snapshot(0, time, (10 + np.arange(count), 20 + np.arange(count)),
                    (states(np.zeros((count, 2))), states(displacements)), (covariances, covariances))


def test_pairs_displaced_along_their_velocity_are_a_clock_offset_and_its_size():
    """Stamps 2 s late: each second-user track 2 s back along its velocity (400 and 500 m), left unpaired by the
    method at 4 common times: 2 pairs, 4 times, 2 s."""
    velocities = np.array([[200.0, 0.0], [0.0, -250.0]])
    snapshots = [snapshot(t, velocities, -2.0 * velocities) for t in range(4)]
    evidence = clock_evidence(snapshots, [NONE] * 4, [None] * 4, [None] * 4, ASSOCIATION)
    assert (evidence.pairs, evidence.times) == (2, 4)
    assert np.isclose(evidence.offset_s, 2.0)


def test_paired_displaced_across_or_brief_pairs_are_no_evidence():
    """The same tracks paired by the method; displaced 1 km across the velocity; or alike at MIN_TIMES - 1 times."""
    velocities = np.array([[200.0, 0.0], [0.0, -250.0]])
    along = [snapshot(t, velocities, -2.0 * velocities) for t in range(4)]
    paired = np.array([[0, 0], [1, 1]])
    assert clock_evidence(along, [paired] * 4, [None] * 4, [None] * 4, ASSOCIATION).pairs == 0
    across = [snapshot(t, velocities, np.array([[0.0, 1000.0], [1000.0, 0.0]])) for t in range(4)]
    assert clock_evidence(across, [NONE] * 4, [None] * 4, [None] * 4, ASSOCIATION).pairs == 0
    brief = along[:MIN_TIMES - 1]
    assert clock_evidence(brief, [NONE] * len(brief), [None] * len(brief), [None] * len(brief), ASSOCIATION).pairs == 0


def test_the_methods_own_registration_is_removed_first():
    """Stamps 3 s late, and a method that estimated 2 s of it (and no translation) left the pairs unpaired: the
    evidence is of the remaining 1 s."""
    velocities = np.array([[200.0, 0.0], [0.0, -250.0]])
    snapshots = [snapshot(t, velocities, -3.0 * velocities) for t in range(4)]
    evidence = clock_evidence(snapshots, [NONE] * 4, [np.zeros(2)] * 4, [2.0] * 4, ASSOCIATION)
    assert evidence.pairs == 2 and np.isclose(evidence.offset_s, 1.0)

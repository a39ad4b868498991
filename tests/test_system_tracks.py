"""System track numbers of a fused picture: a fused track keeps its number while either local track continues."""

from __future__ import annotations

import numpy as np

from pipeline.association.system_tracks import SystemTracks


def test_a_fused_track_keeps_its_number_while_either_local_track_continues():
    numbering = SystemTracks()
    # time 0: radar 1's 10 fused with radar 2's 20; radar 1's 11 and radar 2's 21 alone
    first = numbering.number(0, np.array([[10, 20], [11, -1], [-1, 21]]))
    assert first.tolist() == [0, 1, 2]
    # time 1: 10 re-paired with 21 (the pair changed: 10 carries its number 0, older than 21's 2);
    # 11 still alone keeps 1; 20 left alone cannot keep 0 (taken) and gets a new number
    second = numbering.number(0, np.array([[10, 21], [11, -1], [-1, 20]]))
    assert second.tolist() == [0, 1, 3]


def test_merged_system_tracks_keep_the_older_number_and_scenarios_are_separate():
    numbering = SystemTracks()
    numbering.number(0, np.array([[10, -1], [-1, 20]]))     # 10 -> 0, 20 -> 1
    assert numbering.number(0, np.array([[10, 20]])).tolist() == [0]
    assert numbering.number(0, np.array([[-1, 20], [11, -1]])).tolist() == [0, 2]  # 20 now carries 0
    assert numbering.number(1, np.array([[10, 20]])).tolist() == [3]  # same ids, another scenario: a new track
    assert numbering.number(1, np.zeros((0, 2), dtype=np.int64)).tolist() == []

"""Role: the track-to-track associator, which pairs two users' tracks at one common time.

Stone Soup's track-to-track associators take two sets of tracks and give their pairs
(`associate_tracks(tracks_set_1, tracks_set_2)`, `stonesoup.dataassociator.tracktotrack`); so does an
associator here, on arrays rather than a Python object per track. Each set is one user's tracks at its
latest common times (`TrackSet`: the horizontal state every method compares, `association_memory.horizontal`),
as many as the associator declares it reads in `common_times` (1: the current time alone). The knobs sit on
the associator (gate probability, offset bounds, the trained network), set when the registry builds it
(`pipeline.association.registry`) from params `association`, as the tracker's roles are built from params
`tracker`. The memory that continues a time's pairs from the last time's is the same for every associator and
is not theirs (`association_memory`, applied by `table_association.decide`).

A new track-to-track method is one class offering `common_times` and `associate_tracks`, and one registry entry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class TrackSet:
    """One user's tracks at its latest L >= 1 common times of one scenario, oldest first, the current time last:
    per time, the track ids (N_t,) in ascending order, the horizontal states (N_t, 4) [east, north, v_east,
    v_north] (m, m/s, in the common frame's ENU) and their covariances (N_t, 4, 4)."""

    ids: tuple[np.ndarray, ...]
    states: tuple[np.ndarray, ...]
    covariances: tuple[np.ndarray, ...]

    @property
    def current(self) -> tuple[np.ndarray, np.ndarray]:
        """The states (N, 4) and covariances (N, 4, 4) at the current (last) common time."""
        return self.states[-1], self.covariances[-1]


@dataclass(frozen=True)
class Decision:
    """One common time's pairs (K, 2) [first user's row, second user's row] of the current time; the second
    user's estimated offset (2,) east, north m, its clock offset (s, its time stamps that much late) and the
    offset's covariance (2, 2) m² (each None unless the method estimates them: bias_robust)."""

    pairs: np.ndarray
    bias_m: np.ndarray | None
    time_offset_s: float | None = None
    bias_covariance_m2: np.ndarray | None = None


class Associator(Protocol):
    """Pairs two users' tracks at their current common time. `common_times`: how many of the latest common
    times it reads; it is given at most that many, fewer at the start of a scenario."""

    common_times: int

    def associate_tracks(self, tracks1: TrackSet, tracks2: TrackSet) -> Decision:
        """The pairs (rows of each set's current time) and the offsets the method estimates. Both sets have
        tracks at the current time. TrackInputError (`track_association`) on unusable tracks."""
        ...

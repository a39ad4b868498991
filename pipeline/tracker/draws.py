"""Random draws that belong to a (track, plot) pair, not to the call that makes them (issue 29).

MIA's gate perturbs a track's last state with random samples for every plot it scores the track
against. Drawn from one stream, call after call, a pair's samples would depend on what else was
scored before it: on the loop scoring an antenna scan at once or plot by plot, nearest neighbour's
look-ahead, a plot scored again after a track changed. Here a pair's samples are a function of the
run's seed, the track's id and the plot's id alone: the counter-based generator Philox4x64-10
(Salmon, Moraes, Dror and Shaw, "Parallel random numbers: as easy as 1, 2, 3", SC 2011; NumPy's
`numpy.random.Philox`) keyed by (the seed's hash, track id) at counter (plot id, 0, 0, 0), its normals drawn
by NumPy's ziggurat. One generator is re-keyed per pair: constructing one costs about ten times as
much.
"""

from __future__ import annotations

import numpy as np


class PairDraws:
    """Standard normal draws per (track, plot) pair under one `seed` (a non-negative integer or a list of
    them, as `numpy.random.default_rng` takes: hashed to the key's first word by `numpy.random.SeedSequence`)."""

    def __init__(self, seed: int | list[int]) -> None:
        self.seed = np.random.SeedSequence(seed).generate_state(1, dtype=np.uint64)[0]
        self._bits = np.random.Philox(0)
        self._generator = np.random.Generator(self._bits)

    def normals(self, track_ids: np.ndarray, plot_ids: np.ndarray, count: int, size: int = 3) -> np.ndarray:
        """`count` draws of `size` standard normals for each pair (track_ids[k], plot_ids[k]) (P,), pair by
        pair: (P * count, size). A pair gives the same draws in any call, alone or among others; ids
        are taken modulo 2^64."""
        out = np.empty((len(track_ids) * count, size))
        for k, (track_id, plot_id) in enumerate(zip(np.asarray(track_ids, dtype=np.int64).astype(np.uint64),
                                                    np.asarray(plot_ids, dtype=np.int64).astype(np.uint64))):
            self._bits.state = {"bit_generator": "Philox",
                                "state": {"counter": np.array([plot_id, 0, 0, 0], dtype=np.uint64),
                                          "key": np.array([self.seed, track_id], dtype=np.uint64)},
                                "buffer": np.zeros(4, dtype=np.uint64), "buffer_pos": 4, "has_uint32": 0,
                                "uinteger": 0}
            out[k * count:(k + 1) * count] = self._generator.standard_normal((count, size))
        return out

"""How many rows a batched network step runs, so that no row's numbers depend on the rows beside it (issue 29).

The tracker's learned estimators step (track, plot) pairs through their networks a batch at a time:
the candidates of one plot, or every pair of an antenna scan in one call. For the tracker to give
the same updates however the pairs are batched, a row must come out of a call of one row and of a
thousand alike, to the bit. Two of PyTorch's CPU kernels give a row other bits in another call
(float64, measured with torch 2.13 and MKL 2024.2 on AVX512, one thread and two):

- MKL's dgemm (`nn.Linear`, and the GRU and LSTM cells' matrix products) computes a call of fewer
  than GEMM_ROWS rows with other kernels than a larger one, which differ in the last bits; from
  GEMM_ROWS rows on a row's result is the same whatever the row count and its place in the call
  (checked up to 30 000 rows);
- an elementwise kernel takes a tensor VECTOR_STEP float64 elements at a time (2 x 8 lanes on
  AVX512, 2 x 4 on AVX2) and the few left at its end one at a time with the scalar formula, which
  for `sigmoid` and `pow` differs from the vectorised one in the last bit for some inputs (sigmoid:
  2.6 % of normal draws; exp, log and tanh agree).

`padding` gives the rows to run: the items (tracks or pairs) and the last one repeated, as many as
make the call at least GEMM_ROWS rows and every tensor of a given width a whole number of vector
steps; the caller drops the repeated rows' results. A row then meets the same kernels in every call.
"""

from __future__ import annotations

import numpy as np

GEMM_ROWS = 4     # MKL's dgemm: calls of fewer rows take their own kernels
VECTOR_STEP = 16  # float64 elements an elementwise kernel takes per step (2 x 8 on AVX512; 2 x 4 on AVX2 divides it)


def padding(count: int, rows_each: int = 1, elements_each: int = VECTOR_STEP) -> np.ndarray:
    """Indices (n,) of `count` items (at least one), the last repeated up to n: the fewest with
    n * rows_each >= GEMM_ROWS and n * elements_each a multiple of VECTOR_STEP. `rows_each`: the
    rows an item gives the matrix products (an LSTM track's copies); `elements_each`: an item's
    elements in the narrowest contiguous tensor that a sigmoid or pow takes (the default: no constraint
    beyond whole steps)."""
    step = VECTOR_STEP // np.gcd(VECTOR_STEP, elements_each)
    n = max(count, -(-GEMM_ROWS // rows_each))
    n += -n % step
    return np.minimum(np.arange(n), count - 1)

"""Validation material: segments of a split left out of a filter's training, to fit what must not be fitted on
the plots it trained on or on the hold-out it is scored on (the LSTM update's covariance factors, issue 18).

The split's target plots are cut into segments as the windows stage cuts them (`windows.target_plots` at
`windows.segment_gap_s`: the hold-out's segments come from the same cut), the hold-out's plots are left
out, and a seeded random share of the remaining segments is chosen (`windows.holdout_segments`, the
windows stage's own choice of its hold-out), so validation windows look like the hold-out's windows
(same segmentation, same gaps) without sharing a plot with them or with the training material.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from pipeline.learning import windows
from pipeline.params import Radar


def validation_plots(plots: pa.Table, holdout: pa.Table | None, radar: Radar, gap_s: float, fraction: float,
                     seed: int, source: str) -> windows.TargetPlots:
    """The target plots (in scenario and time order) of round(`fraction` x segments) segments of `plots`
    (a split's plot table, `simulate.PLOT_SCHEMA`) chosen with `seed` among those with no plot in
    `holdout` (a table with `plot_id`, or None). InputError (naming `source`) as `windows.target_plots`."""
    targets = windows.target_plots(plots, radar, gap_s, source)
    if holdout is not None:
        targets = targets.take(~np.isin(targets.segment_id, targets.segment_id[
            np.isin(targets.plot_id, holdout.column("plot_id").to_numpy())]))
    return targets.take(np.isin(targets.segment_id, windows.holdout_segments(targets.segment_id, fraction, seed)))


def without(holdout: pa.Table | None, validation: windows.TargetPlots) -> pa.Table:
    """A table of the `plot_id`s to leave out of training: the hold-out's (if any) and the validation's."""
    held = holdout.column("plot_id").to_numpy() if holdout is not None else np.empty(0, np.int64)
    return pa.table({"plot_id": pa.array(np.concatenate([held, validation.plot_id]).astype(np.int64))})

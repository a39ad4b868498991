"""The validation segments a filter trains without: cut as the windows stage cuts, none of the hold-out's."""

import numpy as np
import pyarrow.compute as pc

from pipeline.learning import validation_split, windows


def test_validation_segments_share_no_plot_with_the_hold_out_or_the_training_material(tiny_pipeline):
    from pipeline import io
    from pipeline.learning import materials
    from pipeline.settings import load_params
    from pipeline.simulation import simulate
    params = load_params(tiny_pipeline / "params.yaml")
    plots = io.read_parquet(tiny_pipeline / "data" / "simulated" / "train" / "plots.parquet", simulate.PLOT_SCHEMA)
    holdout = io.read_parquet(tiny_pipeline / "data" / "windows" / "holdout.parquet", materials.HOLDOUT_SCHEMA)
    validation = validation_split.validation_plots(plots, holdout, params.radar, params.windows.segment_gap_s, 0.3, 1,
                                                   "train")
    targets = windows.target_plots(plots, params.radar, params.windows.segment_gap_s, "train")
    free = len(np.unique(targets.segment_id)) - len(np.unique(holdout.column("segment_id").to_numpy()))
    assert len(np.unique(validation.segment_id)) == round(0.3 * free) > 0
    assert not np.isin(validation.plot_id, holdout.column("plot_id").to_numpy()).any()
    left_out = validation_split.without(holdout, validation).column("plot_id")
    training = plots.filter(pc.invert(pc.is_in(plots.column("plot_id"), left_out)))
    assert not np.isin(training.column("plot_id").to_numpy(), validation.plot_id).any()
    assert training.num_rows == plots.num_rows - holdout.num_rows - len(validation.plot_id)
    again = validation_split.validation_plots(plots, holdout, params.radar, params.windows.segment_gap_s, 0.3, 1,
                                              "train")
    np.testing.assert_array_equal(again.plot_id, validation.plot_id)

"""Training windows: segments, sliding windows, balancing, the hold-out and calibration material.

Small hand-built inputs show each rule; one tiny run of routes -> simulate -> windows checks
that the written materials keep the rules, joined back to the simulated plots by plot_id.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline import io
from pipeline.geometry import geodesy
from pipeline.learning import materials, windows
from pipeline.learning.scaling import WindowScaler
from pipeline.params import Params
from pipeline.settings import parse_params
from pipeline.simulation import simulate
from tests.project import run_pipeline, tiny_params_tree, write_params

T0 = 1.78e9  # an instant in 2026, in Unix seconds
GAP_S = 18.0
# The tiny run has 8 training segments; a quarter of them (2) go to the hold-out, so that
# there is something to check for leakage (the default 5 % of 8 rounds to none).
HOLDOUT_FRACTION = 0.25
LENGTHS = {"filter": 10, "predictor": 6, "autoencoder": 5}


# ----------------------------------------------------------------------------- hand-built inputs

def plot_table(rows: list[tuple[int, int, float, bool]]) -> pa.Table:
    """A simulated-plots table from (plot_id, scenario_id, time_unix_s, is_target) rows.

    Measured positions move 200 m/s along x from a point in Finland; the truth of a target
    plot is 50 m off in y; false plots have no truth (NaN), as the simulator writes them.
    """
    plot_id, scenario, time, is_target = (np.array(column) for column in zip(*rows))
    x = 2.88e6 + 200.0 * (time - T0)
    true = np.where(is_target, 1.0, np.nan)
    columns = {
        "scenario_id": scenario.astype(np.int32), "plot_id": plot_id.astype(np.int64),
        "radar_id": np.ones(len(rows), np.int32), "scan": ((time - T0) // 6).astype(np.int64),
        "time_of_day_s": np.mod(time, 86400.0), "time_unix_s": time.astype(float),
        "range_m": np.full(len(rows), 1.0e5), "azimuth_deg": np.full(len(rows), 45.0),
        "flight_level": np.full(len(rows), 300.0), "altitude_m": np.full(len(rows), 9144.0),
        "x_ecef_m": x, "y_ecef_m": np.full(len(rows), 1.34e6), "z_ecef_m": np.full(len(rows), 5.52e6),
        "is_target": is_target.astype(bool), "target_id": np.where(is_target, scenario, -1).astype(np.int32),
        "true_x_ecef_m": x * true, "true_y_ecef_m": (1.34e6 + 50.0) * true, "true_z_ecef_m": 5.52e6 * true,
    }
    return pa.Table.from_pydict(columns, schema=simulate.PLOT_SCHEMA)


@pytest.fixture(scope="module")
def radar(make_params):
    return make_params(1).radar


def test_window_starts_never_cross_a_segment_boundary():
    """Windows of 3 over segments [0,0,0,1,1,1,1,2] start at 0, 3 and 4 only."""
    segment = np.array([0, 0, 0, 1, 1, 1, 1, 2])
    np.testing.assert_array_equal(windows.window_starts(segment, 3), [0, 3, 4])
    np.testing.assert_array_equal(windows.gather(segment, windows.window_starts(segment, 3), 3),
                                  [[0, 0, 0], [1, 1, 1], [1, 1, 1]])
    assert windows.window_starts(segment, 9).size == 0


def test_target_plots_cut_segments_at_gaps_and_scenario_changes(radar):
    """Target plots are sorted by scenario and time; a gap over 18 s or a new scenario starts a segment."""
    rows = [  # (plot_id, scenario, time, is_target), deliberately out of order
        (20, 9, T0 + 160.0, True), (11, 7, T0 + 130.5, True),   # 18.5 s after 112: new segment
        (10, 7, T0 + 112.0, True), (15, 7, T0 + 120.0, False),  # false plots are left out
        (8, 7, T0 + 100.0, True), (9, 7, T0 + 106.0, True),
        (12, 7, T0 + 136.0, True), (13, 7, T0 + 154.0, True),   # exactly 18 s: same segment
        (21, 9, T0 + 166.0, True), (30, 3, T0 + 1000.0, True),  # scenario 9 follows 7 by 6 s: new segment
        (31, 3, T0 + 1006.0, True), (16, 7, T0 + 103.0, False),
    ]
    plots = windows.target_plots(plot_table(rows), radar, GAP_S, "train/plots.parquet")
    np.testing.assert_array_equal(plots.plot_id, [30, 31, 8, 9, 10, 11, 12, 13, 20, 21])
    np.testing.assert_array_equal(plots.scenario_id, [3, 3, 7, 7, 7, 7, 7, 7, 9, 9])
    np.testing.assert_array_equal(plots.segment_id, [0, 0, 1, 1, 1, 2, 2, 2, 3, 3])
    np.testing.assert_array_equal(plots.time - T0, [1000, 1006, 100, 106, 112, 130.5, 136, 154, 160, 166])
    # Every column travels with its plot: the truth is 50 m from the measurement in y.
    np.testing.assert_array_equal(plots.position[:, 0], 2.88e6 + 200.0 * (plots.time - T0))
    np.testing.assert_array_equal(plots.true_position[:, 1] - plots.position[:, 1], 50.0)
    np.testing.assert_allclose(plots.true_range_m,
                               np.linalg.norm(plots.true_position - geodesy.radar_site_ecef(radar), axis=1))


def test_target_plot_without_truth_is_an_input_error_naming_file_and_column(radar):
    """A target plot with NaN true_x_ecef_m stops the stage with an error naming source, column and plot."""
    table = plot_table([(0, 1, T0, True), (1, 1, T0 + 6.0, True), (2, 1, T0 + 7.0, False)])
    true_x = table.column("true_x_ecef_m").to_numpy().copy()
    true_x[1] = np.nan
    table = table.set_column(table.schema.get_field_index("true_x_ecef_m"), simulate.PLOT_SCHEMA.field("true_x_ecef_m"),
                             pa.array(true_x))
    with pytest.raises(io.InputError, match=r"data/simulated/train/plots.parquet: column 'true_x_ecef_m'") as error:
        windows.target_plots(table, radar, GAP_S, "data/simulated/train/plots.parquet")
    assert "plot_id 1" in str(error.value)


def test_linearity_is_chord_over_path_length():
    """Eq. 4.7: a straight window scores 1, a right-angle corner 1/sqrt(2)."""
    straight = np.array([[[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]])
    corner = np.array([[[0.0, 0, 0], [1, 0, 0], [1, 1, 0]]])
    np.testing.assert_allclose(windows.linearity(np.concatenate([straight, corner])), [1.0, np.sqrt(0.5)])


def test_state_windows_are_consecutive_true_states_and_targets_are_the_next_states():
    """Predictor windows hold 6 consecutive true states of one segment; inputs 0-4, targets 2-5 are the next ones."""
    time = T0 + np.cumsum([0.0, 6, 6, 12, 6, 18, 6, 30, 6, 6, 12, 6, 6])  # a missed scan or two; a 30 s gap
    count = len(time)
    true = np.column_stack([200.0 * (time - T0), 10.0 * (time - T0) ** 1.5, np.full(count, 9000.0)]) + [3e6, 1e6, 5e6]
    plots = windows.TargetPlots(
        scenario_id=np.full(count, 4), plot_id=np.arange(100, 100 + count), segment_id=np.repeat([0, 1], [7, 6]),
        time=time, position=true + 40.0, range_m=np.linalg.norm(true, axis=1) + 40.0,
        true_position=true, true_range_m=np.linalg.norm(true, axis=1), radar_position=np.zeros((count, 3)))
    starts = windows.window_starts(plots.segment_id, 6)
    np.testing.assert_array_equal(starts, [0, 1, 7])
    states = windows.state_features(plots.true_features(), starts, 6)
    assert states.shape == (3, 6, 6)
    for window, start in enumerate(starts):
        rows = slice(start, start + 6)
        np.testing.assert_array_equal(states[window][:, [0, 2, 3, 4, 5]], plots.true_features()[rows])
        np.testing.assert_array_equal(states[window, :, 1], np.r_[np.diff(time[rows]), 0.0])
        assert len(set(plots.segment_id[rows])) == 1
    # Input state i (1-4) plus its dt is the time of target i-1, i.e. of state i+1.
    inputs, targets = states[:, :5], states[:, 2:]
    np.testing.assert_array_equal(targets[:, :, 0], inputs[:, 1:, 0] + inputs[:, 1:, 1])
    np.testing.assert_array_equal(windows.gather(plots.plot_id, starts, 6)[2], np.arange(107, 113))


def test_balance_keeps_every_curved_window_and_as_many_straight_ones():
    """50 windows below the last 3 of 100 bins are all kept, and 50 of the 1000 in the last 3 bins."""
    low = np.linspace(0.0, 0.9, 50)      # min 0 and max 1: the bins are 0.01 wide, the last 3 from 0.97
    high = np.linspace(0.99, 1.0, 1000)
    values = np.concatenate([low, high])[np.random.default_rng(7).permutation(1050)]
    keep = windows.balance(values, bins=100, high_bins=3, rng=np.random.default_rng(1))
    assert len(keep) == 100
    assert np.all(np.diff(keep) > 0)  # sorted and unique
    assert set(np.flatnonzero(values < 0.97)) <= set(keep.tolist())
    assert (values[keep] >= 0.99).sum() == 50
    np.testing.assert_array_equal(keep, windows.balance(values, 100, 3, np.random.default_rng(1)))
    assert not np.array_equal(keep, windows.balance(values, 100, 3, np.random.default_rng(2)))


def test_balance_keeps_everything_when_straight_windows_are_fewer():
    """With fewer windows in the last 3 bins than in the others, balancing drops nothing."""
    values = np.concatenate([np.linspace(0.0, 0.9, 50), np.linspace(0.99, 1.0, 20)])
    np.testing.assert_array_equal(windows.balance(values, 100, 3, np.random.default_rng(1)), np.arange(70))
    assert windows.balance(np.array([]), 100, 3, np.random.default_rng(1)).size == 0


def test_long_table_and_window_arrays_are_inverses():
    """A material's one-row-per-step table reads back into the same (N x L x F) windows."""
    values = np.random.default_rng(3).normal(size=(4, 6, 6))
    table = windows.long_table({"state": values}, {"plot_id": np.arange(24).reshape(4, 6)},
                               {"linearity": np.linspace(0.5, 1.0, 4)})
    assert table.column("step").to_pylist() == list(range(6)) * 4
    assert table.column("window_id").to_pylist() == [w for w in range(4) for _ in range(6)]
    np.testing.assert_array_equal(windows.window_arrays(table, "state", ("t", "dt", "x", "y", "z", "r")), values)


def test_cli_without_simulated_data_names_the_file_and_writes_nothing(tmp_path: Path):
    """`windows` with a missing simulated folder exits 2, names the missing file, and writes no output."""
    params = write_params(tiny_params_tree(), tmp_path / "params.yaml")
    result = run_pipeline("windows", "--params", str(params), "--simulated", "nowhere", "--out", "windows",
                          "--reports", "reports", cwd=tmp_path)
    assert result.returncode == 2
    assert "nowhere/train/plots.parquet: file not found" in result.stderr
    assert not (tmp_path / "windows").exists()
    assert not (tmp_path / "reports" / "windows.json").exists()


# ----------------------------------------------------------------------------- the real chain

class Simulated:
    """A split's simulated plots as arrays, looked up by plot_id."""

    def __init__(self, table: pa.Table):
        self.columns = {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}
        self._order = np.argsort(self.columns["plot_id"])
        target = np.flatnonzero(self.columns["is_target"])
        by_time = target[np.lexsort((self.columns["time_unix_s"][target], self.columns["scenario_id"][target]))]
        self._rank = np.full(len(self._order), -1)
        self._rank[by_time] = np.arange(len(by_time))
        scenario, time = self.columns["scenario_id"][by_time], self.columns["time_unix_s"][by_time]
        self.segments = 1 + int(np.sum((np.diff(scenario) != 0) | (np.diff(time) > GAP_S)))

    def row(self, plot_id: np.ndarray) -> np.ndarray:
        sorted_ids = self.columns["plot_id"][self._order]
        position = np.searchsorted(sorted_ids, plot_id)
        assert np.array_equal(sorted_ids[position], plot_id), "plot_id not in the simulated plots"
        return self._order[position]

    def at(self, name: str, plot_id: np.ndarray) -> np.ndarray:
        return self.columns[name][self.row(plot_id)]

    def position(self, plot_id: np.ndarray, prefix: str = "") -> np.ndarray:
        return np.stack([self.at(f"{prefix}{axis}_ecef_m", plot_id) for axis in "xyz"], axis=-1)

    def target_rank(self, plot_id: np.ndarray) -> np.ndarray:
        """Index of each plot among the split's target plots in scenario and time order (-1: a false plot)."""
        return self._rank[self.row(plot_id)]


@dataclass
class Chain:
    """What the tiny run wrote, read back, with the simulated plots it was made from."""

    params: Params
    material: dict[str, pa.Table]
    holdout: pa.Table
    scalers: dict[str, WindowScaler]
    report: dict
    train: Simulated
    calibration: Simulated
    train_table: pa.Table


@pytest.fixture(scope="module")
def chain(tmp_path_factory) -> Chain:
    """routes -> simulate -> windows with 2 routes per strategy, in a fresh folder."""
    folder = tmp_path_factory.mktemp("chain")
    tree = tiny_params_tree()
    tree["windows"]["holdout_fraction"] = HOLDOUT_FRACTION
    write_params(tree, folder / "params.yaml")
    for command in (("routes", "--out", "routes"), ("simulate", "--routes", "routes", "--out", "simulated"),
                    ("windows", "--simulated", "simulated", "--out", "windows", "--reports", "reports")):
        result = run_pipeline(command[0], "--params", "params.yaml", *command[1:], cwd=folder)
        assert result.returncode == 0, result.stderr
    out = folder / "windows"
    names = ("filter", "predictor", "autoencoder", "autoencoder_calibration")
    train_table = io.read_parquet(folder / "simulated" / "train" / "plots.parquet", simulate.PLOT_SCHEMA)
    return Chain(
        params=parse_params(tree),
        material={name: pq.read_table(out / f"{name}.parquet") for name in names},
        holdout=pq.read_table(out / "holdout.parquet"),
        scalers={name: WindowScaler.from_dict(data)
                 for name, data in json.loads((out / "scalers.json").read_text()).items()},
        report=json.loads((folder / "reports" / "windows.json").read_text()),
        train=Simulated(train_table),
        calibration=Simulated(pq.read_table(folder / "simulated" / "calibration" / "plots.parquet")),
        train_table=train_table,
    )


def per_step(table: pa.Table, column: str) -> np.ndarray:
    """A column as (windows x steps), checking the rows are window by window, step by step."""
    length = int(table.column("step").to_numpy().max()) + 1
    assert table.column("step").to_numpy().reshape(-1, length).tolist() == [list(range(length))] * (
        table.num_rows // length)
    return table.column(column).to_numpy(zero_copy_only=False).reshape(-1, length)


def unscaled(table: pa.Table, prefix: str, scaler: WindowScaler) -> np.ndarray:
    """The `prefix_*` windows back in metres and seconds, using each window's stored origin."""
    origin = np.column_stack([per_step(table, f"origin_{name}")[:, 0] for name in materials.ORIGIN_COLUMNS])
    return scaler.inverse(windows.window_arrays(table, prefix, scaler.features), origin)


def test_written_scalers_are_the_ones_the_params_describe(chain):
    """scalers.json rebuilds exactly the scalers made from the `windows:` params."""
    assert chain.scalers == materials.scalers(chain.params.windows)


def test_filter_pairs_each_plot_with_the_truth_at_its_time(chain):
    """Unscaled filter windows: in = the measured plots, out = the truth at the same plot times (1e-6 m)."""
    table = chain.material["filter"]
    plot_id = per_step(table, "plot_id")
    assert plot_id.shape[1] == 10
    plots, truth = unscaled(table, "in", chain.scalers["plots"]), unscaled(table, "out", chain.scalers["plots"])
    np.testing.assert_array_equal(plots[..., 0], truth[..., 0])
    np.testing.assert_allclose(plots[..., 0], chain.train.at("time_unix_s", plot_id), rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(plots[..., 1:4], chain.train.position(plot_id), rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(plots[..., 4], chain.train.at("range_m", plot_id), rtol=0.0, atol=1e-6)
    true_position = chain.train.position(plot_id, "true_")
    np.testing.assert_allclose(truth[..., 1:4], true_position, rtol=0.0, atol=1e-6)
    site = geodesy.radar_site_ecef(chain.params.radar)
    np.testing.assert_allclose(truth[..., 4], np.linalg.norm(true_position - site, axis=-1), rtol=0.0, atol=1e-6)


@pytest.mark.parametrize("name", sorted(LENGTHS))
def test_material_windows_are_consecutive_plots_of_one_segment(chain, name):
    """Every window is consecutive target plots of one scenario and segment, at most 18 s apart."""
    table = chain.material[name]
    plot_id, segment = per_step(table, "plot_id"), per_step(table, "segment_id")
    assert plot_id.shape[1] == LENGTHS[name]
    assert (segment == segment[:, :1]).all()
    assert (chain.train.at("scenario_id", plot_id) == per_step(table, "scenario_id")[:, :1]).all()
    rank = chain.train.target_rank(plot_id)
    assert (rank >= 0).all() and (np.diff(rank, axis=1) == 1).all()
    step_s = np.diff(chain.train.at("time_unix_s", plot_id), axis=1)
    assert (step_s > 0).all() and (step_s <= GAP_S).all()


def test_predictor_windows_are_six_true_states_with_time_to_the_next(chain):
    """Unscaled predictor states are the truth of their plots; dt is the time to the next state, 0 at step 5."""
    table = chain.material["predictor"]
    plot_id = per_step(table, "plot_id")
    assert plot_id.shape[1] == 6
    states = unscaled(table, "state", chain.scalers["states"])
    time = states[..., 0]
    np.testing.assert_allclose(time, chain.train.at("time_unix_s", plot_id), rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(states[:, :5, 1], np.diff(time, axis=1), rtol=0.0, atol=1e-6)
    assert (states[:, 5, 1] == 0.0).all()
    true_position = chain.train.position(plot_id, "true_")
    np.testing.assert_allclose(states[..., 2:5], true_position, rtol=0.0, atol=1e-6)
    site = geodesy.radar_site_ecef(chain.params.radar)
    np.testing.assert_allclose(states[..., 5], np.linalg.norm(true_position - site, axis=-1), rtol=0.0, atol=1e-6)


def low_and_high(values: np.ndarray, bins: int, high_bins: int) -> tuple[int, int]:
    """Windows in the first `bins - high_bins` equal bins of the observed range, and in the last ones."""
    edges = np.linspace(values.min(), values.max(), bins + 1)
    high = int((values >= edges[bins - high_bins]).sum())
    return len(values) - high, high


@pytest.mark.parametrize("name", sorted(LENGTHS))
def test_balancing_counts_follow_the_thesis_rule(chain, name):
    """windows.json before/after: all curved windows kept, as many straight ones drawn (or all if fewer)."""
    cfg = chain.params.windows
    targets = windows.target_plots(chain.train_table, chain.params.radar, cfg.segment_gap_s, "train")
    training = targets.take(~np.isin(targets.segment_id, chain.holdout.column("segment_id").to_numpy()))
    length = LENGTHS[name]
    before = windows.linearity(windows.gather(training.true_position,
                                              windows.window_starts(training.segment_id, length), length))
    low, high = low_and_high(before, cfg.balance_bins, cfg.balance_high_bins)
    counts = chain.report["materials"][name]
    assert counts["before"] == len(before)
    assert counts["after"] == low + min(low, high) <= counts["before"]
    table = chain.material[name]
    assert table.num_rows == counts["after"] * length
    kept = per_step(table, "linearity")[:, 0]
    edges = np.linspace(before.min(), before.max(), cfg.balance_bins + 1)
    assert (kept < edges[-cfg.balance_high_bins - 1]).sum() == low


def test_holdout_segments_never_reach_training_material(chain):
    """No hold-out segment or plot is in any training material; the hold-out is round(fraction * segments)."""
    held_segments = set(chain.holdout.column("segment_id").to_pylist())
    held_plots = set(chain.holdout.column("plot_id").to_pylist())
    total = chain.report["segments"]["total"]
    assert total == chain.train.segments
    assert 0 < len(held_segments) == round(HOLDOUT_FRACTION * total) == chain.report["segments"]["holdout"]
    assert len(held_plots) == chain.holdout.num_rows == chain.report["segments"]["holdout_plots"]
    for name in LENGTHS:
        table = chain.material[name]
        assert held_segments.isdisjoint(table.column("segment_id").to_pylist()), name
        assert held_plots.isdisjoint(table.column("plot_id").to_pylist()), name


def test_holdout_is_raw_target_plots_in_metres(chain):
    """The hold-out holds the held segments' target plots unscaled: positions and truth as simulated."""
    holdout = {name: chain.holdout.column(name).to_numpy() for name in chain.holdout.column_names}
    plot_id = holdout["plot_id"]
    assert chain.train.at("is_target", plot_id).all()
    np.testing.assert_array_equal(holdout["time_unix_s"], chain.train.at("time_unix_s", plot_id))
    for axis in "xyz":
        np.testing.assert_array_equal(holdout[f"{axis}_ecef_m"], chain.train.at(f"{axis}_ecef_m", plot_id))
        np.testing.assert_array_equal(holdout[f"true_{axis}_ecef_m"], chain.train.at(f"true_{axis}_ecef_m", plot_id))


def test_calibration_windows_end_with_a_near_candidate_labelled_by_its_origin(chain):
    """4 consecutive target plots, then a plot < 8 s later and < 20 km away, labelled is_target; both labels occur."""
    cfg = chain.params.windows
    table = chain.material["autoencoder_calibration"]
    plot_id = per_step(table, "plot_id")
    assert plot_id.shape[1] == 5
    calibration = chain.calibration
    rank = calibration.target_rank(plot_id[:, :4])
    assert (rank >= 0).all() and (np.diff(rank, axis=1) == 1).all()
    assert (calibration.at("scenario_id", plot_id) == calibration.at("scenario_id", plot_id[:, :1])).all()
    last, candidate = plot_id[:, 3], per_step(table, "candidate_plot_id")[:, 0]
    np.testing.assert_array_equal(plot_id[:, 4], candidate)
    delay = calibration.at("time_unix_s", candidate) - calibration.at("time_unix_s", last)
    assert (delay > 0).all() and (delay < cfg.calibration_max_delay_s).all()
    distance = np.linalg.norm(calibration.position(candidate) - calibration.position(last), axis=1)
    assert (distance < cfg.calibration_max_distance_m).all()
    label = per_step(table, "label")[:, 0]
    np.testing.assert_array_equal(label, calibration.at("is_target", candidate))
    assert label.any() and not label.all()
    # A true candidate is the target's next plot; and the scaled features are the plots'.
    assert (calibration.target_rank(candidate[label]) == rank[label, 3] + 1).all()
    plots = unscaled(table, "in", chain.scalers["plots"])
    np.testing.assert_allclose(plots[..., 1:4], calibration.position(plot_id), rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(plots[..., 4], calibration.at("range_m", plot_id), rtol=0.0, atol=1e-6)

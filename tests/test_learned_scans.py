"""The learned trackers step a scan in one call (issue 29): their estimators and gates are `pairwise`,
so the loop predicts, scores and updates the (track, plot) pairs of a whole antenna scan (global
nearest neighbour) or of nearest neighbour's look-ahead (`run._track_ahead`) in one network call
each, MC-dropout copies and MIA's samples included. The update table is the one the same tracker
gives stepping one plot at a time (roles not `pairwise`), to the last bit, column by column.

Eight flights crossing each other's paths 3 km apart among clutter (`test_kalman_tracker`), networks
with random weights (scales, corrections and spreads that differ from pair to pair).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest
import torch

from pipeline.learning import batch_rows
from pipeline.learning.kalman_net import KalmanNet
from pipeline.learning.lstm_update import LSTMUpdate, LSTMUpdateConfig
from pipeline.tracker import registry, run
from pipeline.tracker.assigner import GlobalNearestPerScan
from pipeline.tracker.models import Models
from pipeline.tracker.draws import PairDraws
from pipeline.tracker.run import Composition, track
from tests import tracker_fixtures as tf
from tests.test_kalman_net_tracker import pinned_network
from tests.test_kalman_tracker import crossing_flights_among_clutter

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def params():
    return tf.make_params()


@pytest.fixture(scope="module")
def plots(params):
    return crossing_flights_among_clutter(params)


def scaling_network(params) -> KalmanNet:
    """A network-scaled CV filter whose every weight is random: scales that differ from pair to pair."""
    model = pinned_network(params)
    torch.manual_seed(6)
    with torch.no_grad():
        for parameter in model.network.parameters():
            parameter.normal_(0.0, 0.5)
    return model.eval()


def lstm_update(copies: int, floor_m: float, dropout: float = 0.2) -> LSTMUpdate:
    """An LSTM update with MC dropout over `copies` copies of a track besides its point estimate and a
    covariance floor of `floor_m`, its cell and output weights perturbed at random (the output layer
    otherwise reads only the features); with `dropout` 0, the point estimate alone."""
    config = LSTMUpdateConfig(hidden=16, dropout=dropout, mc_samples=copies, detach_prediction=False,
                              position_scale_m=1000.0, velocity_scale_mps=400.0, acceleration_scale_mps2=10.0,
                              time_scale_s=6.0, initial_alpha=0.5, initial_beta=0.2, floor_m=floor_m,
                              start_velocity_std_mps=170.0, calibration_ages=4, calibration_gaps=3)
    torch.manual_seed(7)
    model = LSTMUpdate(config)
    with torch.no_grad():
        for parameter in model.cell.parameters():
            parameter.add_(torch.randn_like(parameter) * 0.1)
        model.output.weight.add_(torch.randn_like(model.output.weight) * 0.01)
    return model.eval()


def scan_and_plot_by_plot(compose: Callable[[], Composition], plots, monkeypatch
                          ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], list[bool]]:
    """The update tables of a tracker stepping pairs at once and of the same tracker one plot at a
    time, and the look-ahead's verdicts (`run._unchanged_near`: True, a plot kept its scores)."""
    verdicts = []
    unchanged_near = run._unchanged_near

    def watched(*args):
        verdicts.append(unchanged_near(*args))
        return verdicts[-1]

    monkeypatch.setattr(run, "_unchanged_near", watched)
    tables = []
    for pairwise in (True, False):
        tracker = compose()
        tracker.estimator.pairwise = pairwise
        assert tracker.pairwise == pairwise
        tables.append(track(plots, tracker))
    return tables[0], tables[1], verdicts


def assert_same_updates(scan: dict[str, np.ndarray], plot_by_plot: dict[str, np.ndarray]) -> None:
    assert scan.keys() == plot_by_plot.keys()
    for column, values in scan.items():
        np.testing.assert_array_equal(values, plot_by_plot[column], err_msg=column)


@pytest.mark.parametrize("runtime", ["script", "eager"])
@pytest.mark.parametrize("method", ["kalman_net", "kalman_net_gnn"])
def test_the_network_scaled_filter_steps_a_scan_as_plot_by_plot(params, plots, method, runtime, monkeypatch):
    """The network steps every (track, plot) pair of a scan, or of four plots ahead, in one call;
    the updates are those of one plot at a time, through both kinds of look-ahead plot (kept, scored
    again); traced to TorchScript and eager (`tracker.learned_runtime`)."""
    model, tracker_params = scaling_network(params), replace(params.tracker, learned_runtime=runtime)
    scan, plot_by_plot, verdicts = scan_and_plot_by_plot(
        lambda: registry.compose(method, Models({"kalman_net": model}), tracker_params, 4000.0, 0), plots,
        monkeypatch)
    assert (scan["association"] == method).sum() > 50
    if method == "kalman_net":
        assert True in verdicts and False in verdicts
    assert_same_updates(scan, plot_by_plot)


@pytest.mark.parametrize("runtime", ["script", "eager"])
@pytest.mark.parametrize("copies, floor_m", [(8, 1.0), (2, 1000.0)])
def test_the_lstm_update_predicts_a_look_ahead_at_once_and_steps_as_plot_by_plot(params, plots, copies, floor_m,
                                                                                  runtime, monkeypatch):
    """Nearest neighbour's four plots ahead predicted in one call, and each track stepped with its MC-dropout
    masks drawn in the order of the updates: the updates of one plot at a time; with 2 copies a track's
    step runs on more rows than its own 3 (`batch_rows`; their spread is a line, so a floor of 1 km
    makes the gate). Young tracks take what the window takes too (`tracker.lstm_update.young_window_fallback`).
    Traced to TorchScript and eager (`tracker.learned_runtime`)."""
    fallback = replace(params.tracker.lstm_update, young_window_fallback=True)
    model = lstm_update(copies, floor_m)
    tracker_params = replace(params.tracker, lstm_update=fallback, learned_runtime=runtime)
    scan, plot_by_plot, verdicts = scan_and_plot_by_plot(
        lambda: registry.compose("lstm_update", Models({"lstm_update": model}), tracker_params, 4000.0, 0), plots,
        monkeypatch)
    assert (scan["association"] == "lstm_update").sum() > 50
    assert True in verdicts and False in verdicts
    assert_same_updates(scan, plot_by_plot)


def test_the_lstm_update_with_global_nearest_neighbour_steps_a_scan_in_one_call(params, plots, monkeypatch):
    """Under global nearest neighbour (`lstm_update_gnn`) a scan's mature tracks step through the LSTM in
    one call: without dropout (no masks, so no draws whose order could differ) the updates of one plot at a
    time, to the bit."""
    model = lstm_update(8, 1000.0, dropout=0.0)
    assert model.ensemble() == (1, False)

    def compose(method: str) -> Composition:
        return registry.compose(method, Models({"lstm_update": model}), params.tracker, 4000.0, 0)

    scan, plot_by_plot, _ = scan_and_plot_by_plot(lambda: compose("lstm_update_gnn"), plots, monkeypatch)
    assert (scan["association"] == "lstm_update_gnn").sum() > 50
    assert_same_updates(scan, plot_by_plot)
    assert isinstance(compose("lstm_update_gnn").assigner, GlobalNearestPerScan)


@pytest.mark.parametrize("method", ["radius", "via", "mia", "ae"])
def test_the_thesis_networks_score_a_look_ahead_at_once_as_plot_by_plot(params, plots, method, monkeypatch,
                                                                        tmp_path_factory):
    """The predictor runs once for every (track, plot) pair of four plots ahead, MIA's samples of every
    pair in the same call (each pair's its own draws, `pipeline.tracker.draws`), the autoencoder once
    for all of them, and a scan's filter-network updates in one call: the updates of one plot at a
    time, to the bit, through both kinds of look-ahead plot."""
    models = tf.load_models(tf.trained_models(tmp_path_factory))
    scan, plot_by_plot, verdicts = scan_and_plot_by_plot(
        lambda: registry.compose(method, models, params.tracker, 4000.0, 0), plots, monkeypatch)
    assert (scan["association"] == method).sum() > 50
    assert True in verdicts and False in verdicts
    assert_same_updates(scan, plot_by_plot)


def test_a_pairs_draws_are_its_own_in_any_call():
    """MIA's samples of a (track, plot) pair do not depend on the pairs drawn with it, or on the order."""
    draws = PairDraws(7)
    together = draws.normals(np.array([3, 5, 3]), np.array([100, 100, 101]), 4)
    assert together.shape == (12, 3)
    np.testing.assert_array_equal(together[4:8], draws.normals(np.array([5]), np.array([100]), 4))
    np.testing.assert_array_equal(together[:4], PairDraws(7).normals(np.array([3]), np.array([100]), 4))
    assert not np.array_equal(together[:4], together[8:])  # another plot, other draws
    assert not np.array_equal(together[:4], PairDraws(8).normals(np.array([3]), np.array([100]), 4))
    assert abs(PairDraws(1).normals(np.arange(2000), np.zeros(2000), 1).std() - 1.0) < 0.03


@pytest.mark.parametrize("count, rows_each, elements_each, expected", [
    (1, 1, 16, 4), (5, 1, 16, 5),    # at least 4 rows for MKL's matrix products
    (1, 1, 2, 8), (9, 1, 2, 16),     # 2 sigmoids a row: whole steps of 16
    (1, 17, 17 * 32, 1), (1, 2, 2, 8),  # an LSTM track's 17 copies make 4 rows alone
])
def test_padding_makes_whole_matrix_and_vector_steps(count, rows_each, elements_each, expected):
    """The rows a call runs: the items, then the last one again up to the count `batch_rows` asks."""
    rows = batch_rows.padding(count, rows_each, elements_each)
    assert len(rows) == expected
    np.testing.assert_array_equal(rows, np.minimum(np.arange(expected), count - 1))


@pytest.mark.parametrize("runtime", ["script", "eager"])
@pytest.mark.parametrize("copies", [16, 8, 3, 2])
def test_the_lstm_step_alone_gives_each_track_the_numbers_of_its_own_call(copies, runtime):
    """A scan's young tracks step together (`step_runtime.LSTMStepAlone`) with each track's numbers, to the bit,
    those of its own call (`LSTMStep`, padded as `update_pairs` pads one track): 17 and 9 copies leave one row
    of a call of one track to MKL's last-rows kernel, 4 none, 3 copies pad it with a second track."""
    from pipeline.learning import step_runtime
    from pipeline.learning.lstm_update import FEATURES
    from pipeline.tracker.lstm_update_estimator import LSTMUpdateEstimator
    model = lstm_update(copies, 1.0)
    estimator = LSTMUpdateEstimator(model, 0, runtime=runtime)
    assert estimator.samples == copies + 1
    generator, tracks = torch.Generator().manual_seed(3), 11
    normal = lambda *shape: torch.randn(*shape, generator=generator, dtype=torch.float64)  # noqa: E731
    start = torch.full((tracks, 3), 6.4e6, dtype=torch.float64) + normal(tracks, 3) * 1e4
    ensemble = model.started(start, copies + 1)
    x, h, c = ensemble.x + normal(*ensemble.x.shape) * 50.0, normal(*ensemble.h.shape), normal(*ensemble.c.shape)
    age, dt = torch.randint(1, 6, (tracks,), generator=generator), torch.full((tracks,), 6.0, dtype=torch.float64)
    z, R = start + 1e3 + normal(tracks, 3) * 100.0, torch.eye(3, dtype=torch.float64).expand(tracks, 3, 3) * 1e4
    masks = torch.stack([model.dropout_masks(copies + 1, generator) for _ in range(tracks)])

    def stepped(step, rows: np.ndarray) -> tuple[torch.Tensor, ...]:
        at = torch.as_tensor(rows)
        with torch.no_grad():
            return step(x[at], h[at], c[at], age[at], z[at], R[at], dt[at], masks[at])

    alone = [stepped(estimator._step, np.full(1, k)[batch_rows.padding(1, copies + 1)]) for k in range(tracks)]
    assert isinstance(estimator._step_alone, step_runtime.Unoptimised if runtime == "script" else
                      step_runtime.LSTMStepAlone)
    for count in (1, 2, 3, 5, tracks):
        together = stepped(estimator._step_alone, np.arange(count)[batch_rows.padding(count, copies + 1)])
        for k in range(count):
            for name, value, own in zip(("x", "h", "c", "age", "position", "covariance"), together, alone[k]):
                assert torch.equal(value[k], own[0]), (count, k, name)


def test_the_dropout_masks_of_several_tracks_are_each_tracks_own_draws():
    """Drawn for several tracks at once (`LSTMUpdate.dropout_masks(tracks=...)`), the masks are those drawn
    track after track, and the generator ends where it would: the updates' draws do not change."""
    model = lstm_update(16, 1.0)
    for tracks in (1, 2, 7):
        one_by_one, together = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
        expected = torch.stack([model.dropout_masks(17, one_by_one) for _ in range(tracks)])
        assert torch.equal(model.dropout_masks(17, together, tracks=tracks), expected)
        assert torch.equal(torch.rand(4, generator=together), torch.rand(4, generator=one_by_one))

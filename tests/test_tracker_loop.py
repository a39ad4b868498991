"""The tracking loop (`pipeline.tracker.run`) with stub components, no trained networks: start,
confirmation and deletion by the thesis's weights, one shared prediction per plot, global nearest
neighbour over a scan, the oracle's true association, and the count of plots a learned gate
refused that the window would have taken (`pipeline.tracker.refusals`).

Plots lie on a line through a point near the radar (ECEF x axis offsets), so distances are plain
to read; the stub estimator takes each plot as the track's new position and predicts that a track
stays where it is.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import io
from pipeline.recordings.plot_table import NO_TARGET
from pipeline.tracker import registry
from pipeline.tracker.assigner import Candidates, GlobalNearestPerScan, NearestPerPlot, TrueAssociation
from pipeline.tracker.estimator import Prediction
from pipeline.tracker.gate import AcceptAll, RadiusFloorGate, RadiusGate, Scores, WindowGate
from pipeline.tracker.management import ThesisWeights
from pipeline.tracker.models import Models
from pipeline.tracker.refusals import RefusalCounts, RefusalWatch, remedy, warn_refusals
from pipeline.tracker.run import Composition, track, track_chunks
from pipeline.tracker.tracks import LiveTracks
from tests import tracker_fixtures as tf

ORIGIN = np.array([2.9e6, 1.3e6, 5.5e6])  # ECEF metres, near the default radar
RULE = ThesisWeights(start=0.4, candidate=0.8, confirmed_weight=1.0, step=0.2, silence_s=12.0)
WINDOW_M = 2000.0


class StayingEstimator:
    """A stub estimator: a track is predicted where its last update put it, and an update puts it on
    the plot. It records every prediction it makes and every prediction an update is given."""

    gives_covariance = False
    gives_velocity = False
    pairwise = True  # it ignores the time: any (track, plot) pairs
    latest_plots = 0  # it reads no plot of a track's

    def __init__(self) -> None:
        self.made: list[Prediction] = []
        self.given: list[Prediction | None] = []

    def start(self, tracks, slot: int) -> None:
        pass

    def predict(self, tracks, slots: np.ndarray, time: float) -> Prediction:
        self.made.append(Prediction(tracks.position[slots].copy(), None, slots.copy()))
        return self.made[-1]

    def update(self, tracks, slot: int, row: int, prediction: Prediction | None, index: int):
        self.given.append(prediction)
        return tracks.plots.position[row], None

    def update_pairs(self, tracks, slots: np.ndarray, rows: np.ndarray, prediction: Prediction, indices: np.ndarray):
        self.given.extend([prediction] * len(slots))
        return tracks.plots.position[rows], None


class RecordingGate(WindowGate):
    """VIA's window gate, recording the predictions it is given."""

    def __init__(self, window_m: float) -> None:
        super().__init__(window_m)
        object.__setattr__(self, "seen", [])

    def __call__(self, tracks, slots, row, prediction):
        self.seen.append(prediction)
        return super().__call__(tracks, slots, row, prediction)


class FixedGate:
    """A stub learned gate: the same errors for every call, one per candidate in slot order (inf
    everywhere by default: it refuses every plot, as the LSTM update's gate a target faster than its
    training, issue 27)."""

    uses_prediction = False
    pairwise = True
    latest_plots = 0

    def __init__(self, errors: list[float] | None = None) -> None:
        self.errors = errors

    def __call__(self, tracks, slots, row, prediction):
        return Scores(np.full(len(slots), np.inf) if self.errors is None else np.array(self.errors), None)


def composition(estimator=None, gate=None, assigner=None, mature_from: int = 2, prefilter_m: float = 20000.0,
                mature_first: bool = False, young_gate=None, refusals: RefusalWatch | None = None) -> Composition:
    return Composition("stub", estimator or StayingEstimator(), gate or WindowGate(WINDOW_M),
                       young_gate or RadiusGate(WINDOW_M), "radius", mature_from, prefilter_m,
                       assigner or NearestPerPlot(), RULE, mature_first, refusals)


def plots(times: list[float], offsets_m: list[float], targets: list[int] | None = None):
    """Plots at `times` (s after T0), `offsets_m` metres along ECEF x from ORIGIN."""
    positions = ORIGIN + np.outer(offsets_m, [1.0, 0.0, 0.0])
    features = np.column_stack([tf.T0 + np.asarray(times, float), positions, np.full(len(times), 1e5)])
    radar = tf.make_params().radar
    return tf.plots_of(features, np.arange(len(times)), radar, None if targets is None else np.asarray(targets))


def test_a_track_starts_is_confirmed_at_its_fourth_plot_and_labels_its_gates():
    """Six plots 500 m apart, 6 s apart: one track; weights 0.4, 0.6, 0.8, 1.0, 1.0, 1.0; statuses
    tentative, tentative, candidate, confirmed...; the second plot joins by the young-track radius, the
    others by the method's gate; a start's error is NaN, the others distance / window."""
    updates = track(plots([0, 6, 12, 18, 24, 30], [0, 500, 1000, 1500, 2000, 2500]), composition())
    assert tf.tracks_of(updates) == {0: [0, 1, 2, 3, 4, 5]}
    np.testing.assert_allclose(updates["weight"], [0.4, 0.6, 0.8, 1.0, 1.0, 1.0])
    assert [RULE.status(w) for w in updates["weight"]] == ["tentative", "tentative", "candidate", "confirmed",
                                                            "confirmed", "confirmed"]
    assert updates["association"].tolist() == ["start", "radius", "stub", "stub", "stub", "stub"]
    assert np.isnan(updates["association_error"][0])
    np.testing.assert_allclose(updates["association_error"][1:], 500.0 / WINDOW_M)
    np.testing.assert_allclose(updates["x_ecef_m"] - ORIGIN[0], [0, 500, 1000, 1500, 2000, 2500], atol=1e-6)
    assert np.isnan(updates["position_covariance"]).all()


@pytest.mark.parametrize("gap_s, same_track", [(12.0 - 1 / 128, True), (12.0, True), (12.0 + 1 / 128, True),
                                                (12.02, False)])
def test_a_revisit_exactly_on_the_silence_boundary_is_associated_before_the_lowering(gap_s, same_track):
    """Case 07's kind: a candidate (0.8, after three plots 6 s apart) misses one scan and its next
    plot comes silence_s = 12 s later, to the time quantum (ASTERIX's 1/128 s) either side: the plot
    joins the track (back to 1.0) before the due lowering would delete it, whichever way the time was
    rounded; a plot clearly later finds the candidate deleted and starts a new track."""
    updates = track(plots([0, 6, 12, 12 + gap_s], [0, 100, 200, 300]), composition())
    assert updates["weight"][2] == pytest.approx(0.8)
    assert updates["track_id"].tolist() == ([0] * 4 if same_track else [0, 0, 0, 1])
    assert updates["weight"][-1] == pytest.approx(1.0 if same_track else 0.4)


@pytest.mark.parametrize("gap_s, same_track", [(18.0, True), (23.9, True), (24.1, False), (40.0, False)])
def test_a_silent_confirmed_track_is_lowered_once_then_deleted(gap_s, same_track):
    """A confirmed track silent for up to 24 s (lowered once, to 0.8) takes the next plot (back to 1.0);
    silent for longer it was deleted and the plot starts a new track at 0.4."""
    updates = track(plots([0, 6, 12, 18, 18 + gap_s], [0, 100, 200, 300, 400]), composition())
    assert updates["track_id"].tolist() == ([0] * 5 if same_track else [0] * 4 + [1])
    assert updates["weight"][-1] == pytest.approx(1.0 if same_track else 0.4)


def test_plots_out_of_every_gate_start_tracks_that_die_after_one_silence():
    """Plots 5 km apart never join a track; each starts one, deleted 12 s later (a plot at the same
    place 13 s on starts a new one)."""
    updates = track(plots([0, 1, 2, 14], [0, 5000, 10000, 0]), composition())
    assert updates["track_id"].tolist() == [0, 1, 2, 3]
    assert (updates["association"] == "start").all()


@pytest.mark.parametrize("mature_first, expected", [(False, [0, 0, 0, 0, 1, 1]), (True, [0, 0, 0, 0, 1, 0])])
def test_mature_first_keeps_a_plot_the_established_track_gates(mature_first, expected):
    """A track of four plots at 0 m; a plot at 2500 m misses its 2 km window and starts a young track;
    the next plot, at 1500 m, is inside the mature track's window (error 0.75) and nearer the young
    track's plot (error 0.5). Nearest of all gives it to the young track, which takes the aircraft
    over; mature first keeps it on the established track."""
    updates = track(plots([0, 6, 12, 18, 24, 30], [0, 0, 0, 0, 2500, 1500]), composition(mature_first=mature_first))
    assert updates["track_id"].tolist() == expected


def test_each_prediction_is_made_once_and_handed_to_gate_and_update():
    """For each plot with mature candidates the estimator predicts once; the gate scores with that
    prediction and the winner's update resumes from the very same object; young tracks get none."""
    estimator, gate = StayingEstimator(), RecordingGate(WINDOW_M)
    track(plots([0, 6, 12, 18], [0, 500, 1000, 1500]), composition(estimator, gate))
    assert len(estimator.made) == 2 and len(gate.seen) == 2
    assert all(seen is made for seen, made in zip(gate.seen, estimator.made))
    assert estimator.given[0] is None                      # plot 1: the young track, radius gate
    assert [given is made for given, made in zip(estimator.given[1:], estimator.made)] == [True, True]


def test_global_nearest_neighbour_assigns_a_scan_jointly_where_nearest_per_plot_is_greedy():
    """Scan 0 (one radar rotation, 6 s): plots at 0 and 1000 m start tracks A and B (no track is alive
    at the scan's start). Scan 1: plots at 600 m and 1500 m. Jointly the best is 600 -> A (error 0.3) and
    1500 -> B (0.25), 0.55 in all, against 0.95 for 600 -> B (0.2, the nearest) and 1500 -> A (0.75).
    Nearest per plot instead gives both scan-0 plots one track (1000 m is inside its window)."""
    recording = plots([0.0, 0.5, 6.0, 6.5], [0.0, 1000.0, 600.0, 1500.0])
    joint = track(recording, composition(assigner=GlobalNearestPerScan(), mature_from=1))
    assert tf.tracks_of(joint) == {0: [0, 2], 1: [1, 3]}
    np.testing.assert_allclose(joint["association_error"][2:], [0.3, 0.25])
    greedy = track(recording, composition(mature_from=1))
    assert tf.tracks_of(greedy) != tf.tracks_of(joint)


def test_global_nearest_neighbour_scans_follow_each_radars_rotation():
    """The batches are the runs of plots of one radar within one of its scans (6 s, from its first plot)."""
    recording = plots([0.0, 2.0, 5.9, 6.1, 11.0, 12.5], [0, 1, 2, 3, 4, 5])
    np.testing.assert_array_equal(GlobalNearestPerScan().batches(recording), [0, 3, 5, 6])


def test_global_nearest_neighbour_counts_a_later_parts_scans_from_the_radars_first_plot():
    """A recording read in parts: the second part (from 5.9 s) is cut at 6 s and 12 s, counted from
    the first part's first plot, not at 11.9 s from its own."""
    recording = plots([0.0, 2.0, 5.9, 6.1, 11.0, 12.5], [0, 1, 2, 3, 4, 5])
    assigner = GlobalNearestPerScan()
    assigner.batches(recording.take(np.arange(2)))
    np.testing.assert_array_equal(assigner.batches(recording.take(np.arange(2, 6))), [0, 1, 3, 4])


def test_the_oracle_joins_each_plot_to_its_own_targets_track():
    """Two targets crossing (their plots swap sides) among false plots, with no gating and an infinite
    pre-filter: each target's plots form its own track, whatever the distances; each false plot starts
    a track of its own."""
    times = [0, 1, 2, 6, 7, 8, 12, 13, 14]
    offsets = [0, 3000, 50, 1000, 2000, 1020, 2000, 1000, 40]
    targets = [1, 2, NO_TARGET, 1, 2, NO_TARGET, 1, 2, NO_TARGET]
    oracle = Composition("oracle", StayingEstimator(), AcceptAll(), RadiusGate(WINDOW_M), "radius", 1, float("inf"),
                         TrueAssociation(), RULE, False)
    updates = track(plots(times, offsets, targets), oracle)
    assert sorted(tf.tracks_of(updates).values()) == [[0, 3, 6], [1, 4, 7], [2], [5], [8]]
    assert set(updates["association"][updates["association"] != "start"]) == {"oracle"}


def test_the_oracle_needs_the_truth():
    with pytest.raises(io.InputError, match="target_id"):
        track(plots([0, 6], [0, 100]), composition(assigner=TrueAssociation()))


@pytest.mark.parametrize("distance_m", [20000.0, 7000.0, 45000.0])
def test_the_prefilter_grid_finds_exactly_the_tracks_a_scan_of_all_finds(distance_m):
    """Tracks started, moved and deleted at random over 60 km around ORIGIN (cubes of 20 km, so
    many tracks sit near cube faces): after every change, `near` gives, for every plot, the same
    sorted slots as testing the distance of every live track, for distances below, at and above
    the cube edge."""
    rng = np.random.default_rng(7)
    count = 400
    positions = ORIGIN + rng.uniform(-60000.0, 60000.0, (count, 3))
    positions[:40] = np.round(positions[:40] / 20000.0) * 20000.0  # exactly on cube faces
    features = np.column_stack([tf.T0 + np.arange(count, dtype=float), positions, np.full(count, 1e5)])
    live = LiveTracks(tf.plots_of(features, np.arange(count), tf.make_params().radar), RULE, latest_plots=0, capacity=4,
                      cell_m=20000.0)
    for row in range(count):
        if row % 3 == 2 and len(live):  # move a live track onto another plot's position
            slot = int(rng.choice(np.flatnonzero(live.alive)))
            live.associate(slot, row, positions[rng.integers(count)])
        else:
            live.start(row)
        if row % 50 == 49:  # tracks silent for more than a silence period die
            live.manage(tf.T0 + row + RULE.silence_s * rng.uniform(0.2, 1.0))
        for probe in rng.choice(row + 1, 5):
            offset = live.position - positions[probe]
            brute_force = np.flatnonzero(np.einsum("ij,ij->i", offset, offset) < distance_m ** 2)
            assert np.array_equal(live.near(int(probe), distance_m), brute_force)
    assert len(live) < count  # some tracks were deleted


@pytest.mark.parametrize("method", ["imm", "kalman_cv_gnn", "oracle"])
def test_a_recording_tracked_in_chunks_gives_the_updates_of_tracking_it_whole(method):
    """Chunks of 1, 7 and 100 plots (cutting scans and live tracks, and shorter than the tracks: a
    filter started in a later chunk than its track's first plot): the joined update tables equal
    the whole recording's, bit for bit, for nearest per plot, global nearest per scan and the oracle."""
    params = tf.make_params()
    recording = tf.busy_recording(params.radar)
    models = Models({"kalman_tuned": tf.untuned_filters(params)})
    whole = tf.assert_chunked_as_whole(
        recording, lambda: registry.compose(method, models, params.tracker, 4000.0, [params.tracker.seed]), (1, 7, 100))
    assert max(map(len, tf.tracks_of(whole).values())) > 7  # tracks outlive a chunk


def test_a_track_keeps_its_first_plot_and_the_latest_the_roles_read():
    """A track of 50 plots with `latest_plots` 3 holds the rows of its first plot and its latest 3,
    and only those are carried into the next part of a recording, renumbered (the new part after them)."""
    features = np.column_stack([tf.T0 + np.arange(60.0), ORIGIN + np.outer(np.arange(60.0), [100.0, 0.0, 0.0]),
                                np.full(60, 1e5)])
    plots = tf.plots_of(features, np.arange(60), tf.make_params().radar)
    live = LiveTracks(plots.take(np.arange(50)), RULE, latest_plots=3)
    slot = live.start(0)
    for row in range(1, 50):
        live.associate(slot, row, plots.position[row])
    assert live.tracks[slot].rows == [0, 47, 48, 49] and live.plot_count[slot] == 50
    assert live.carry(plots.take(np.arange(50, 60))) == 4
    assert live.tracks[slot].rows == [0, 1, 2, 3]
    assert live.plots.plot_id.tolist() == [0, 47, 48, 49, *range(50, 60)]
    with pytest.raises(ValueError, match="latest_plots"):
        LiveTracks(plots, RULE, latest_plots=-1)


FAST_TIMES, FAST_OFFSETS = [0, 6, 12, 15, 18, 24, 30], [0, 1500, 3000, -12000, 4500, 6000, 7500]  # a target
# 1500 m a scan (3/4 of the window), and at 15 s a clutter plot 12 km off: within the pre-filter, not the window


@pytest.mark.parametrize("young_learned, counted", [(True, (5, 5)), (False, (0, 0))])
def test_a_learned_gate_refusing_every_plot_leaves_each_its_own_track_and_is_counted(young_learned, counted):
    """A young-track gate that refuses every plot (lstm_update's on a target faster than its training):
    the target's 6 plots and the clutter plot each start a track, none confirmed. With the gate
    declared learned, the 5 target plots after the first lay within the window of the track the
    previous one started and are counted, all refused; the clutter plot, 12 km off, is not. A plain
    gate's refusals (declared not learned) are not counted."""
    watch = RefusalWatch(WINDOW_M, young=young_learned, mature=True)
    updates = track(plots(FAST_TIMES, FAST_OFFSETS), composition(young_gate=FixedGate(), gate=FixedGate(),
                                                                 refusals=watch))
    assert updates["track_id"].tolist() == [0, 1, 2, 3, 4, 5, 6]
    assert not RULE.confirmed(updates["weight"]).any()
    assert (watch.counts.in_window, watch.counts.refused) == counted


def test_young_tracks_floored_by_the_radius_take_what_the_window_takes():
    """The same target with the refusing gate floored by the window (`RadiusFloorGate`, lstm_update's
    young gate under `tracker.lstm_update.young_window_fallback`): the second plot joins by the radius,
    error (1500 / 2000)^2 on the chi-square's scale; the mature window gate takes the rest (error 0.75), one
    track confirmed at its fourth plot; the clutter plot starts its own; nothing counted refused."""
    watch = RefusalWatch(WINDOW_M, young=True, mature=True)
    updates = track(plots(FAST_TIMES, FAST_OFFSETS), composition(young_gate=RadiusFloorGate(FixedGate(), WINDOW_M),
                                                                 refusals=watch))
    assert updates["track_id"].tolist() == [0, 0, 0, 1, 0, 0, 0]
    assert updates["association"].tolist() == ["start", "radius", "stub", "start", "stub", "stub", "stub"]
    np.testing.assert_allclose(updates["association_error"][[1, 2, 4, 5, 6]], [0.5625, 0.75, 0.75, 0.75, 0.75])
    assert [RULE.status(w) for w in updates["weight"][[0, 1, 2, 4]]] == ["tentative", "tentative", "candidate",
                                                                         "confirmed"]
    assert (watch.counts.in_window, watch.counts.refused) == (5, 0)


def test_the_radius_floor_keeps_the_smaller_error_and_refuses_only_what_both_refuse():
    """Three one-plot tracks 1000, 1000 and 2500 m from a plot, the learned gate's errors 0.1, inf, inf:
    the floored errors are 0.1 (the learned gate's, below the radius's 0.25), 0.25 ((1000 / 2000)^2,
    the radius alone) and inf (outside both)."""
    table = plots([0, 0, 0, 6], [0, 2000, 3500, 1000])
    live = LiveTracks(table, RULE, latest_plots=0)
    slots = np.array([live.start(row) for row in range(3)])
    scores = RadiusFloorGate(FixedGate([0.1, np.inf, np.inf]), WINDOW_M)(live, slots, 3, None)
    np.testing.assert_allclose(scores.errors, [0.1, 0.25, np.inf])


def test_refusals_counted_in_chunks_are_those_of_the_whole_recording():
    """The counts follow the plots, not the chunks a recording is read in: one plot a chunk counts
    what the whole does."""
    recording = plots(FAST_TIMES, FAST_OFFSETS)
    counts = []
    for size in (1, len(recording)):
        watch = RefusalWatch(WINDOW_M, young=True, mature=True)
        chunks = [recording.take(np.arange(k, min(k + size, len(recording)))) for k in range(0, len(recording), size)]
        list(track_chunks(chunks, composition(young_gate=FixedGate(), gate=FixedGate(), refusals=watch)))
        counts.append(watch.counts)
    assert counts[0] == counts[1] == RefusalCounts(in_window=5, refused=5)


def test_a_scans_refusals_are_counted_at_once_as_plot_by_plot():
    """Three one-plot tracks at 0, 2000 and 3500 m and a scan of three plots, counted by a watch of learned
    young gates: the plot at 1000 m (two young candidates in the window, one accepting) is in the window;
    the one at 20 km has no candidate; the one at 2600 m, refused by its young candidate 600 m off and by
    a mature one whose gate is not learned, is in the window and refused. One call for the scan counts
    what three calls, a plot each, count."""
    live = LiveTracks(plots([0, 0, 0, 6, 6, 6], [0, 2000, 3500, 1000, 20000, 2600]), RULE, latest_plots=0)
    for row in range(3):
        live.start(row)
    scan = [Candidates(np.array([0, 1]), np.array([np.inf, 0.5]), np.array([False, False]), None, 0),
            Candidates(np.empty(0, dtype=np.int64), np.empty(0), np.empty(0, dtype=bool), None, 0),
            Candidates(np.array([1, 2]), np.array([np.inf, np.inf]), np.array([False, True]), None, 0)]
    at_once, plot_by_plot = (RefusalWatch(WINDOW_M, young=True, mature=False) for _ in range(2))
    at_once.count(live, range(3, 6), scan)
    for row, candidates in zip(range(3, 6), scan):
        plot_by_plot.count(live, range(row, row + 1), [candidates])
    assert at_once.counts == plot_by_plot.counts == RefusalCounts(in_window=2, refused=1)


@pytest.mark.parametrize("method, young_fallback, told", [
    ("lstm_update", False, "young_window_fallback widens"), ("lstm_update_gnn", False, "young_window_fallback widens"),
    ("lstm_update_gnn", True, "even with tracker.lstm_update.young_window_fallback on"),
    ("kalman_net", False, "a classical method")])
def test_the_remedy_for_a_refusing_gate_names_what_is_left_to_try(method, young_fallback, told):
    """Either LSTM update (per plot or per scan) is first told to widen its young tracks' gate; once that is
    on, or for another learned gate, a method whose gate is not learned."""
    assert told in remedy(method, young_fallback)


@pytest.mark.parametrize("refused, warned", [(0, False), (1, False), (2, True)])
def test_the_warning_names_the_method_once_the_refused_share_is_reached(caplog, refused, warned):
    """A share of 0.5: 2 of 4 plots in the window refused warn, naming the method and the count; 1 of 4
    (the odd clutter plot near a track) does not, nor does none."""
    with caplog.at_level("WARNING", logger="pipeline"):
        warn_refusals("kalman_net", 4000.0, RefusalCounts(in_window=4, refused=refused), 0.5)
    assert ("track: method kalman_net: its learned gate refused 2 of the 4 plots (50.0 %) that lay within "
            "window_m = 4000 m" in caplog.text) == warned
    assert len(caplog.records) == warned


@pytest.mark.parametrize("method, fallback, advice", [
    ("lstm_update", False, "tracker.lstm_update.young_window_fallback widens its young tracks' gate"),
    ("lstm_update", True, "even with tracker.lstm_update.young_window_fallback on: a classical method"),
    ("kalman_net", False, "its gate cannot follow such targets: a classical method")])
def test_the_warning_advises_what_is_left_to_try(caplog, method, fallback, advice):
    """Case 29: the LSTM update's warning offers the young-track fallback only while it is off; once on, and
    for the other learned gates, it names the methods that follow such targets."""
    with caplog.at_level("WARNING", logger="pipeline"):
        warn_refusals(method, 4000.0, RefusalCounts(in_window=4, refused=4), 0.5, fallback)
    assert advice in caplog.text


@pytest.mark.parametrize("rule", [RULE, ThesisWeights(start=0.4, candidate=0.8, confirmed_weight=1.0, step=0.2,
                                                      silence_s=0.0, silence_scans=2.0)])
def test_survives_tells_whether_management_keeps_a_track_to_a_time(rule):
    """`LiveTracks.survives` replays a track's lowerings without making them: for every time it agrees with
    what `manage` up to that time does to a copy of the tracks (a young track, one raised to candidate, and
    the boundary's quantum), so the loop updates ahead only the young tracks that live to their plots."""
    recording = plots([0, 6, 12, 18], [0, 500, 1000, 1500])
    for associations in (0, 2):
        for now in np.arange(0.0, 80.0, 0.25).tolist() + [12.0 + 1.0 / 128.0, 12.0 + 2.0 / 128.0]:
            live = LiveTracks(recording, rule, latest_plots=0)
            slot = live.start(0)
            for row in range(1, associations + 1):
                live.associate(slot, row, recording.position[row])
            expected = live.survives(slot, tf.T0 + associations * 6 + now)
            live.manage(tf.T0 + associations * 6 + now)
            assert expected == live.holds(slot, 0), (associations, now)


def test_global_nearest_neighbour_updates_young_tracks_ahead_as_plot_by_plot():
    """A scan's chosen young tracks are updated in one `update_pairs` call with no prediction (the estimator
    predicts them itself), after the mature ones; a young track that management deletes before its plot's
    turn is not updated (its plot starts a track): the updates are those of the plot-by-plot loop."""
    # track A at 0 m takes a plot each scan; track B at 9 km, silent in scan 1, is chosen in scan 2 by a plot
    # 0.1 s after its silence ran out (12.5 s): deleted at that plot's turn, which starts track C
    recording = plots([0.0, 0.5, 6.0, 12.0, 12.6], [0.0, 9000.0, 300.0, 600.0, 9300.0])

    class Counting(StayingEstimator):
        def __init__(self, pairwise: bool) -> None:
            super().__init__()
            self.pairwise, self.young_calls = pairwise, []

        def update_pairs(self, tracks, slots, rows, prediction, indices):
            if prediction is None:
                self.young_calls.append(rows.tolist())
            return super().update_pairs(tracks, slots, rows, prediction, indices)

    tables = []
    for pairwise in (True, False):
        estimator = Counting(pairwise)
        tables.append(track(recording, composition(estimator, assigner=GlobalNearestPerScan(), mature_from=3)))
        if pairwise:
            assert estimator.young_calls == [[3]]  # scan 2: A's plot, not B's (scan 1 is one plot: no batch)
    for column in tables[0]:
        np.testing.assert_array_equal(tables[0][column], tables[1][column], err_msg=column)
    assert tf.tracks_of(tables[0]) == {0: [0, 2, 3], 1: [1], 2: [4]}

"""The M-of-N track management rule (`pipeline.tracker.m_of_n`) in the tracking loop, with the stub
parts of `tests/test_tracker_loop.py` (no networks), and a long orbit tracked by the tuned IMM
under both rules (`tracker.management.rule`).

M = 3, N = 5, one opportunity = one 6 s scan (the plots' radar's): a tentative track records a
miss 9 s after its last hit, then every 6 s.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.bench.evaluation import run_rule
from pipeline.bench.runs import declared_runs
from pipeline.bench.tracker_metrics import markdown_table
from pipeline.filters.classical_filters import FilterSettings
from pipeline.geometry import geodesy
from pipeline.settings import parse_params
from pipeline.tracker import registry
from pipeline.tracker.m_of_n import CONFIRMED, MOfN
from pipeline.tracker.management import ThesisWeights
from pipeline.tracker.models import Models
from pipeline.tracker.run import track
from pipeline.tracker.updates import confirmed_associations
from tests import tracker_fixtures as tf
from tests.test_tracker_loop import composition, plots

RULE = MOfN(m=3, n=5, delete_after_s=20.0, delete_after_scans=3.25)
# the default run's tuned filters (models/kalman_tuned.json of the committed run, rounded)
TUNED = {"cv": FilterSettings("cv", (20.22,), 112.4, 10.0, 0.05, 0.9),
         "ca": FilterSettings("ca", (24.36,), 167.2, 10.0, 0.05, 0.9),
         "imm": FilterSettings("imm", (0.1161, 34.68), 253.8, 10.0, 0.1645, 0.9)}


def m_of_n(**parts):
    """The stub composition of tests/test_tracker_loop.py under RULE."""
    return dataclasses.replace(composition(**parts), management=RULE)


def test_confirmed_at_the_mth_association_within_n_scans_and_not_before():
    """Hits at scans 0, 1 and 4 (scans 2 and 3 missed): 3 hits within 5 scans, confirmed by the third
    association, tentative before it."""
    updates = track(plots([0, 6, 24, 30], [0, 100, 400, 500]), m_of_n())
    assert tf.tracks_of(updates) == {0: [0, 1, 2, 3]}
    assert [RULE.status(w) for w in updates["weight"]] == ["tentative", "tentative", "confirmed", "confirmed"]
    assert updates["weight"][2] == CONFIRMED


def test_an_mth_association_outside_the_last_n_scans_does_not_confirm():
    """Hits at scans 0, 1 and 5 (three misses between): the last 5 scans (1-5) hold 2 hits, the
    third association leaves the track tentative; a hit at scan 6 leaves scans 2-6 with 2; hits at
    scans 7 confirm (5, 6, 7)."""
    updates = track(plots([0, 6, 30, 36, 42], [0, 100, 500, 600, 700]), m_of_n())
    assert tf.tracks_of(updates) == {0: [0, 1, 2, 3, 4]}
    assert [RULE.status(w) for w in updates["weight"]] == ["tentative"] * 4 + ["confirmed"]


def test_a_tentative_track_with_no_hit_in_its_last_n_scans_is_deleted():
    """A lone plot's track records misses at 9, 15, 21, 27 and 33 s: after 33 s its last 5 scans hold
    no hit and it is deleted; a plot at the same place at 33 s (to the time quantum) still joins it,
    one at 33.01 s starts anew."""
    assert track(plots([0, 33], [0, 100]), m_of_n())["track_id"].tolist() == [0, 0]
    assert track(plots([0, 33 + 1 / 128], [0, 100]), m_of_n())["track_id"].tolist() == [0, 0]
    assert track(plots([0, 33.01], [0, 100]), m_of_n())["track_id"].tolist() == [0, 1]


@pytest.mark.parametrize("silence_s, same_track", [(19.9, True), (20.0, True), (20.01, False), (20.1, False)])
def test_a_confirmed_track_silent_longer_than_delete_after_s_is_deleted(silence_s, same_track):
    """Confirmed at 12 s (hits at 0, 6, 12), then silent: a plot 19.9 s or exactly delete_after_s =
    20 s later joins it; a plot later than that finds it deleted and starts a new track."""
    updates = track(plots([0, 6, 12, 12 + silence_s], [0, 100, 200, 300]), m_of_n())
    assert RULE.status(updates["weight"][2]) == "confirmed"
    assert updates["track_id"].tolist() == ([0] * 4 if same_track else [0, 0, 0, 1])


def test_a_confirmed_track_is_not_lowered_before_its_time_out():
    """Unlike a tentative one, a confirmed track misses scans without losing its confirmation."""
    updates = track(plots([0, 6, 12, 30], [0, 100, 200, 300]), m_of_n())
    assert updates["track_id"].tolist() == [0] * 4
    assert (updates["weight"][2:] == CONFIRMED).all()


def orbit_plots(params, minutes: float = 20.0, rate_dps: float = 3.0, speed_mps: float = 150.0, seed: int = 5):
    """A constant-rate orbit (`rate_dps`, `speed_mps`) 60 km east and 40 km north of the default radar at
    6000 m, one plot per 6 s scan for `minutes`, no clutter, measured with the radar's errors
    (radar.sigma_*: range, azimuth, altitude) and placed in ECEF as the plot table places plots
    (thesis eqs. 4.1-4.6)."""
    radar = params.radar
    elapsed = np.arange(0.0, minutes * 60.0, tf.SCAN_S)
    heading = np.radians(rate_dps) * elapsed
    radius = speed_mps / np.radians(rate_dps)
    enu = np.column_stack([60e3 + radius * np.sin(heading), 40e3 + radius * np.cos(heading),
                           np.full(len(elapsed), 6000.0)])
    truth = tf.enu_to_features(tf.T0 + elapsed, enu, radar)[:, 1:4]
    slant, azimuth, altitude = geodesy.true_measurement(truth, radar)
    rng = np.random.default_rng(seed)
    slant = slant + rng.normal(0.0, radar.sigma_range_m, len(elapsed))
    azimuth = azimuth + rng.normal(0.0, radar.sigma_azimuth_deg, len(elapsed))
    altitude = altitude + rng.normal(0.0, radar.sigma_altitude_m, len(elapsed))
    features = np.column_stack([tf.T0 + elapsed, geodesy.plot_to_ecef(slant, azimuth, altitude, radar), slant])
    return tf.plots_of(features, np.arange(len(elapsed)), radar)


def confirmed_tracks(method: str, rule_name: str) -> int:
    """Confirmed tracks of the orbit tracked by `method` (tuned filters, 4 km young-track radius)
    under the management rule `rule_name`."""
    params = tf.make_params()
    composition = registry.compose(method, Models({"kalman_tuned": TUNED}), params.tracker, 4000.0, params.tracker.seed,
                                   rule_name)
    updates = track(orbit_plots(params), composition)
    return len(np.unique(updates["track_id"][confirmed_associations(updates, composition.management)]))


@pytest.mark.parametrize("rule", [registry.THESIS_RULE, registry.M_OF_N_RULE])
@pytest.mark.parametrize("method", ["kalman_cv", "kalman_ca", "imm"])
def test_a_20_minute_orbit_at_3_dps_is_one_confirmed_track(method, rule):
    """No clutter, 200 plots: under either rule the orbit is one confirmed track with every tuned
    filter. Before the tuning cost counted gate misses (`kalman.cost: rmse_in_gate`) and mature
    tracks had first claim on their plots (`tracker.association.mature_first`), the IMM split it into 5 (thesis)
    or 6 (m_of_n): tuned on RMSE alone its CV model had no process noise (0.0067 m/s^2), its
    prediction gated out a plot 700 m off in the turn, and the track that plot started took over."""
    assert confirmed_tracks(method, rule) == 1


def test_evaluate_scores_each_run_under_its_own_rule():
    """A run naming m_of_n is tracked and scored under MOfN; the others and the references under the
    tracker's rule (thesis by default)."""
    tree = tf.params_tree()
    tree["evaluate"]["site_runs"] = tree["evaluate"]["scene_runs"] = tree["peers"]["runs"] = []
    tree["evaluate"]["runs"] = [{"method": "via", "window_m": 4000.0}, {"method": "imm", "window_m": 4000.0},
                                {"method": "imm", "window_m": 4000.0, "management": "m_of_n"}]
    params = parse_params(tree)
    rules = {name: run_rule(params, run) for name, run in declared_runs(params).items()}
    management = tf.make_params().tracker.management
    assert rules["imm_4000_m_of_n"] == MOfN.from_params(management)
    assert rules["imm_4000"] == rules["plots_reference"] == ThesisWeights.from_params(management)


def test_the_tracker_table_labels_a_run_by_its_rule_and_keeps_the_others():
    """tracker_tables.md: `imm_4000_m_of_n` is the row `IMM 4000, m_of_n` right after `IMM 4000`, whose
    label is unchanged (our rows; the thesis's own rows sit under those it has)."""
    values = {"ROCA": 0.9}
    runs = tf.run_records({"imm_4000_m_of_n": values, "imm_4000": values, "via_4000": values})
    rows = [row for row in markdown_table(runs).splitlines()[2:] if "| ours |" in row]
    assert [row.split(" | ")[0] for row in rows] == ["| VIA 4000", "| IMM 4000", "| IMM 4000, m_of_n"]
    gnn = declared_runs(tf.make_params())["imm_gnn_4000_m_of_n"]
    assert (gnn.method, gnn.window_m, gnn.management, gnn.family) == ("imm_gnn", 4000.0, "m_of_n", registry.CLASSICAL)


def test_initiation_table_per_rule_fastest_first_with_false_tracks_per_hour_and_its_picture():
    """The comparison's track-initiation section: each tracker run under its rule (the default params' rule for
    a run that names none), fastest first, false tracks per flying hour; the raw plots' reference, no tracker,
    is left out; the picture is a PNG."""
    from pipeline.reports import comparison_tables, figures

    runs = tf.run_records({
        "imm_4000": {"initiation_mean_s": 23.2, "initiation_p95_s": 42.0, "false_tracks": 1.0},
        "imm_4000_m_of_n": {"initiation_mean_s": 14.8, "initiation_p95_s": 24.0, "false_tracks": 75.0},
        "plots_reference": {"initiation_mean_s": 1.1, "initiation_p95_s": 6.0, "false_tracks": 0.0},
        "via_4000": {"OSPA": 250.0}})
    rows = comparison_tables.initiation_rows(runs, "thesis", 50.0)
    assert comparison_tables.initiation_table(rows, hours=50.0).splitlines()[2:] == [
        "| imm_4000_m_of_n | m_of_n | 14.8 | 24 | 1.50 | – | – |", "| imm_4000 | thesis | 23.2 | 42 | 0.02 | – | – |"]
    assert figures.initiation_picture(rows).startswith(b"\x89PNG")


def test_initiation_table_reads_another_rule_against_the_default_with_paired_intervals():
    """A run under another rule is read against its method's run under the default rule: the paired intervals of
    the initiation time (s) and of the false tracks, per draw in the intervals, per flying hour in the table."""
    from pipeline.reports import comparison_tables

    runs = tf.run_records({
        "imm_gnn_4000": {"initiation_mean_s": 23.2, "initiation_p95_s": 42.0, "false_tracks": 1.0},
        "imm_gnn_4000_learned": {"initiation_mean_s": 10.0, "initiation_p95_s": 20.0, "false_tracks": 3.0}})
    paired = {"initiation_mean_s": {"imm_gnn_4000_learned": {"imm_gnn_4000": [-14.0, -12.5]}},
              "false_tracks": {"imm_gnn_4000_learned": {"imm_gnn_4000": [-1.0, 5.0]}}}
    rows = comparison_tables.initiation_rows(runs, "thesis", 50.0)
    assert comparison_tables.initiation_table(rows, {"paired": paired}, 50.0).splitlines()[2] == (
        "| imm_gnn_4000_learned | learned | 10.0 | 20 | 0.06 | [-14.00, -12.50] | [-0.02, +0.10] |")

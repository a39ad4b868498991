"""The peers stage (`pipeline.bench.peers`): Stone Soup's trackers, ours and the oracle on the same plots, scored by
GOSPA and the surveillance scorecard; and its report's verdicts (`pipeline.reports.peers_tables`)."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil

import numpy as np
import pytest

from pipeline import io
from pipeline.bench import peers, scene_evaluation
from pipeline.reports import peers_tables
from tests import tracker_fixtures as tf


def test_the_runs_are_stone_soups_then_ours_then_the_oracle() -> None:
    params = tf.make_params()
    runs = peers.peer_runs(params)
    ours = [run.name for run in params.peers.runs_of(params.evaluate)]  # in evaluate.runs' order
    assert sorted(ours) == sorted(params.peers.runs)
    assert [run.name for run in runs] == ["stone_soup_gnn", "stone_soup_jpda", *ours, "oracle_reference"]
    assert [run.family for run in runs][:2] == [peers.STONE_SOUP] * 2 and runs[-1].family == "reference"
    assert all(run.association is None for run in runs[2:]) and runs[0].run is None


def test_without_stone_soup_installed_its_runs_are_skipped_with_a_message(monkeypatch, caplog) -> None:
    """An environment without Stone Soup: the bench runs ours and the oracle, and says why Stone Soup's are not
    there and how to install it; the report then has no verdict against it, and no error."""
    import importlib.util

    from pipeline.peers import stone_soup

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *args: None if name == stone_soup.PACKAGE else real(name, *args))
    params = tf.make_params()
    with caplog.at_level("WARNING", logger="pipeline"):
        runs = peers.peer_runs(params)
    assert [run.family for run in runs].count(peers.STONE_SOUP) == 0 and runs[-1].name == "oracle_reference"
    assert "Stone Soup is not installed" in caplog.text and "pip install" in caplog.text
    report, intervals = _report(100.0, 120.0, [-30.0, -10.0])
    report["runs"]["test"].pop("stone_soup_jpda")
    assert peers_tables.verdicts(report, intervals) == []


def _report(ours_gospa: float, theirs_gospa: float, paired: list[float]) -> tuple[dict, dict]:
    metrics = {name: {"GOSPA": value, "position_rms_m": 150.0, "probability_of_update": 0.95,
                      "ratio_of_long_gaps": 0.01}
               for name, value in (("imm_gnn_4000", ours_gospa), ("stone_soup_jpda", theirs_gospa),
                                   ("oracle_reference", 1.0))}
    report = {"runs": {"test": metrics}, "families": {"imm_gnn_4000": "classical", "stone_soup_jpda": "stone_soup",
                                                      "oracle_reference": "reference"}}
    no_difference = [-1.0, 1.0]
    intervals = {"test": {"paired": {"GOSPA": {"imm_gnn_4000": {"stone_soup_jpda": paired}},
                                     **{name: {"imm_gnn_4000": {"stone_soup_jpda": no_difference}} for name in
                                        ("position_rms_m", "probability_of_update", "ratio_of_long_gaps")}}}}
    return report, intervals


def test_a_verdict_is_a_win_only_beyond_the_noise() -> None:
    """The best of ours (not the oracle, a reference) against the best of Stone Soup: GOSPA lower by 20 m with an
    interval excluding 0 is a win; the other metrics, equal with an interval about 0, are ties."""
    lines = peers_tables.verdicts(*_report(200.0, 220.0, [-30.0, -10.0]))
    assert lines[0].startswith("- GOSPA: imm_gnn_4000 200 against stone_soup_jpda 220") and "imm_gnn_4000 wins" in lines[0]
    assert all("a tie within the noise" in line for line in lines[1:])
    assert "stone_soup_jpda wins" in peers_tables.verdicts(*_report(230.0, 220.0, [5.0, 15.0]))[0]
    assert "a tie" in peers_tables.verdicts(*_report(210.0, 220.0, [-15.0, 4.0]))[0]


def test_speeds_are_told_as_multiples_of_stone_soups_fastest() -> None:
    """Stone Soup's GNN 50 plots/s and JPDA 40 on the same plots: ours as multiples of the faster, per family
    (the oracle, a reference, aside), in the speed line and in the table's last column."""
    report = {"runs": {"test": {name: {"GOSPA": 100.0 + rate, "plots_per_second": rate} for name, rate in (
        ("stone_soup_gnn", 50.0), ("stone_soup_jpda", 40.0), ("kalman_cv_4000", 10_000.0), ("imm_gnn_4000", 7_500.0),
        ("lstm_update_4000", 2_000.0), ("oracle_reference", 20_000.0))}},
        "families": {"stone_soup_gnn": "stone_soup", "stone_soup_jpda": "stone_soup", "kalman_cv_4000": "classical",
                     "imm_gnn_4000": "classical", "lstm_update_4000": "neural", "oracle_reference": "reference"}}
    assert peers_tables.speed_line(report) == [
        "- speed (plots/s on the same plots, tracking alone, one core): Stone Soup's fastest 50; ours classical "
        "150-200×, neural 40× as many (issue 33's goal for the classical trackers: 200×)."]
    table = peers_tables.material_table(report["runs"]["test"], None, report["families"]).splitlines()
    row = next(line for line in table if line.startswith("| kalman_cv_4000 |"))
    assert table[0].endswith("| plots/s | × Stone Soup's fastest |") and row.endswith("| 10,000 | 200× |")
    assert "Stone Soup" not in peers_tables.material_table(report["runs"]["test"], None).splitlines()[0]
    assert peers_tables.speed_line({"runs": {"test": {}}, "families": {}}) == []


def test_an_interval_read_back_as_null_is_shown_without_one() -> None:
    """A metric undefined on every resample has the interval [NaN, NaN], which JSON writes as [null, null]."""
    runs = {"a": {"GOSPA_missed": 10.0, "GOSPA_missed_undetected": 1.0, "GOSPA_missed_initiation": 4.0,
                  "GOSPA_missed_after_track": 5.0}}
    table = peers_tables.cause_table(runs, {"a": {"GOSPA_missed": [None, None], "GOSPA_missed_initiation": [3.0, 5.0]}})
    assert table.splitlines()[2] == "| a | 10 | 1 | 4 [3, 5] | 5 |"


def test_the_stage_runs_in_the_tiny_pipeline(tiny_pipeline, tmp_path) -> None:
    """`dvc repro peers` in a copy of the tiny pipeline: every run on every material (a test scenario per strategy,
    the first minute of the one scene, the real traffic), the scorecard's indicators beside the reference figures,
    intervals over the test scenarios and the scenes, the Markdown report."""
    from tests.servers import dvc
    repository = shutil.copytree(tiny_pipeline, tmp_path / "copy", symlinks=True)
    dvc(repository, "repro", "--single-item", "scenes")  # the tiny pipeline runs up to evaluate, which needs none
    dvc(repository, "repro", "--single-item", "peers")
    report = io.read_metrics(repository / "reports" / "peers.json")
    params = tf.make_params()
    names = ["stone_soup_gnn", "stone_soup_jpda", "via_4000", "ae_5000", "kalman_cv_4000", "oracle_reference"]
    assert set(report["materials"]) == {"test", "scenes", "real_traffic"}
    test = report["materials"]["test"]
    assert len(test["recordings"]) == len(set(test["strategies"].values())) <= 4 and test["window_s"] == 60.0
    assert report["materials"]["real_traffic"]["targets"] > 10
    scenes = report["materials"]["scenes"]
    assert scenes["recordings"] == [0] and scenes["window_s"] == 60.0 and scenes["aircraft"] == {"0": 6}
    assert 2 <= scenes["targets"] <= 6  # those in coverage in the first minute
    for material in ("test", "scenes", "real_traffic"):
        assert sorted(report["runs"][material]) == sorted(names)
        for name, metrics in report["runs"][material].items():
            assert 0.0 <= metrics["GOSPA"] < math.inf, (material, name)  # GOSPA is no mean: it grows with aircraft
            assert 0.0 <= metrics["probability_of_update"] <= 1.0 and metrics["plots_per_second"] > 0
            causes = sum(metrics[f"GOSPA_missed_{cause}"] for cause in scene_evaluation.MISSED_CAUSES)
            assert causes == pytest.approx(metrics["GOSPA_missed"], rel=1e-5, abs=1e-9)  # the causes add up (to the
            # file's six digits)
        oracle = report["runs"][material]["oracle_reference"]
        assert oracle["false_tracks"] == 0 and oracle["position_rms_m"] < params.scorecard.association_m
        bounds = report["materials"][material]["pcrb_horizontal_rms_m"]
        assert set(bounds) == {"cv", "ca"} and all(0.0 < value < 1000.0 for value in bounds.values())
        judged = report["references"][material]["stone_soup_gnn"]
        assert {row["figures"] for row in judged} == {"single-radar", "multi-radar", "ED-129C"}
    intervals = json.loads((repository / "reports" / "peers_intervals.json").read_text())["test"]
    low, high = intervals["runs"]["kalman_cv_4000"]["GOSPA"]
    assert math.isnan(low) or low <= report["runs"]["test"]["kalman_cv_4000"]["GOSPA"] <= high
    assert set(intervals["paired"]) == set(peers.PAIRED)
    assert set(json.loads((repository / "reports" / "peers_intervals.json").read_text())) == {"test", "scenes"}
    text = (repository / "reports" / "peers.md").read_text()
    assert text.startswith(f"# {peers_tables.TITLE}") and "| stone_soup_jpda |" in text and "ED-129C" in text
    assert "posterior Cramér-Rao bound" in text and "before its first track (m)" in text


@pytest.mark.parametrize("association", ["gnn", "jpda"])
def test_stone_soup_settings_name_the_gate_of_our_trackers(association: str) -> None:
    from pipeline.filters.classical_filters import FilterSettings
    from pipeline.peers.stone_soup import StoneSoupSettings
    params = tf.make_params()
    settings = StoneSoupSettings.from_params(association, params.peers.stone_soup,
                                             FilterSettings("cv", (3.0,), 150.0, 10.0, 0.05, 0.9),
                                             params.tracker.association.kalman_gate_probability)
    assert settings.gate_probability == params.tracker.association.kalman_gate_probability


def test_score_of_a_track_table_is_the_benchs_scorecard(tiny_pipeline, tmp_path) -> None:
    """`track` then `score` on one test scenario give the scorecard the bench gives the same run on the same plots
    (issue 32: the bench scores trackers as `score` scores any tracker's output)."""
    from pipeline.settings import load_params
    from pipeline.surveillance import scorecard
    from tests.project import run_pipeline
    params = load_params(tiny_pipeline / "params.yaml")
    whole = dataclasses.replace(params.peers, window_s=0.0, scenes=0,
                                real_traffic=dataclasses.replace(params.peers.real_traffic, states=""))
    bench = peers.prepare(dataclasses.replace(params, peers=whole), tiny_pipeline / "data" / "simulated",
                          tiny_pipeline / "data" / "routes", tiny_pipeline / "data" / "scenes", tiny_pipeline / "models",
                          tiny_pipeline)
    scenario = bench.recordings[0].scene.scenario_id
    expected = scorecard.combined([peers.evaluate_unit(bench, "kalman_cv_4000", 0).card])
    split = tiny_pipeline / "data" / "simulated" / "test"
    tracked = run_pipeline("track", "--plots", str(split / "plots.parquet"), "--radar", str(split / "radar.parquet"),
                           "--method", "kalman_cv", "--window", "4000", "--out", str(tmp_path / "tracks.parquet"),
                           cwd=tiny_pipeline)
    assert tracked.returncode == 0, tracked.stderr
    scored = run_pipeline("score", "--tracks", str(tmp_path / "tracks.parquet"), "--truth", str(split / "truth.parquet"),
                          "--scenario", str(scenario), "--out", str(tmp_path / "score.json"), cwd=tiny_pipeline)
    assert scored.returncode == 0, scored.stderr
    card = json.loads((tmp_path / "score.json").read_text())["scorecard"]
    assert expected["confirmed_updates"] > 0 and card.keys() == expected.keys()
    for name, value in expected.items():
        if isinstance(value, float) and math.isnan(value):  # JSON has no NaN: written as null
            assert card[name] is None, name
        else:
            assert card[name] == pytest.approx(value, rel=1e-9), name

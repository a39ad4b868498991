"""The fusion section of the comparison report and docs/results.md: every picture best GOSPA first with its interval
and its ratio to the better radar, each method's pair counts, the bias sweep's cells, and the verdicts of the best
fused picture told from the noise by the paired intervals over the scenes."""

from __future__ import annotations

from pipeline.reports import fusion_tables

SHARES = {"localisation": 0.0, "missed": 0.0, "false": 0.0}
FUSION = {
    "scenes": 1, "common_times": 10, "oracle_pairs": 100,
    "gospa_m": {"radar_1": 1000.0, "radar_2": 1500.0, "fused_network": 850.0, "fused_oracle": 800.0},
    "gospa_shares_m": {"radar_1": {"localisation": 400.0, "missed": 500.0, "false": 100.0}, "radar_2": SHARES,
                       "fused_network": SHARES, "fused_oracle": SHARES},
    "track_switches": {"radar_1": 3, "radar_2": 4, "fused_network": 5, "fused_oracle": 2},
    "tracks_per_truth": {"radar_1": 1.1, "radar_2": 1.2, "fused_network": 1.5, "fused_oracle": 1.05},
    "association": {"network": {"accuracy": 0.975, "false_pairs": 2, "missed_pairs": 3}},
    "bias_sweep": {"scenes": 1, "by_bias_m": {
        "200": {"methods": {"network": {"accuracy": 0.96, "false_pairs": 0.01, "missed_pairs": 0.04}}},
        "0": {"methods": {"network": {"accuracy": 0.98, "false_pairs": 0.005, "missed_pairs": 0.02}}}}},
}

SPREAD = {"pictures": {"units": 6, "runs": {"fused_network": {"GOSPA": [820.0, 880.0]}},
                       "paired": {"GOSPA": {"fused_network": {"radar_1": [-190.0, -110.0], "fused_oracle": [-10.0, 110.0],
                                                              "radar_2": [-700.0, -600.0]}}}},
          "association": {"runs": {"network": {"accuracy": [0.96, 0.99]}}}}


def test_pictures_best_first_with_their_ratio_to_the_better_radar():
    rows = fusion_tables.picture_table(FUSION).splitlines()[2:]
    assert [row.split(" | ")[0] for row in rows] == ["| fused, oracle pairs", "| fused, network", "| radar 1 alone",
                                                     "| radar 2 alone"]
    assert rows[1] == "| fused, network | 850 | -15.0 % | 0 | 0 | 0 | 5 | 1.50 |"
    assert rows[2] == "| radar 1 alone | 1000 | +0.0 % | 400 | 500 | 100 | 3 | 1.10 |"
    with_intervals = fusion_tables.picture_table(FUSION, SPREAD).splitlines()[3]
    assert with_intervals == "| fused, network | 850 | [820, 880] | -15.0 % | 0 | 0 | 0 | 5 | 1.50 |"


def test_association_counts_and_the_bias_sweep_cells_in_bias_order():
    assert fusion_tables.association_table(FUSION).splitlines()[2] == "| network | 97.5 % | 2 | 3 |"
    assert fusion_tables.association_table(FUSION, SPREAD).splitlines()[2] == "| network | 97.5 % | [96.0, 99.0] | 2 | 3 |"
    lines = fusion_tables.bias_table(FUSION["bias_sweep"]).splitlines()
    assert lines[0] == "| method | 0 m | 200 m |"
    assert lines[2] == "| network | 98.0 · 0.5 · 2.0 | 96.0 · 1.0 · 4.0 |"
    section = fusion_tables.fusion_section(FUSION, "fusion_bias.png")
    assert section[-1].endswith("(fusion_bias.png)")
    assert len(fusion_tables.fusion_section({k: v for k, v in FUSION.items() if k != "bias_sweep"}, "x.png")) == 4


def test_the_best_fused_picture_wins_only_where_its_paired_interval_excludes_zero():
    """fused_network against the better radar: [-190, -110] excludes 0, a win; against the oracle's pairs
    [-10, 110] holds 0, a tie; no intervals, no verdicts."""
    assert fusion_tables.verdicts(FUSION, SPREAD) == [
        "- fused, network against the better radar alone (radar 1 alone): GOSPA 850 against 1000 m, difference "
        "-150 m, paired 95 % interval over the 6 scenes [-190, -110]: fused, network wins.",
        "- fused, network against the oracle's pairs (fused, oracle pairs): GOSPA 850 against 800 m, difference "
        "+50 m, paired 95 % interval over the 6 scenes [-10, 110]: a tie within the noise."]
    assert fusion_tables.verdicts(FUSION, None) == []
    one_scene = {"pictures": {"units": 1, "runs": {"fused_network": {"GOSPA": [None, None]}},  # JSON's NaN: null
                              "paired": {"GOSPA": {"fused_network": {"radar_1": [None, None]}}}}}
    assert fusion_tables.verdicts(FUSION, one_scene)[0].endswith("over the 1 scenes n/a: a tie within the noise.")
    assert "| 850 | n/a |" in fusion_tables.picture_table(FUSION, one_scene)
    assert fusion_tables.fusion_section(FUSION, "x.png", SPREAD)[1].startswith("- fused, network against")

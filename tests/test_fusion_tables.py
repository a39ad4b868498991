"""The fusion section of the comparison report and docs/results.md: every picture best GOSPA first with its ratio to the
better radar, each method's pair counts, and the bias sweep's cells."""

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


def test_pictures_best_first_with_their_ratio_to_the_better_radar():
    rows = fusion_tables.picture_table(FUSION).splitlines()[2:]
    assert [row.split(" | ")[0] for row in rows] == ["| fused, oracle pairs", "| fused, network", "| radar 1 alone",
                                                     "| radar 2 alone"]
    assert rows[1] == "| fused, network | 850 | -15.0 % | 0 | 0 | 0 | 5 | 1.50 |"
    assert rows[2] == "| radar 1 alone | 1000 | +0.0 % | 400 | 500 | 100 | 3 | 1.10 |"


def test_association_counts_and_the_bias_sweep_cells_in_bias_order():
    assert fusion_tables.association_table(FUSION).splitlines()[2] == "| network | 97.5 % | 2 | 3 |"
    lines = fusion_tables.bias_table(FUSION["bias_sweep"]).splitlines()
    assert lines[0] == "| method | 0 m | 200 m |"
    assert lines[2] == "| network | 98.0 · 0.5 · 2.0 | 96.0 · 1.0 · 4.0 |"
    section = fusion_tables.fusion_section(FUSION, "fusion_bias.png")
    assert section[-1].endswith("(fusion_bias.png)")
    assert len(fusion_tables.fusion_section({k: v for k, v in FUSION.items() if k != "bias_sweep"}, "x.png")) == 4

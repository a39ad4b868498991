"""The peers stage's report as Markdown (`reports/peers.md`, and the comparison's section): per material, every
run's GOSPA and scorecard with the test material's 95 % intervals, the reference figures passed or failed, and the
verdicts between the best of Stone Soup and the best of ours (`reports/peers.json`, `pipeline.bench.peers`)."""

from __future__ import annotations

import math
from collections import Counter
from typing import Mapping

TITLE = "The field's peers on the same plots: Stone Soup, ours and the oracle"
STONE_SOUP = "stone_soup"
REFERENCE = "reference"
COLUMNS = (  # metric, header, format
    ("GOSPA", "GOSPA (m)", "{:.0f}"), ("GOSPA_missed", "missed (m)", "{:.0f}"), ("GOSPA_false", "false (m)", "{:.0f}"),
    ("tracks_per_aircraft", "tracks per aircraft", "{:.2f}"), ("track_swaps", "swaps", "{:.0f}"),
    ("position_rms_m", "position RMS (m)", "{:.0f}"), ("position_error_mean_m", "mean (m)", "{:.0f}"),
    ("position_error_sigma_m", "σ (m)", "{:.0f}"), ("velocity_rms_straight_mps", "velocity RMS straight (m/s)", "{:.1f}"),
    ("straight_within_0_25_nm", "straight ≤ 0.25 NM", "{:.2%}"), ("manoeuvring_within_1_nm", "manoeuvring ≤ 1 NM",
                                                                    "{:.2%}"),
    ("probability_of_update", "probability of update", "{:.3f}"), ("ratio_of_long_gaps", "long gaps", "{:.2%}"),
    ("false_tracks", "false tracks", "{:.0f}"), ("initiation_mean_s", "initiation (s)", "{:.0f}"),
    ("plots_per_second", "plots/s", "{:,.0f}"))
WITH_INTERVAL = ("GOSPA", "position_rms_m", "probability_of_update", "ratio_of_long_gaps")
VERDICTS = (("GOSPA", "GOSPA", True), ("position_rms_m", "position RMS", True),
            ("probability_of_update", "probability of update", False), ("ratio_of_long_gaps", "ratio of long gaps", True))


def as_floats(interval: list[float | None] | None) -> list[float]:
    """An interval as read from JSON (NaN is written there as null) with NaN for null; [NaN, NaN] for none."""
    return [math.nan if value is None else float(value) for value in (interval or [None, None])]


def _shown(value: float | None, form: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return form.format(value)


def _cell(metric: str, form: str, value: float | None, interval: list[float] | None,
          with_interval: tuple[str, ...] = WITH_INTERVAL) -> str:
    text = _shown(value, form)
    if interval is None or metric not in with_interval or not all(math.isfinite(v) for v in as_floats(interval)):
        return text
    return f"{text} [{_shown(interval[0], form)}, {_shown(interval[1], form)}]"


def stone_soup_fastest(runs: Mapping[str, dict], families: Mapping[str, str] | None) -> float | None:
    """The plots/s of Stone Soup's fastest run among `runs` (by `families`), None where none ran."""
    rates = [runs[name]["plots_per_second"] for name in runs if (families or {}).get(name) == STONE_SOUP]
    return max(rates) if rates else None


def material_table(runs: Mapping[str, dict], run_intervals: Mapping[str, dict] | None,
                   families: Mapping[str, str] | None = None) -> str:
    """Every run's row (the COLUMNS some run has: a report without speeds has no plots/s), best GOSPA first; the
    95 % interval beside WITH_INTERVAL where given; and where Stone Soup ran (`families`), each run's plots/s as a
    multiple of Stone Soup's fastest on the same plots."""
    fastest = stone_soup_fastest(runs, families)
    columns = [column for column in COLUMNS if any(values.get(column[0]) is not None for values in runs.values())]
    headers = [header for _, header, _ in columns] + (["× Stone Soup's fastest"] if fastest else [])
    lines = ["| run | " + " | ".join(headers) + " |", "|---" * (len(headers) + 1) + "|"]
    for name in sorted(runs, key=lambda n: runs[n]["GOSPA"]):
        own = (run_intervals or {}).get(name, {})
        cells = [_cell(metric, form, runs[name].get(metric), own.get(metric)) for metric, _, form in columns]
        if fastest:
            cells.append(f"{runs[name]['plots_per_second'] / fastest:,.0f}×")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def speed_line(report: dict, material: str = "test") -> list[str]:
    """Our runs' plots/s on `material` as multiples of Stone Soup's fastest on the same plots, by family (issue
    33's goal: the classical trackers at least 200 times); none where Stone Soup did not run."""
    runs, families = report["runs"].get(material, {}), report["families"]
    fastest = stone_soup_fastest(runs, families)
    if not fastest:
        return []
    told = []
    for family in dict.fromkeys(families[name] for name in runs):
        if family in (STONE_SOUP, REFERENCE):
            continue
        ratios = sorted(runs[name]["plots_per_second"] / fastest for name in runs if families[name] == family)
        told.append(f"{family} {ratios[0]:,.0f}×" if len(ratios) == 1 else f"{family} {ratios[0]:,.0f}-{ratios[-1]:,.0f}×")
    return [f"- speed (plots/s on the same plots, tracking alone, one core): Stone Soup's fastest {fastest:,.0f}; "
            f"ours {', '.join(told)} as many (issue 33's goal for the classical trackers: 200×)."]


MISSED_COLUMNS = (("GOSPA_missed", "missed (m)"), ("GOSPA_missed_undetected", "no plot of it (m)"),
                  ("GOSPA_missed_initiation", "before its first track (m)"),
                  ("GOSPA_missed_after_track", "after a track (m)"))
FALSE_COLUMNS = (("GOSPA_false", "false (m)"), ("GOSPA_false_clutter", "clutter tracks (m)"),
                 ("GOSPA_false_duplicate", "second tracks of an aircraft (m)"),
                 ("GOSPA_false_astray", "tracks astray (m)"))


def cause_table(runs: Mapping[str, dict], run_intervals: Mapping[str, dict] | None,
                columns: tuple[tuple[str, str], ...] = MISSED_COLUMNS) -> str | None:
    """A GOSPA part and its split by cause (`columns`: MISSED_COLUMNS, `scene_evaluation.missed_causes`, or
    FALSE_COLUMNS, `scene_evaluation.false_causes`), smallest part first, with the 95 % intervals where given;
    None for a report made before the split."""
    if not all(metric in values for values in runs.values() for metric, _ in columns):
        return None
    names = tuple(metric for metric, _ in columns)
    lines = ["| run | " + " | ".join(header for _, header in columns) + " |", "|---" * (len(names) + 1) + "|"]
    for name in sorted(runs, key=lambda n: runs[n][names[0]]):
        own = (run_intervals or {}).get(name, {})
        lines.append(f"| {name} | " + " | ".join(_cell(metric, "{:.0f}", runs[name][metric], own.get(metric), names)
                                                 for metric in names) + " |")
    return "\n".join(lines)


MISSED_INTRO = ("Where the missed metres are lost: each aircraft-scan a run misses (no confirmed track within the "
                "cutoff) split by why, its share of the scan's missed part in metres: no plot of the aircraft in "
                "the scan (the radar's misses: no tracker can do better without coasting), a plot but no track of the "
                "aircraft yet (the scans its track management takes to confirm), a plot and the aircraft had a track "
                "before (a track lost, deleted or swapped away, or the plot refused by the gate).")
FALSE_INTRO = ("What the false metres are: each confirmed estimate no aircraft is assigned split by what its track "
               "is (its aircraft: the most of its confirmed plots'), its share of the scan's false part in metres: a "
               "clutter track (most of its plots false), a second track of an aircraft another track holds in the "
               "scan, a track astray (its aircraft held by no track in the scan: the track too far off it).")


FIGURES = {"single-radar": "ECAC single-radar", "multi-radar": "ECAC multi-radar", "ED-129C": "ED-129C"}
INDICATORS = {"position_error_mean_m": "mean", "position_error_sigma_m": "σ",
              "straight_within_0_25_nm": "straight ≤ 0.25 NM", "manoeuvring_within_1_nm": "manoeuvring ≤ 1 NM",
              "ratio_of_long_gaps": "long gaps"}


def references_table(references: Mapping[str, list[dict]]) -> str:
    """Each run against each reference figure (ECAC single- and multi-radar, ED-129C): pass or fail."""
    first = next(iter(references.values()))
    header = [f"{FIGURES.get(row['figures'], row['figures'])}: {INDICATORS.get(row['indicator'], row['indicator'])} "
              f"{'≤' if row['at_most'] else '≥'} {_figure(row)}" for row in first]
    lines = ["| run | " + " | ".join(header) + " | passed |", "|---" * (len(header) + 2) + "|"]
    for name, rows in references.items():
        verdicts = [{True: "pass", False: "**fail**", None: "n/a"}[row["passes"]] for row in rows]
        lines.append(f"| {name} | " + " | ".join(verdicts) + f" | {verdicts.count('pass')} of {len(rows)} |")
    sources = list(dict.fromkeys(row["source"].split(":")[0] for row in first))
    return "\n".join(lines) + "\n\nSources: " + "; ".join(sources) + " (`pipeline/surveillance/scorecard.py`)."


def _figure(row: dict) -> str:
    value = row["reference"]
    return f"{value:.2%}" if row["indicator"] in INDICATORS and not row["indicator"].endswith("_m") else f"{value:.0f} m"


def best(runs: Mapping[str, dict], families: Mapping[str, str], stone_soup: bool) -> str | None:
    """The run of lowest GOSPA among Stone Soup's (`stone_soup`) or among ours (no reference)."""
    chosen = [name for name in runs if (families[name] == STONE_SOUP) == stone_soup and families[name] != REFERENCE]
    return min(chosen, key=lambda name: runs[name]["GOSPA"]) if chosen else None


def verdicts(report: dict, intervals: dict, material: str = "test") -> list[str]:
    """The best of ours against the best of Stone Soup on `material` (one with intervals: the test scenarios or
    the scenes), each metric of VERDICTS with the paired 95 % interval of the difference (ours minus Stone
    Soup's): a win only when the interval excludes 0."""
    runs, families = report["runs"].get(material, {}), report["families"]
    ours, theirs = best(runs, families, False), best(runs, families, True)
    if ours is None or theirs is None:
        return []
    paired = intervals.get(material, {}).get("paired", {})
    lines = []
    for metric, label, lower_better in VERDICTS:
        mine, their = as_floats([runs[ours].get(metric), runs[theirs].get(metric)])  # JSON's null: NaN
        difference = mine - their
        low, high = as_floats(paired.get(metric, {}).get(ours, {}).get(theirs))
        if not (math.isfinite(low) and math.isfinite(high)) or low <= 0.0 <= high:
            outcome = "a tie within the noise"
        else:
            outcome = f"{ours if (difference < 0) == lower_better else theirs} wins"
        lines.append(f"- {label}: {ours} {mine:.4g} against {theirs} {their:.4g}, "
                     f"difference {difference:+.4g}, paired 95 % interval [{low:.4g}, {high:.4g}]: {outcome}.")
    return lines


def bound_line(material: dict) -> list[str]:
    """The limit beside the position RMS column: the PCRB's horizontal RMS under each tuned model (none in a
    report made before it)."""
    bounds = material.get("pcrb_horizontal_rms_m")
    if not bounds:
        return []
    told = ", ".join(f"{_shown(value, '{:.0f}')} m under the tuned {kind.upper()} model" for kind, value in bounds.items())
    return [f"The limit beside the position RMS column: the posterior Cramér-Rao bound's horizontal RMS over every "
            f"in-coverage scan, {told} (`pipeline/surveillance/pcrb.py`: the bound of trackers that assume that "
            "model; the runs' RMS is over their confirmed updates alone)."]


def materials_intro(report: dict) -> str:
    """What each material holds (`reports/peers.json`'s materials)."""
    parts = []
    test = report["materials"].get("test")
    if test:
        kinds = Counter(test["strategies"].values())
        each = "-".join(str(n) for n in sorted(set(kinds.values())))
        parts.append(f"**Test scenarios**: {len(test['recordings'])} scenarios of the {test['split']} split (the first "
                     f"{each} of each of {len(kinds)} route strategies), each its first {test['window_s'] / 60:.0f} minutes "
                     f"({test['plots']['target']:,} target and {test['plots']['false']:,} false plots), one aircraft "
                     "each; intervals resample the scenarios.")
    scenes = report["materials"].get("scenes")
    if scenes:
        parts.append(f"**Many-aircraft scenes**: the first {len(scenes['recordings'])} scenes of the scenes stage "
                     f"({', '.join(str(n) for n in scenes['aircraft'].values())} aircraft each, crossings and a "
                     f"formation among them), each its first {scenes['window_s'] / 60:.0f} minutes "
                     f"({scenes['plots']['target']:,} target and {scenes['plots']['false']:,} false plots, "
                     f"{scenes['targets']} aircraft seen); intervals resample the scenes.")
    real = report["materials"].get("real_traffic")
    if real:
        parts.append(f"**Real traffic**: {real['targets']} aircraft tracks of OpenSky's recording ({real['states']}) "
                     f"past our radar at {real['site']['latitude_deg']:g}°, {real['site']['longitude_deg']:g}° "
                     f"({real['plots']['target']:,} target and {real['plots']['false']:,} false plots), one scene: no "
                     "interval.")
    return " ".join(parts)


INTRO = ("Every run tracks the same plots (`dvc repro peers`, `pipeline/bench/peers.py`): Stone Soup's GNN and JPDA "
         "set up as its tutorials set them up on our tuned CV model and our chi-square gate "
         "(`pipeline/peers/stone_soup.py`), our runs of `peers.runs`, and the oracle (the tuned IMM given each "
         "plot's aircraft). Scored on the confirmed updates: GOSPA (as the scenes) and the surveillance scorecard "
         "(`pipeline/surveillance/scorecard.py`: EUROCAE ED-129C's probability of update and ratio of long gaps, the "
         "ECAC guidelines' position error figures, velocity, false tracks, swaps, initiation time). plots/s: tracking "
         "alone, one core.")


def section(report: dict, intervals: dict, heading: str = "###") -> list[str]:
    """The report's blocks: intro, verdicts, then per material its table and the reference figures."""
    blocks = [INTRO, materials_intro(report)]
    for material, title in (("test", "test scenarios"), ("scenes", "many-aircraft scenes")):
        lines = verdicts(report, intervals, material)
        if lines:
            blocks += [f"{heading} Who wins: the best of ours against the best of Stone Soup ({title})",
                       "\n".join(lines)]
    for material, title in (("test", "Test scenarios"), ("scenes", "Many-aircraft scenes"),
                            ("real_traffic", "Real traffic")):
        if material in report["runs"]:
            runs_intervals = intervals.get(material, {}).get("runs")
            missed = cause_table(report["runs"][material], runs_intervals, MISSED_COLUMNS)
            false = cause_table(report["runs"][material], runs_intervals, FALSE_COLUMNS)
            blocks += [f"{heading} {title}", material_table(report["runs"][material], runs_intervals, report["families"]),
                       *speed_line(report, material),
                       *bound_line(report["materials"][material]),
                       *([MISSED_INTRO, missed] if missed else []), *([FALSE_INTRO, false] if false else []),
                       f"{heading} {title}: the reference figures", references_table(report["references"][material])]
    return blocks


def report_markdown(report: dict, intervals: dict) -> str:
    """`reports/peers.md`."""
    return "\n\n".join([f"# {TITLE}", "Generated by `dvc repro peers` from `reports/peers.json` and "
                        "`reports/peers_intervals.json`.", *section(report, intervals, "##")]) + "\n"

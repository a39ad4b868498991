"""The comparison's tables and sentences in Markdown, from the numbers `compare` gathers
(`reports/comparison.json`): the tracker table, continuity, GOSPA, the scenes, the sites, the
hold-out and tuning tables, and the plain-sentence verdict. The `compare` stage writes them to
`reports/comparison.md`, the `readme` stage into docs/results.md (and its verdict into the README). The tables of runs read each run's
record with its metrics (`pipeline.bench.runs`: its method, window, rule, family; a report's names
looked up among params' runs), and show its name.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from pipeline.bench.intervals import within_noise
from pipeline.bench.runs import Run
from pipeline.reports import peers_tables, site_report
from pipeline.surveillance import scorecard
from pipeline.tracker import registry

ORACLE = "oracle"  # the reference whose gap to the best tracker the verdict states

TRACKER_METRICS = ("OSPA", "OSPA_p90", "MAE", "ROCA", "tracks_per_aircraft", "NOMT", "NOFPA", "ANEES",
                   "plots_per_second")

GOSPA_METRICS = ("GOSPA", "GOSPA_localisation", "GOSPA_missed", "GOSPA_false", "track_switches", "tracks_per_truth",
                 "track_purity")

CARD_METRICS = (*scorecard.INDICATORS, *scorecard.COUNTS)  # the surveillance scorecard's, where a report has them
SCORECARD_TITLE = "Surveillance scorecard"

SCENE_METRICS = ("GOSPA", "GOSPA_localisation", "GOSPA_missed", "GOSPA_false", "track_switches", "fragmentation",
                 "tracks_per_truth", "track_purity", "plots_per_second")

MAE_MIN_ROCA = 0.9  # MAE counts confirmed associations only: a tracker that keeps few plots can look precise

FILTER_LABELS = {"cv": "Kalman CV", "ca": "Kalman CA", "imm": "IMM (CV + CA)", "imm_ct": "IMM (CV + turns)",
                 "imm_ca_ct": "IMM (CV + CA + turns)"}

SITES_INTRO = ("The same routes (same seeds: the same manoeuvres in the radar's east-north frame, the same radar "
               "noise and clutter) flown past a radar at each site of `evaluate.sites` (`dvc repro evaluate_sites`, "
               "`reports/site_metrics.json`). Per tracker: its position error (MAE) at the training site, and at "
               "each other site the MAE and its ratio to the training site's; **off**: more than "
               f"{site_report.TOLERANCE:.0%} away.")

GRADIENT_LABELS = {"cv": "Kalman CV", "ca": "Kalman CA", "singer": "Singer", "imm": "IMM (CV + CA)"}

SCALED_TITLE = "Learned estimators against filters tuned by gradient descent and by Nelder-Mead"

SCALED_INTRO = (
    "The network-scaled Kalman filter (issue 17, seed 003: a small network scales Q, R and Singer's manoeuvre "
    "frequency at each step, `pipeline/learning/kalman_net.py`), the LSTM update on a CA Kalman prediction (issue 18, "
    "seed 001: an LSTM cell in place of the measurement update, its covariance from Monte-Carlo dropout, "
    "`pipeline/learning/lstm_update.py`, `dvc repro train_lstm_update`), the same torch filters with Q, an R scale and the "
    "initial spreads tuned by gradient descent on the same loss, data and truncation (`pipeline/filters/gradient_tuning.py`; "
    "`dvc repro train_kalman_net`; the learned ones trained without the hold-out segments), and the Nelder-Mead tuned "
    "filters (`tune_kalman`, tuned on the whole train split, hold-out included), on the hold-out windows of the table "
    "above: each filter started at a window's first plot, scored at its last (`pipeline/learning/filter_holdout.py`). "
    "Turns: the windows of lowest truth linearity (share `lstm_update.turn_share`), straight: the rest. "
    "NEES: the position error's e' P^-1 e with the filter's own covariance, 3 if it tells the truth; **in**: the "
    "ANEES inside its chi-square 95 % bounds. Within x % of range: the share of windows whose error is at most x % of "
    "the target's true range (seed 001's accuracy measure).")



def estimator_table(detailed: dict) -> str:
    """The hold-out's `filter_holdout.detailed_scores` of every estimator, best mean error first."""
    forms = (("mean_error_m", "{:.1f}"), ("rmse_m", "{:.1f}"), ("p95_error_m", "{:.1f}"), ("turn_mean_error_m", "{:.1f}"),
             ("straight_mean_error_m", "{:.1f}"))
    shares = list(next(iter(detailed["filters"].values()))["within_range_share"])
    low, high = next(iter(detailed["filters"].values()))["anees_bounds"]
    lines = ["| estimator | mean error (m) | RMSE (m) | 95th percentile (m) | turns (m) | straight (m) | "
             f"ANEES (95 % bounds {low:.2f}-{high:.2f}) | " + " | ".join(f"within {float(share):.1%} of range"
                                                                       for share in shares) + " |",
             "|---" * (7 + len(shares)) + "|"]
    for name, values in sorted(detailed["filters"].items(), key=lambda item: item[1]["mean_error_m"]):
        lines.append(f"| {name} | " + " | ".join(form.format(values[key]) for key, form in forms)
                     + f" | {values['anees']:.2f}{' in' if values['anees_inside'] else ''} | "
                     + " | ".join(f"{values['within_range_share'][share]:.1%}" for share in shares) + " |")
    return "\n".join(lines)



def scaled_filter_tables(detailed: dict, result: dict) -> list[str]:
    """The hold-out scores (`estimator_table`) and the mean error against the noise factor, as two tables."""
    factors = result["noise_factors"]
    noise = ["| filter | " + " | ".join(f"noise x {f:g} (m)" for f in factors) + " |", "|---" * (len(factors) + 1) + "|"]
    for name, errors in result["mean_error_by_noise_m"].items():
        noise.append(f"| {name} | " + " | ".join(f"{e:.1f}" for e in errors) + " |")
    return [estimator_table(detailed),
            "Mean error with the hold-out plots measured again from the truth, the radar's sigmas times each factor "
            "(unknown to every filter, which keeps the nominal R; one draw per factor, seed "
            "`kalman_net.noise_seed`):", "\n".join(noise), "![Mean error against the noise factor](noise_scales.png)"]



def scaled_verdict(result: dict) -> list[str]:
    """Each learned estimator's (network-scaled filter, LSTM update) hold-out mean error against the
    best gradient-tuned and the best Nelder-Mead tuned filter (issue 17's goal: 10 % below the former
    and below the latter; issue 18's: below the tuned CA and IMM)."""
    errors = {name: values["mean_error_m"] for name, values in result["filters"].items()}
    sentences = []
    for learned in (name for name in errors if name.startswith("network-scaled") or name == "LSTM update"):
        for method in ("gradient-tuned", "Nelder-Mead tuned"):
            group = [name for name in errors if name.endswith(method)]
            if group:
                best = min(group, key=errors.get)
                change = errors[learned] / errors[best] - 1.0
                sentences.append(f"- Hold-out filtering, {learned} filter {errors[learned]:.1f} m against the best "
                                 f"{method} filter ({best}) {errors[best]:.1f} m: {abs(change):.1%} "
                                 f"{'below' if change < 0 else 'above'}.")
    return sentences



def _cell(value: float | None, form: str) -> str:
    return "n/a" if value is None or not np.isfinite(value) else form.format(value)



def by_ospa(runs: Mapping[Run, dict]) -> list[Run]:
    """The runs, best (lowest) OSPA first; runs without one last."""
    return sorted(runs, key=lambda r: runs[r].get("OSPA") if runs[r].get("OSPA") is not None else np.inf)



def sites_section(sites: dict, runs: Mapping[Run, dict], report: dict | None = None) -> list[str]:
    """The verdict on the radar sites and the table of the runs scored there (those of `runs`
    that `sites` has, best OSPA first), and with the sites' report (`reports/site_metrics.json`) their scorecard
    at every site (`site_scorecards`); nothing when there are no sites besides the training one."""
    if len(sites["sites"]) < 2:
        return []
    scored = [run for run in by_ospa(runs) if run.name in sites["runs"]]  # evaluate.site_runs and the references
    neural = [run.name for run in scored if run.family == registry.NEURAL]
    return [site_report.site_sentence(sites, neural), site_report.site_table(sites, [run.name for run in scored]),
            *site_scorecards(report or {}, [run.name for run in scored])]



CONTINUITY_INTRO = (
    "How many pieces each aircraft's track falls into (confirmed tracks that followed it, per route: "
    "`pipeline/bench/tracker_metrics.py`) and the share of its plots in confirmed tracks (ROCA), over all test "
    "routes and by route strategy; each cell is tracks per aircraft · ROCA. Runs named `_m_of_n` are tracked "
    "and scored under M-of-N confirmation and time-out deletion, the others under the thesis's weights "
    "(`tracker.management.rule`). The oracle's figure is the floor the routes allow: an aircraft that leaves "
    "coverage and comes back is two tracks even with the true association.")



INITIATION_TITLE = "Track initiation"
INITIATION_PICTURE = "initiation.png"


def initiation_intro(hours: float) -> str:
    return ("How long an aircraft waits for its first confirmed update against how many false tracks a rule lets "
            "through, for every run under each track management rule (the thesis's weights, or M of N with "
            "time-out deletion for the runs named `_m_of_n`; `tracker.management.rule`). Initiation time: from "
            "the start of an aircraft's first stretch in coverage to its first confirmed update, mean and 95th "
            "percentile over the aircraft (the scorecard's, `pipeline/surveillance/scorecard.py`); false tracks: "
            "confirmed tracks on no aircraft, per hour of the test routes' flying time "
            f"({hours:.1f} h per draw, `reports/data.json`). Faster at fewer false tracks is better: down and left "
            "in the picture; each line joins one method's two rules.")


def initiation_rows(runs: Mapping[Run, dict], default_rule: str, hours: float) -> list[tuple[Run, str, float, float,
                                                                                            float]]:
    """(run, rule, initiation mean s, its 95th percentile s, false tracks per hour) of every tracker run
    with an initiation time (the raw plots' reference is no tracker), fastest first."""
    rows = [(run, run.management or default_rule, values["initiation_mean_s"], values["initiation_p95_s"],
             values["false_tracks"] / hours)
            for run, values in runs.items() if run.method != "plots" and values.get("initiation_mean_s") is not None]
    return sorted(rows, key=lambda row: (row[2], row[4], row[0].name))


def initiation_table(rows: list[tuple[Run, str, float, float, float]], intervals: dict | None = None,
                     hours: float = 1.0) -> str:
    """The rows of `initiation_rows` as a table; with the report's `intervals` (`tracker_intervals.json`'s), a run
    under another rule than its method's run under the default rule (same method and window, no `management`)
    also gets the paired 95 % intervals of the differences to that run: initiation time (s) and false tracks per
    hour (the per-draw count's interval over `hours`), so "faster at equal false tracks" is read beyond the noise."""
    names = {(run.method, run.window_m): run.name for run, *_ in rows if not run.reference and not run.management}
    lines = ["| tracker | rule | initiation mean (s) | initiation 95th percentile (s) | false tracks per hour | "
             "initiation against the default rule (s) | false tracks per hour against it |", "|---" * 7 + "|"]
    for run, rule, mean, p95, per_hour in rows:
        base = names.get((run.method, run.window_m)) if run.management else None
        start, false = (_paired(intervals, "initiation_mean_s", run.name, base),
                        _paired(intervals, "false_tracks", run.name, base)) if base else (None, None)
        lines.append(f"| {run.name} | {rule} | {mean:.1f} | {p95:.0f} | {per_hour:.2f} | {_interval(start)} | "
                     f"{_interval(false, hours)} |")
    return "\n".join(lines)


def _interval(pair: list[float] | None, scale: float = 1.0) -> str:
    """A paired interval as "[low, high]" (divided by `scale`), "–" where there is none."""
    if pair is None or not all(np.isfinite(pair)):
        return "–"
    return f"[{pair[0] / scale:+.2f}, {pair[1] / scale:+.2f}]"


def continuity_table(runs: Mapping[Run, dict], by_strategy: dict[str, dict]) -> str:
    """Tracks per aircraft and ROCA of every run (references first, then by method, window and
    rule, so a run under both rules is two adjacent rows), over all routes and per strategy
    (`by_strategy`, by run name as the report has it)."""
    strategies = list(next(iter(by_strategy.values()), {}))
    order = list(registry.METHODS)

    def position(run: Run) -> tuple:
        if run.reference:
            return (-1, 0.0, "", run.name)
        return (order.index(run.method) if run.method in order else len(order), run.window_m, run.management or "",
                run.name)

    def cell(values: dict) -> str:
        return f"{_cell(values.get('tracks_per_aircraft'), '{:.2f}')} · {_cell(values.get('ROCA'), '{:.3f}')}"

    lines = ["| tracker | all routes | " + " | ".join(strategies) + " |", "|---" * (len(strategies) + 2) + "|"]
    for run in sorted(runs, key=position):
        lines.append(f"| {run.name} | {cell(runs[run])} | "
                     + " | ".join(cell(by_strategy.get(run.name, {}).get(s, {})) for s in strategies) + " |")
    return "\n".join(lines)



def tracker_table(runs: Mapping[Run, dict]) -> str:
    forms = {"OSPA": "{:.0f}", "OSPA_p90": "{:.0f}", "MAE": "{:.0f}", "ROCA": "{:.3f}", "tracks_per_aircraft": "{:.2f}",
             "NOMT": "{:.2f}", "NOFPA": "{:.0f}",
             "ANEES": "{:.2f}", "plots_per_second": "{:,.0f}"}
    header = ["tracker", "OSPA (m)", "OSPA, 90 % of scans below (m)", "MAE (m)", "ROCA", "aircraft tracks per route", "NOMT",
              "NOFPA", "ANEES (3 = consistent)", "plots/s"]
    lines = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
    for run in by_ospa(runs):
        values = runs[run]
        lines.append(f"| {run.name} | " + " | ".join(_cell(values.get(m), forms[m]) for m in TRACKER_METRICS) + " |")
    return "\n".join(lines)



GOSPA_INTRO = (
    "GOSPA (α = 2, `pipeline/bench/gospa.py`) on the same sets of each scan as OSPA: a missed aircraft or a false "
    "track costs c/2^(1/p), not c, and nothing is divided by the number of aircraft. Its parts are each scan's "
    "GOSPA split in proportion to the localisation, missed and false terms (before the root), so the three add "
    "up to GOSPA. A track switch is an aircraft's assigned confirmed track changing to another (a scan without "
    "one in between is no reset), summed over routes; tracks assigned per aircraft are the distinct confirmed "
    "tracks ever assigned to it; purity is the share of a confirmed track's assigned scans on its most frequent "
    "aircraft, averaged over tracks.")



def gospa_table(runs: Mapping[Run, dict]) -> str:
    """GOSPA and its parts, switches, tracks per truth and purity of the runs that have them (reports
    before GOSPA have none: then no table), best GOSPA first."""
    scored = {run: values for run, values in runs.items() if values.get("GOSPA") is not None}
    if not scored:
        return ""
    forms = {"GOSPA": "{:.0f}", "GOSPA_localisation": "{:.0f}", "GOSPA_missed": "{:.0f}", "GOSPA_false": "{:.0f}",
             "track_switches": "{:.0f}", "tracks_per_truth": "{:.2f}", "track_purity": "{:.3f}"}
    header = ["tracker", "GOSPA (m)", "localisation (m)", "missed (m)", "false (m)", "track switches",
              "tracks assigned per aircraft", "track purity"]
    lines = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
    for run in sorted(scored, key=lambda r: scored[r]["GOSPA"]):
        lines.append(f"| {run.name} | " + " | ".join(_cell(scored[run].get(m), forms[m]) for m in GOSPA_METRICS)
                     + " |")
    return "\n".join(lines)



SCENES_TITLE = "Many aircraft: GOSPA and its parts, switches"



def scenes_intro(scenes: dict, cutoff_m: float, order: float) -> str:
    """What the scenes table scores, with the scenes' size (`reports/scene_metrics.json`)."""
    return (f"{scenes['scenes']} scenes of {scenes['aircraft_per_scene']} aircraft, {scenes['duration_s'] / 60:.0f} "
            f"minutes each ({scenes['plots']['target']:,} target and {scenes['plots']['false']:,} false plots; "
            "`pipeline/simulation/scenes.py`: in every scene two routes crossing at one altitude at 10-30°, a formation of 2-4 "
            "aircraft 0.5-3 km apart that splits, aircraft entering and leaving coverage, the others on the route "
            "strategies), tracked whole by every run of `evaluate.scene_runs` and the oracle (`dvc repro "
            "evaluate_scenes`). GOSPA per scan over the aircraft in coverage (cutoff "
            f"{cutoff_m:.0f} m, order {order:g}) with its parts, means over all scans; track switches summed over all "
            "aircraft, an aircraft keeping its track while it stays within the cutoff (CLEAR MOT's rule, "
            "`pipeline/bench/gospa.py`); fragmentation: the tracks assigned to an aircraft beyond the first, per "
            "aircraft; purity per confirmed track; plots/s: tracking alone, one core. Best GOSPA first; "
            f"`reports/scene_example.png`: scene {scenes['example']['scene']} tracked by {scenes['example']['run']}.")



def scenes_table(runs: Mapping[Run, dict]) -> str:
    """GOSPA and its parts, switches, fragmentation, tracks per truth, purity and speed of every run on
    the scenes, best GOSPA first."""
    forms = {"GOSPA": "{:.0f}", "GOSPA_localisation": "{:.0f}", "GOSPA_missed": "{:.0f}", "GOSPA_false": "{:.0f}",
             "track_switches": "{:.0f}", "fragmentation": "{:.2f}", "tracks_per_truth": "{:.2f}",
             "track_purity": "{:.3f}", "plots_per_second": "{:,.0f}"}
    header = ["tracker", "GOSPA (m)", "localisation (m)", "missed (m)", "false (m)", "track switches",
              "fragmentation", "tracks assigned per aircraft", "track purity", "plots/s"]
    lines = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
    for run in sorted(runs, key=lambda r: runs[r]["GOSPA"]):
        lines.append(f"| {run.name} | " + " | ".join(_cell(runs[run].get(m), forms[m]) for m in SCENE_METRICS) + " |")
    return "\n".join(lines)



def _numbers(values: Mapping[str, float | None]) -> dict[str, float]:
    """Metrics as read from JSON, null (a NaN written) back to NaN."""
    return {name: float("nan") if value is None else value for name, value in values.items()}


def scorecard_blocks(runs: Mapping[str, dict], run_intervals: Mapping[str, dict] | None, material: str,
                     bounds: Mapping[str, float] | None = None) -> list[str]:
    """The surveillance scorecard of every run on `material` (words: "the scenes") with the reference figures it
    passes, by run name, with the 95 % intervals where given and the PCRB's horizontal RMS by model (`bounds`,
    `peers_tables.bound_line`) where given; nothing for a report made before it."""
    if not runs or not all("probability_of_update" in values for values in runs.values()):
        return []
    return [f"The surveillance scorecard on {material} (`pipeline/surveillance/scorecard.py`: EUROCAE ED-129C's "
            "probability of update and ratio of long gaps, the ECAC guidelines' position error figures, velocity, "
            f"false tracks, swaps, initiation time; counts per draw of {material}), best GOSPA first:",
            peers_tables.material_table(runs, run_intervals),
            *peers_tables.bound_line({"pcrb_horizontal_rms_m": bounds}),
            f"Each run against the reference figures on {material}:",
            peers_tables.references_table({name: scorecard.judged(_numbers(values)) for name, values in runs.items()})]


def site_scorecards(report: dict, order: list[str]) -> list[str]:
    """The scorecard of the runs in `order` at each radar site but the training one (`reports/site_metrics.json`
    as `evaluate_sites` writes it), with the bound there; nothing for a report made before them."""
    blocks = []
    for site in report.get("sites", []):
        runs = {name: site["runs"][name] for name in order if name in site["runs"]}
        blocks += scorecard_blocks(runs, None, f"the {report['split']} routes at site {site['name']}",
                                   site.get("pcrb_horizontal_rms_m"))
    return blocks


def scenes_detail(runs: Mapping[str, dict], run_intervals: Mapping[str, dict] | None) -> list[str]:
    """The scenes' GOSPA missed and false parts by cause (`scene_evaluation.missed_causes`, `false_causes`) and the
    surveillance scorecard of every run with the reference figures it passes (`scorecard_blocks`), by run name,
    with the 95 % intervals over the scenes where given; nothing for a report made before them."""
    blocks = []
    for intro, columns in ((peers_tables.MISSED_INTRO, peers_tables.MISSED_COLUMNS),
                           (peers_tables.FALSE_INTRO, peers_tables.FALSE_COLUMNS)):
        table = peers_tables.cause_table(runs, run_intervals, columns)
        blocks += [intro, table] if table else []
    return blocks + scorecard_blocks(runs, run_intervals, "the scenes")


def holdout_table(holdout: dict) -> str:
    """The `holdout` part of comparison.json as a table."""
    lines = ["| estimator | filter: error of the last plot's estimate (m) | predictor: error of the next state (m) |",
             "|---|---|---|",
             f"| raw plot | {holdout['raw_plot_error_m']:.1f} | |",
             f"| linear extrapolation | | {holdout['linear_extrapolation_error_m']:.1f} |",
             f"| networks (filter, predictor) | {holdout['network_filter_error_m']:.1f} | "
             f"{holdout['network_prediction_error_m']:.1f} |"]
    for kind, label in FILTER_LABELS.items():
        if kind in holdout["filter_error_m"]:
            lines.append(f"| {label}, tuned | {holdout['filter_error_m'][kind]:.1f} | "
                         f"{holdout['prediction_error_m'][kind]:.1f} |")
    return "\n".join(lines)



def tuning_table(tuning: dict) -> str:
    lines = [f"| filter | process noise | velocity spread (m/s) | model switch probability | turn rate (deg/s) | "
             f"{tuning['cost']} before | after | RMSE (m) | raw plots RMSE (m) | ANEES | ANEES 95 % bounds | "
             "NEES in chi-square 95 % | target plots outside the gate |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for kind, values in tuning["filters"].items():
        after = values["after"]
        switching = f"{values['switch_probability']:.3g}" if len(values["noise_std"]) > 1 else "-"
        turning = f"{values['turn_rate_dps']:.3g}" if values.get("turn_rate_dps") else "-"
        lines.append(
            f"| {FILTER_LABELS[kind]} | {', '.join(f'{v:.3g}' for v in values['noise_std'])} | "
            f"{values['velocity_std_mps']:.0f} | {switching} | {turning} | {values['cost_before']:.4g} | "
            f"{values['cost_after']:.4g} | "
            f"{after['rmse_m']:.1f} | {after['plot_rmse_m']:.1f} | {after['anees']:.3f} | "
            f"{after['anees_bounds'][0]:.3f}-{after['anees_bounds'][1]:.3f} | {after['nees_in_95_interval']:.3f} | "
            f"{after['gate_misses']:.2%} (gate allows {after['gate_allowance']:.1%}) |")
    return "\n".join(lines)



def _paired(intervals: dict | None, metric: str, a: str, b: str) -> list[float] | None:
    """The paired interval of `a` minus `b` on `metric`, where the report has one."""
    if intervals is None:
        return None
    return intervals.get("paired", {}).get(metric, {}).get(a, {}).get(b)


def _outcome(intervals: dict | None, metric: str, n: str, c: str, winner: str) -> str:
    """'**winner** wins' with the paired interval of n - c that backs it, or a tie where it holds 0
    (`pipeline.bench.intervals`); without intervals (reports before them) the bare verdict."""
    pair = _paired(intervals, metric, n, c)
    if pair is None:
        return f"**{winner}** wins."
    if not all(np.isfinite(pair)):
        return f"**{winner}** wins (no interval: too few scenarios to tell the noise)."
    interval = f"paired {intervals['level']:.0%} interval of {n} − {c}: [{pair[0]:.4g}, {pair[1]:.4g}]"
    if within_noise(pair):
        return f"**a tie within the noise** ({interval} holds 0)."
    return f"**{winner}** wins ({interval})."


def verdict(runs: Mapping[Run, dict], holdout: dict, intervals: dict | None = None) -> list[str]:
    """Plain sentences on who wins what, from the numbers; with `intervals` (the evaluation's
    `tracker_intervals.json`) every win is backed by its paired interval, and a difference whose
    interval holds 0 is called a tie."""
    trackers = {run.name: values for run, values in runs.items() if not run.reference}
    families = {name: {run.name: v for run, v in runs.items() if not run.reference and registry.group(run.method) == name}
                for name in registry.GROUPS}
    oracle_run = next((run for run in runs if run.reference and run.method == ORACLE), None)
    oracle = runs[oracle_run] if oracle_run is not None else None
    sentences = []

    def best(group: dict, metric: str, low: bool = True) -> str:
        return min(group, key=lambda n: group[n][metric] if low else -group[n][metric])

    kept = {name: {k: v for k, v in members.items() if v["ROCA"] >= MAE_MIN_ROCA} for name, members in families.items()}
    for metric, low, what, among, unit in (
            ("OSPA", True, "OSPA", families, ""),
            ("ROCA", False, "share of target plots in confirmed tracks (ROCA)", families, ""),
            ("MAE", True, f"position error (MAE) among trackers keeping at least {MAE_MIN_ROCA:.0%} of the target "
                          "plots", kept, " m")):
        bests = {name: best(members, metric, low) for name, members in among.items() if members}
        if len(bests) < 2:
            continue
        ranked = sorted(bests.values(), key=lambda n: trackers[n][metric] if low else -trackers[n][metric])
        winner, runner_up = ranked[0], ranked[1]
        listed = "; ".join(f"{name} {run} {trackers[run][metric]:.4g}{unit}" for name, run in bests.items())
        sentences.append(f"- {what}: best of {listed}. Best against the next family's best: "
                         f"{_outcome(intervals, metric, winner, runner_up, winner)}")
    if oracle is not None and trackers:
        top = best(trackers, "OSPA")
        gap = _paired(intervals, "OSPA", top, oracle_run.name)
        backed = "" if gap is None else (f" (paired {intervals['level']:.0%} interval of the OSPA gap: "
                                         f"[{gap[0]:.4g}, {gap[1]:.4g}])")
        sentences.append(f"- True association (oracle, tuned IMM) reaches OSPA {oracle['OSPA']:.4g} "
                         f"and MAE {oracle['MAE']:.4g} m against the best tracker's "
                         f"{trackers[top]['OSPA']:.4g} and {trackers[top]['MAE']:.4g} m ({top}){backed}: the gap is "
                         "what association costs.")
    if holdout["filter_error_m"]:
        kind = min(holdout["filter_error_m"], key=holdout["filter_error_m"].get)
        sentences.append(f"- Hold-out filtering: the filter network {holdout['network_filter_error_m']:.1f} m, the "
                         f"best tuned filter ({FILTER_LABELS[kind]}) {holdout['filter_error_m'][kind]:.1f} m.")
        kind = min(holdout["prediction_error_m"], key=holdout["prediction_error_m"].get)
        sentences.append(f"- Hold-out prediction: the predictor network {holdout['network_prediction_error_m']:.1f} "
                         f"m, the best tuned filter ({FILTER_LABELS[kind]}) "
                         f"{holdout['prediction_error_m'][kind]:.1f} m.")
    return sentences


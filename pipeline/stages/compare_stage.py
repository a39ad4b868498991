"""Stage `compare`: one report of every tracker, neural and classical, and of the networks
against the tuned Kalman filters on the hold-out windows.

Trackers: the evaluate stage's metrics (`reports/tracker_metrics.json`), one row each, best
first by OSPA, and GOSPA with its parts and the identity metrics (`pipeline.bench.gospa`), best first
by GOSPA; on the multi-target scenes, GOSPA with its parts, switches and fragmentation
(`reports/scene_metrics.json`, `pipeline.bench.scene_evaluation`); and each one's position error at
the other radar sites against the training site's (`reports/site_metrics.json`,
`pipeline.reports.site_report`). Two radars: their tracks associated and fused, the fused picture against each radar alone and the oracle
association (`reports/fusion.json` with its intervals, `pipeline.reports.fusion_tables`). Hold-out: the windows the
networks were scored on (`reports/models.json`), run through each tuned filter
(`models/kalman_tuned.json`):
- filter: the estimate of each window's last plot, the filters fed the window's plots with
  their converted-measurement covariance;
- predictor: the next true state, the filters fed the window's true states (measurement
  sigma `training.kalman_truth_sigma_m`), then predicted to the next state's time.
The learned estimators (the network-scaled filter, issue 17; the LSTM update, issue 18) and the
gradient- and Nelder-Mead tuned filters in one table on the same hold-out windows
(`filter_holdout.compare_detailed`: error, turns against straight flight, ANEES and its bounds,
the share within a share of the range), the LSTM update's MC-dropout masks drawn from
`lstm_update.seed` as in its own stage, so its row repeats `reports/lstm_update.json`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pipeline import io
from pipeline.bench.runs import declared_runs, with_records
from pipeline.filters import batch_filters, torch_filters
from pipeline.filters.classical_filters import FilterSettings, load_settings
from pipeline.filters.gradient_tuning import TunedFilter
from pipeline.filters.torch_filters import FilterSpec
from pipeline.geometry import geodesy
from pipeline.learning import filter_holdout, materials, model_eval, windows
from pipeline.learning.kinds import KINDS
from pipeline.learning.scaling import STATE_FEATURES
from pipeline.params import Params
from pipeline.reports import figures, fusion_tables, peers_tables, site_report
from pipeline.reports.comparison_tables import (
    CARD_METRICS,
    CONTINUITY_INTRO,
    FILTER_LABELS,
    GOSPA_INTRO,
    GOSPA_METRICS,
    GRADIENT_LABELS,
    INITIATION_PICTURE,
    INITIATION_TITLE,
    SCALED_INTRO,
    SCALED_TITLE,
    SCENES_TITLE,
    SCORECARD_TITLE,
    SITES_INTRO,
    TRACKER_METRICS,
    continuity_table,
    gospa_table,
    holdout_table,
    initiation_intro,
    initiation_rows,
    initiation_table,
    scaled_filter_tables,
    scaled_verdict,
    scenes_detail,
    scenes_intro,
    scenes_table,
    scorecard_blocks,
    sites_section,
    tracker_table,
    tuning_table,
    verdict,
)


def _filtered(settings: FilterSettings, times: np.ndarray, positions: np.ndarray, covariances: np.ndarray
              ) -> batch_filters.FilteredSequences:
    valid = np.ones(times.shape, dtype=bool)
    restart = np.zeros(times.shape, dtype=bool)
    restart[:, 0] = True
    return batch_filters.filter_sequences(settings, times, positions, covariances, valid, restart)



def holdout_comparison(holdout: windows.TargetPlots, filters: dict[str, FilterSettings], params: Params) -> dict:
    """Mean position error (m) of each tuned filter on the networks' hold-out windows."""
    length = params.windows.filter_length
    starts = windows.window_starts(holdout.segment_id, length)
    raw = windows.gather(holdout.plot_features(), starts, length)
    truth = windows.gather(holdout.true_features(), starts, length)[:, -1, 1:4]
    positions = raw[:, :, 1:4]
    covariances = geodesy.measurement_covariance(positions.reshape(-1, 3), params.radar).reshape(
        *positions.shape[:2], 3, 3)
    filtered = {kind: np.linalg.norm(_filtered(settings, raw[:, :, 0], positions, covariances).position[:, -1] - truth,
                                     axis=1).mean() for kind, settings in filters.items()}

    inputs = params.windows.predictor_inputs
    starts = windows.window_starts(holdout.segment_id, inputs + 1)
    states = windows.state_features(holdout.true_features(), starts, inputs + 1)
    position = [STATE_FEATURES.index(a) for a in "xyz"]
    given, target = states[:, :inputs], states[:, -1]
    sigma = np.broadcast_to(params.training.kalman_truth_sigma_m ** 2 * np.eye(3), (*given.shape[:2], 3, 3))
    predicted = {}
    for kind, settings in filters.items():
        state = _filtered(settings, given[:, :, 0], given[:, :, position], sigma).last
        forecast, _ = batch_filters.predict_positions(settings, state, target[:, 0] - given[:, -1, 0])
        predicted[kind] = np.linalg.norm(forecast - target[:, position], axis=1).mean()
    return {"filter_windows": int(len(raw)), "predictor_windows": int(len(given)),
            "filter_error_m": {kind: float(v) for kind, v in filtered.items()},
            "prediction_error_m": {kind: float(v) for kind, v in predicted.items()}}



def scaled_filters(models_dir: Path, tuned: dict[str, FilterSettings], params: Params
                   ) -> dict[str, filter_holdout.FilterRun]:
    """The LSTM update (first: its dropout masks are the first drawn, as in its stage), the network-scaled
    filter, each gradient-tuned filter and each Nelder-Mead tuned one the torch filters have, by label. The
    IMMs with turns are left out: the torch filters (the gradient tuner's and the noise-scale comparison's,
    `pipeline.filters.torch_filters`) have no turning model; the hold-out comparison of the NumPy filters
    (`holdout_comparison`) has them."""
    estimator = KINDS["lstm_update"].load_from(models_dir, params)
    network = KINDS["kalman_net"].load_from(models_dir, params)
    gradient = _read_json(models_dir / "kalman_gradient.json", "train_kalman_net")
    runs: dict[str, filter_holdout.FilterRun] = {"LSTM update": estimator,
                                                 f"network-scaled {network.config.base}": network}
    for kind, values in gradient.items():
        runs[f"{GRADIENT_LABELS[kind]}, gradient-tuned"] = TunedFilter.from_dict(values)
    for kind, settings in tuned.items():
        if kind not in torch_filters.MODELS:
            continue
        spec = FilterSpec.from_settings(settings)
        runs[f"{FILTER_LABELS[kind]}, Nelder-Mead tuned"] = lambda batch, spec=spec: batch.filtered(spec)
    return runs



def _read_json(path: Path, stage: str) -> dict:
    if not path.is_file():
        raise io.InputError(f"{path}: file not found (run `dvc repro {stage}`)")
    return io.read_metrics(path)



def run_compare(params: Params, windows_dir: Path, models_dir: Path, reports_dir: Path) -> None:
    declared = declared_runs(params)
    tracker = _read_json(reports_dir / "tracker_metrics.json", "evaluate")
    site_metrics = _read_json(reports_dir / "site_metrics.json", "evaluate_sites")
    sites = site_report.site_comparison(site_metrics)
    scenes = _read_json(reports_dir / "scene_metrics.json", "evaluate_scenes")
    intervals = {"trackers": _read_json(reports_dir / "tracker_intervals.json", "evaluate"),
                 "scenes": _read_json(reports_dir / "scene_intervals.json", "evaluate_scenes"),
                 "fusion": _read_json(reports_dir / "fusion_intervals.json", "fusion")}
    fusion = _read_json(reports_dir / "fusion.json", "fusion")
    peers = {"report": _read_json(reports_dir / "peers.json", "peers"),
             "intervals": _read_json(reports_dir / "peers_intervals.json", "peers")}
    networks = _read_json(reports_dir / "models.json", "models_report")
    tuning = _read_json(reports_dir / "kalman_tuning.json", "tune_kalman")
    filters = load_settings(models_dir / "kalman_tuned.json")
    holdout_path = windows_dir / "holdout.parquet"
    holdout = model_eval.holdout_plots(io.read_parquet(holdout_path, materials.HOLDOUT_SCHEMA), params.radar)
    held = holdout_comparison(holdout, filters, params)
    for kind, key in (("filter", "filter_windows"), ("predictor", "predictor_windows")):
        if networks[kind]["holdout_windows"] != held[key]:
            raise io.InputError(f"{holdout_path}: {held[key]} {kind} windows, but reports/models.json scored the "
                                f"{kind} network on {networks[kind]['holdout_windows']}; rerun the train stages")
    estimators = scaled_filters(models_dir, filters, params)
    u = params.lstm_update
    torch.manual_seed(u.seed)  # the LSTM update's dropout masks, as in its stage
    detailed = filter_holdout.compare_detailed(holdout, params.radar, params.windows.filter_length, estimators,
                                               u.turn_share, u.range_shares)
    scaled = filter_holdout.compare(holdout, params.radar, params.windows.filter_length, estimators,
                                    params.kalman_net.noise_scales, params.kalman_net.noise_seed)
    runs = with_records(tracker["runs"], declared, reports_dir / "tracker_metrics.json")
    comparison = {"trackers": {run.name: {m: values.get(m) for m in TRACKER_METRICS + GOSPA_METRICS
                                          + tuple(m for m in CARD_METRICS if m in values)}
                               for run, values in runs.items()},
                  "holdout": {**held, "raw_plot_error_m": networks["filter"]["raw_plot_error_m"],
                              "linear_extrapolation_error_m": networks["predictor"]["linear_extrapolation_error_m"],
                              "network_filter_error_m": networks["filter"]["filter_error_m"],
                              "network_prediction_error_m": networks["predictor"]["predictor_error_m"]},
                  "tuning": {kind: {"cost_before": v["cost_before"], "cost_after": v["cost_after"]}
                             for kind, v in tuning["filters"].items()},
                  "sites": sites, "by_strategy": tracker.get("by_strategy", {}), "scaled_filters": scaled,
                  "holdout_estimators": detailed,
                  "scenes": {**{key: scenes[key] for key in ("scenes", "aircraft_per_scene", "duration_s", "plots",
                                                             "example")},
                             "runs": scenes["runs"]},
                  "fusion": fusion, "intervals": intervals, "peers": peers,
                  "pcrb_horizontal_rms_m": tracker.get("pcrb_horizontal_rms_m")}
    site_part = sites_section(sites, runs, site_metrics)
    gospa_part = gospa_table(runs)
    hours = _read_json(reports_dir / "data.json", "data_report")[params.evaluate.split]["flight_hours"]
    initiation = initiation_rows(runs, params.tracker.management.rule, hours)
    card_part = scorecard_blocks(comparison["trackers"], intervals["trackers"].get("runs"),
                                 f"the {params.evaluate.split} routes", comparison["pcrb_horizontal_rms_m"])
    text = "\n\n".join([
        f"# Neural and classical trackers on the same {params.evaluate.split} scenarios",
        "Generated by `dvc repro compare` (`python -m pipeline compare`) from `reports/tracker_metrics.json`, "
        "`reports/models.json` and `reports/kalman_tuning.json`; every number comes from `dvc repro`.",
        "## Who wins", "\n".join(verdict(runs, comparison["holdout"], intervals["trackers"]) + scaled_verdict(detailed)),
        f"## Trackers ({len(runs)} runs, best OSPA first)",
        f"Same plots, track management and metrics for all. OSPA: cutoff {params.evaluate.ospa_cutoff_m:.0f} m, "
        f"order {params.evaluate.ospa_order:g}, mean over scans and its 90th percentile (see `pipeline/bench/ospa.py`). ANEES only for trackers "
        "with a covariance. `plots_reference`: the raw target plots with the true association; "
        "`oracle_reference`: the tuned IMM with the true association. plots/s: tracking alone, one core, "
        "this machine.",
        tracker_table(runs), "![OSPA, MAE and ROCA of every tracker](comparison.png)",
        "![OSPA per scan: the share of scans at or below each value](ospa_per_scan.png)",
        "## Track continuity", CONTINUITY_INTRO, continuity_table(runs, comparison["by_strategy"]),
        *(["## GOSPA and its parts", f"{GOSPA_INTRO} Cutoff {params.evaluate.gospa_cutoff_m:.0f} m, order "
            f"{params.evaluate.gospa_order:g}; best GOSPA first.", gospa_part] if gospa_part else []),
        *([f"## {SCORECARD_TITLE}", *card_part] if card_part else []),
        f"## {INITIATION_TITLE}", initiation_intro(hours), initiation_table(initiation, intervals["trackers"], hours),
        f"![Initiation time against false tracks per hour]({INITIATION_PICTURE})",
        f"## {SCENES_TITLE}", scenes_intro(comparison["scenes"], params.evaluate.gospa_cutoff_m,
                                           params.evaluate.gospa_order),
        scenes_table(with_records(comparison["scenes"]["runs"], declared, reports_dir / "scene_metrics.json")),
        "![A busy scene: tracks by identity, switches marked]"
                                                   "(scene_example.png)",
        *scenes_detail(scenes["runs"], intervals["scenes"].get("runs")),
        *(["## Radar sites", SITES_INTRO, *site_part] if site_part else []),
        f"## {fusion_tables.TITLE}", *fusion_tables.fusion_section(fusion, "fusion_bias.png", intervals["fusion"]),
        f"## {peers_tables.TITLE}", *peers_tables.section(peers["report"], peers["intervals"]),
        "## Networks against the tuned filters on the hold-out windows", holdout_table(comparison["holdout"]),
        f"## {SCALED_TITLE}", SCALED_INTRO, *scaled_filter_tables(detailed, scaled),
        f"## Tuning (on the {tuning['split']} split's target plots, cost {tuning['cost']})", tuning_table(tuning),
    ]) + "\n"
    picture = figures.comparison_picture(runs, intervals["trackers"]["runs"])
    noise_picture = figures.noise_scale_picture(scaled)
    io.write_metrics(comparison, reports_dir / "comparison.json")
    io.write_text(text, reports_dir / "comparison.md")
    io.write_bytes(picture, reports_dir / "comparison.png")
    io.write_bytes(noise_picture, reports_dir / "noise_scales.png")
    io.write_bytes(figures.initiation_picture(initiation), reports_dir / INITIATION_PICTURE)


"""Command line: `python -m pipeline <command> --help`. Each DVC stage is one command."""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
from datetime import date
from pathlib import Path

from pipeline.association.registry import NAMES as ASSOCIATION_METHODS
from pipeline.bench.engine import SchedulerUnreachable
from pipeline.filters.tuning import TuningError
from pipeline.io import InputError, TrainingDiverged
from pipeline.learning.experiment_tracking import TrackingError
from pipeline.params import ParamError
from pipeline.settings import load_params
from pipeline.simulation.routes import RouteGenerationError
from pipeline.stages.train_stage import TRAINED
from pipeline.tracker.registry import CLASSICAL, MANAGEMENT, METHODS, TRACKERS, UnknownMethod

log = logging.getLogger("pipeline")


def _routes(args: argparse.Namespace) -> None:
    from pipeline.stages.routes_stage import run_routes
    run_routes(load_params(args.params), Path(args.out))


def _simulate(args: argparse.Namespace) -> None:
    from pipeline.stages.simulate_stage import run_simulate
    run_simulate(load_params(args.params), Path(args.routes), Path(args.out))


def _scenes(args: argparse.Namespace) -> None:
    from pipeline.stages.scenes_stage import run_scenes
    run_scenes(load_params(args.params), Path(args.out))


def _data_report(args: argparse.Namespace) -> None:
    from pipeline.stages.data_report_stage import run_data_report
    run_data_report(load_params(args.params), Path(args.routes), Path(args.simulated), Path(args.out))


def _windows(args: argparse.Namespace) -> None:
    from pipeline.stages.windows_stage import run_windows
    run_windows(load_params(args.params), Path(args.simulated), Path(args.out), Path(args.reports))


def _train(args: argparse.Namespace) -> None:
    from pipeline.learning.recipe import Folders
    from pipeline.stages.train_stage import run_train
    given = {name: Path(getattr(args, name)) for name in ("simulated", "windows", "models", "reports")
             if hasattr(args, name)}
    run_train(load_params(args.params), args.kind, Folders(**given))


def _models_report(args: argparse.Namespace) -> None:
    from pipeline.stages.train_stage import run_models_report
    run_models_report(Path(args.reports))


def _tune_kalman(args: argparse.Namespace) -> None:
    from pipeline.stages.tune_stage import run_tune
    run_tune(load_params(args.params), Path(args.simulated), Path(args.models), Path(args.reports))


def _fusion(args: argparse.Namespace) -> None:
    from pipeline.stages.fusion_stage import run_fusion
    run_fusion(load_params(args.params), Path(args.models), Path(args.reports))


def _compare(args: argparse.Namespace) -> None:
    from pipeline.stages.compare_stage import run_compare
    run_compare(load_params(args.params), Path(args.windows), Path(args.models), Path(args.reports))


def _evaluate(args: argparse.Namespace) -> None:
    from pipeline.stages.evaluate_stage import run_evaluate
    run_evaluate(load_params(args.params), Path(args.simulated), Path(args.routes), Path(args.models),
                 Path(args.reports))


def _evaluate_sites(args: argparse.Namespace) -> None:
    from pipeline.stages.evaluate_sites_stage import run_evaluate_sites
    run_evaluate_sites(load_params(args.params), Path(args.models), Path(args.reports))


def _peers(args: argparse.Namespace) -> None:
    from pipeline.stages.peers_stage import run_peers
    run_peers(load_params(args.params), Path(args.simulated), Path(args.routes), Path(args.scenes), Path(args.models),
              Path(args.reports))


def _evaluate_scenes(args: argparse.Namespace) -> None:
    from pipeline.stages.evaluate_scenes_stage import run_evaluate_scenes
    run_evaluate_scenes(load_params(args.params), Path(args.scenes), Path(args.models), Path(args.reports))


def _track(args: argparse.Namespace) -> None:
    from pipeline.stages.track_command import SystemTrackOutput, run_track
    run_track(load_params(args.params), Path(args.plots) if args.plots else None,
              Path(args.radar) if args.radar else None, [Path(p) for p in args.asterix or []],
              args.date, args.method, args.window, Path(args.models),
              Path(args.out), args.management, args.confirmed_only,
              SystemTrackOutput(Path(args.cat062), args.sac, args.sic) if args.cat062 else None)


def _score(args: argparse.Namespace) -> None:
    from pipeline.stages.score_command import run_score
    run_score(load_params(args.params), Path(args.tracks) if args.tracks else None,
              Path(args.cat062) if args.cat062 else None, args.date, tuple(args.reference) if args.reference else None,
              Path(args.truth), args.scenario, args.update_interval, Path(args.out))


def _real_traffic(args: argparse.Namespace) -> None:
    from pipeline.stages.real_traffic_command import run_real_traffic
    run_real_traffic(load_params(args.params), Path(args.states), args.latitude, args.longitude, args.height,
                     Path(args.out))


def _associate(args: argparse.Namespace) -> None:
    from pipeline.stages.associate_command import run_associate
    run_associate(load_params(args.params), [Path(p) for p in args.tracks], [Path(p) for p in args.radar],
                  args.method, Path(args.models), Path(args.pairs), Path(args.fused))


def _asterix_export(args: argparse.Namespace) -> None:
    from pipeline.stages.track_command import export_asterix
    export_asterix(Path(args.plots), Path(args.radar), args.scenario, Path(args.out))


def _readme(args: argparse.Namespace) -> int:
    from pipeline.bench.runs import declared_runs
    from pipeline.reports.readme import update_documents
    changed = update_documents(Path(args.readme), Path(args.docs), Path(args.reports), Path(args.package),
                               declared_runs(load_params(args.params)), check=args.check)
    if args.check and changed:
        log.error("%s: generated sections are out of date; run `python -m pipeline readme`",
                  ", ".join(map(str, changed)))
        return 1
    return 0


def _plots_template(args: argparse.Namespace) -> None:
    from pipeline.reports.plots_page import write_template
    write_template(Path(args.out))


def _params_reference(args: argparse.Namespace) -> int:
    from pipeline.reports.params_reference import write_reference
    load_params(args.params)  # a reference is written of valid params only
    if write_reference(Path(args.params), Path(args.out), check=args.check) and args.check:
        log.error("%s: out of date with the params declarations; run `python -m pipeline params-reference`",
                  args.out)
        return 1
    return 0


DEFAULT_METHOD = "imm_gnn"  # `track`'s method unless --method: see its help

FOLDERS = {  # option -> (default, what it is)
    "routes": ("data/routes", "routes folder"),
    "simulated": ("data/simulated", "simulated data folder"),
    "scenes": ("data/scenes", "multi-target scenes folder"),
    "windows": ("data/windows", "windows folder"),
    "models": ("models", "models folder"),
    "reports": ("reports", "reports folder"),
    "docs": ("docs", "documentation folder (results.md, speed.md, architecture.md hold generated sections)"),
    "package": ("pipeline", "the package whose layout docs/architecture.md lists"),
}

# name -> (handler, summary, example, input/output options; "out" is given as ("out", default), the piece a
# command trains as ("kind", name))
COMMANDS = {
    "routes": (_routes, "Simulate aircraft routes (truth) for every split.",
               "python -m pipeline routes --params params.yaml --out data/routes",
               ["params", ("out", "data/routes")]),
    "simulate": (_simulate, "Run the rotating radar over the routes: plots, per-scan truth, radar description.",
                 "python -m pipeline simulate --params params.yaml --routes data/routes --out data/simulated",
                 ["params", "routes", ("out", "data/simulated")]),
    "scenes": (_scenes, "Simulate the multi-target scenes (crossings, formations, aircraft entering and leaving "
               "coverage): routes, plots, per-scan truth, radar description.",
               "python -m pipeline scenes --params params.yaml --out data/scenes", ["params", ("out", "data/scenes")]),
    "data-report": (_data_report, "Metrics (data.json) and pictures of the simulated data.",
                    "python -m pipeline data-report --routes data/routes --simulated data/simulated --out reports",
                    ["params", "routes", "simulated", ("out", "reports")]),
    "windows": (_windows, "Cut the simulated plots into balanced, scaled training windows and a hold-out.",
                "python -m pipeline windows --simulated data/simulated --out data/windows --reports reports",
                ["params", "simulated", ("out", "data/windows"), "reports"]),
    "train": (_train, "Train one piece (the thesis's filter, predictor or autoencoder network, or any trained piece: "
              f"{', '.join(TRAINED)}), evaluate it, log an MLflow run.",
              "python -m pipeline train --kind predictor --windows data/windows --models models --reports reports",
              ["params", "kind", "simulated", "windows", "models", "reports"]),
    "models-report": (_models_report, "Merge the networks' hold-out metrics into reports/models.json.",
                      "python -m pipeline models-report --reports reports", ["reports"]),
    "tune-kalman": (_tune_kalman, "Tune the classical CV, CA and IMM filters on a split's target plots "
                    "(scipy Nelder-Mead); writes models/kalman_tuned.json.",
                    "python -m pipeline tune-kalman --simulated data/simulated --models models --reports reports",
                    ["params", "simulated", "models", "reports"]),
    "train-kalman-net": (_train, "Train the network-scaled Kalman filter and the gradient-tuned CV, CA, "
                         "Singer and IMM filters on a split's target plots (Lightning, one MLflow run).",
                         "python -m pipeline train-kalman-net --simulated data/simulated --windows data/windows "
                         "--models models --reports reports",
                         ["params", ("kind", "kalman_net"), "simulated", "windows", "models", "reports"]),
    "train-confirmation": (_train, "Train the learned track confirmation's network on the candidate tracks (aircraft "
                           "and clutter) a classical tracker makes on a split's plots, and set its threshold's "
                           "clutter sums on held-out scenarios (Lightning, one MLflow run).",
                           "python -m pipeline train-confirmation --simulated data/simulated --models models "
                           "--reports reports",
                           ["params", ("kind", "confirmation"), "simulated", "models", "reports"]),
    "train-association": (_train, "Train the seed's track-to-track association network on freshly "
                          "simulated two-radar scenes and score it with the statistical, double-threshold and "
                          "bias-robust methods against the bias (Lightning, one MLflow run).",
                          "python -m pipeline train-association --models models --reports reports",
                          ["params", ("kind", "association_net"), "models", "reports"]),
    "train-lstm-update": (_train, "Train the LSTM update on a CA Kalman prediction with its MC-dropout "
                          "covariance and score it on the hold-out against the tuned CA and IMM (Lightning, one "
                          "MLflow run).",
                          "python -m pipeline train-lstm-update --simulated data/simulated --windows data/windows "
                          "--models models --reports reports",
                          ["params", ("kind", "lstm_update"), "simulated", "windows", "models", "reports"]),
    "fusion": (_fusion, "Two radars of params fusion: the multi-target scenes seen by both, each tracked alone, their "
               "tracks associated by every method and fused; GOSPA of each picture (reports/fusion.json).",
               "python -m pipeline fusion --models models --reports reports", ["params", "models", "reports"]),
    "compare": (_compare, "The comparison report: every tracker (neural, classical, references) and the networks "
                "against the tuned Kalman filters on the hold-out.",
                "python -m pipeline compare --windows data/windows --models models --reports reports",
                ["params", "windows", "models", "reports"]),
    "evaluate": (_evaluate, "Run the tracker with every method and window of params over the test scenarios.",
                 "python -m pipeline evaluate --simulated data/simulated --routes data/routes --models models",
                 ["params", "simulated", "routes", "models", "reports"]),
    "evaluate-sites": (_evaluate_sites, "Fly the evaluated routes past a radar at each of evaluate.sites and score "
                       "the runs of evaluate.site_runs (all of evaluate.runs when []) and the references there "
                       "(reports/site_metrics.json; the training site's row from evaluate's).",
                       "python -m pipeline evaluate-sites --models models --reports reports",
                       ["params", "models", "reports"]),
    "evaluate-scenes": (_evaluate_scenes, "Track the multi-target scenes with every run of evaluate.scene_runs and "
                        "the oracle; GOSPA and its parts, track switches (reports/scene_metrics.json) and a picture "
                        "of the busiest scene (reports/scene_example.png).",
                        "python -m pipeline evaluate-scenes --scenes data/scenes --models models --reports reports",
                        ["params", "scenes", "models", "reports"]),
    "peers": (_peers, "The field's peers on the same plots: Stone Soup's GNN and JPDA, our runs of peers.runs and the "
              "oracle on test scenarios, many-aircraft scenes and a real-traffic scene, scored by GOSPA and the "
              "surveillance scorecard beside the ECAC and ED-129C figures, with intervals (reports/peers.json, "
              "reports/peers.md).",
              "python -m pipeline peers --simulated data/simulated --routes data/routes --scenes data/scenes "
              "--models models --reports reports", ["params", "simulated", "routes", "scenes", "models", "reports"]),
    "track": (_track, "Track a recording (Parquet plots + radar description, or ASTERIX CAT048/CAT034) with the "
              "trained networks; writes one row per track update.",
              "python -m pipeline track --plots data/simulated/test/plots.parquet "
              "--radar data/simulated/test/radar.parquet --method via --window 4000 --out tracks.parquet\n"
              "  python -m pipeline track --asterix scenario_0.ast --date 2026-06-01 --management m_of_n --out tracks.parquet\n"
              "  python -m pipeline track --asterix scenario_0.ast --date 2026-06-01 --out tracks.parquet --cat062 tracks.ast",
              ["params", "recording", "models"]),
    "score": (_score, "The surveillance scorecard (probability of update, long gaps, position and velocity errors, "
              "large-error shares, false and extra tracks, swaps, initiation) of a tracker's output, our update table "
              "or ASTERIX CAT062, against a truth table, beside the ECAC and ED-129C reference figures.",
              "python -m pipeline score --tracks tracks.parquet --truth data/simulated/test/truth.parquet "
              "--out scorecard.json\n"
              "  python -m pipeline score --cat062 tracks.ast --date 2026-06-01 --reference 60.1 24.9 "
              "--truth truth.parquet --scenario 5 --out scorecard.json",
              ["params", "scoring"]),
    "real-traffic": (_real_traffic, "Fly real aircraft (OpenSky state vectors; the project ships 84 over the UK) past "
                     "params' radar moved to a site: plots, per-scan truth and radar description, for `track` and "
                     "`score`.",
                     "python -m pipeline real-traffic --out data/real_traffic\n"
                     "  python -m pipeline track --plots data/real_traffic/plots.parquet "
                     "--radar data/real_traffic/radar.parquet --out real_tracks.parquet\n"
                     "  python -m pipeline score --tracks real_tracks.parquet --truth data/real_traffic/truth.parquet "
                     "--out real_score.json",
                     ["params", "real_traffic"]),
    "associate": (_associate, "Associate two users' track tables (what `track` writes, classical methods: they give "
                  "covariances) at common times and fuse the pairs by covariance intersection; writes the pairs "
                  "and the fused air picture (Parquet).",
                  "python -m pipeline associate --tracks north.parquet south.parquet "
                  "--radar north_radar.parquet south_radar.parquet --method bias_robust "
                  "--pairs pairs.parquet --fused fused.parquet",
                  ["params", "association", "models"]),
    "asterix-export": (_asterix_export, "Write one simulated scenario as an ASTERIX CAT034 + CAT048 recording.",
                       "python -m pipeline asterix-export --plots data/simulated/test/plots.parquet "
                       "--radar data/simulated/test/radar.parquet --scenario 0 --out scenario_0.ast",
                       ["export"]),
    "readme": (_readme, "Regenerate the generated sections of the README and docs/: the results from reports/, "
               "the layout from the package's folders and docstrings.",
               "python -m pipeline readme --check", ["params", "readme", "docs", "reports", "package", "check"]),
    "params-reference": (_params_reference, "Write docs/params.md from the params declarations "
                         "(pipeline/params/): every key's type, bounds, value in params.yaml and doc.",
                         "python -m pipeline params-reference --out docs/params.md --check",
                         ["params", "reference"]),
    "plots-template": (_plots_template, "Write the HTML template `dvc plots show` reads (.dvc/config's "
                       "plots.html_template): Vega, Vega-Lite and Vega-Embed inline, so the page needs no network "
                       "(the file is committed; rerun after upgrading vl-convert-python).",
                       "python -m pipeline plots-template --out .dvc/plots/offline.html",
                       [("out", ".dvc/plots/offline.html")]),
}


def _iso_date(text: str) -> date:
    """--date checked where it is parsed, so a wrong date is a usage error (exit 2), not a traceback."""
    try:
        return date.fromisoformat(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"{text!r} is not a date (YYYY-MM-DD): {error}") from None


def _positive(text: str, what: str) -> float:
    """A finite number above 0 parsed from an option, else a usage error (exit 2) saying it is not `what`."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}")
    return value


def _window_m(text: str) -> float:
    """--window checked where it is parsed: a radius of 0, below 0, NaN or infinity would run (no plot, or every
    plot, within it) and give tracks of nothing, so it is a usage error (exit 2)."""
    return _positive(text, "a window: a finite distance above 0 in metres")


def _interval_s(text: str) -> float:
    """--update-interval checked where it is parsed: a finite time above 0."""
    return _positive(text, "an update interval: a finite time above 0 in seconds")


def _add_option(command: argparse.ArgumentParser, option: str | tuple[str, str]) -> None:
    if isinstance(option, tuple) and option[0] == "kind":
        command.set_defaults(kind=option[1])  # a command that trains one piece
    elif isinstance(option, tuple):
        command.add_argument("--out", default=option[1], help="output folder (default: %(default)s)")
    elif option == "params":
        command.add_argument("--params", default="params.yaml", help="params file (default: %(default)s)")
    elif option == "kind":
        command.add_argument("--kind", required=True, choices=tuple(TRAINED), help="which piece")
    elif option == "recording":
        command.add_argument("--plots", help="plots Parquet (the schema `simulate` writes; truth columns optional)")
        command.add_argument("--radar", help="radar description Parquet (radar_id, latitude_deg, longitude_deg, "
                                             "height_m; optionally scan_period_s), one row per radar; with "
                                             "--asterix it supplies or overrides the CAT034 radar positions")
        command.add_argument("--asterix", action="append", help="ASTERIX CAT048 + CAT034 file (repeatable)")
        command.add_argument("--date", type=_iso_date, help="UTC date of the first ASTERIX record, YYYY-MM-DD")
        command.add_argument("--method", default=DEFAULT_METHOD, choices=TRACKERS,
                             help="tracking method (default: %(default)s, the tuned IMM with global nearest neighbour: "
                                  "the best tracker on the project's many-aircraft scenes (GOSPA), a metre of OSPA from "
                                  "the best on single aircraft, and among the fastest; reports/comparison.md); the "
                                  "classical ones ("
                                  + ", ".join(name for name in TRACKERS if METHODS[name].family == CLASSICAL)
                                  + ") need only models/kalman_tuned.json, the others the trained networks")
        command.add_argument("--window", type=_window_m, default=4000.0,
                             help="association window in metres (default: %(default)s)")
        command.add_argument("--management", choices=MANAGEMENT,
                             help="track management rule (default: params' tracker.management.rule): thesis "
                                  "deletes a track not yet confirmed at its first silence (two missed scans), m_of_n "
                                  "confirms at M hits of N scans and deletes a confirmed track after "
                                  "tracker.management.delete_after_s, sprt runs the sequential probability ratio "
                                  "test on hits and misses, learned weighs each hit of M of N by the confirmation "
                                  "network (models/confirmation.pt, `dvc repro train_confirmation`)")
        command.add_argument("--out", required=True, help="output Parquet, one row per track update")
        command.add_argument("--confirmed-only", action="store_true",
                             help="write only the updates of confirmed tracks (the summary still counts every "
                                  "update by status)")
        command.add_argument("--cat062", help="also write the updates as ASTERIX CAT062 system tracks to this file "
                                              "(I062/100 about the first radar's site; see docs/tracking-a-recording.md)")
        command.add_argument("--sac", type=int, default=0, help="with --cat062: the tracker's SAC, I062/010 "
                                                                "(default: %(default)s)")
        command.add_argument("--sic", type=int, default=1, help="with --cat062: the tracker's SIC, I062/010 "
                                                                "(default: %(default)s)")
    elif option == "scoring":
        command.add_argument("--tracks", help="our update table (Parquet, what `track` writes)")
        command.add_argument("--cat062", help="or ASTERIX CAT062 system tracks (ours or another tracker's)")
        command.add_argument("--date", type=_iso_date, help="with --cat062: UTC date of its first record, YYYY-MM-DD")
        command.add_argument("--reference", type=float, nargs=2, metavar=("LAT", "LON"),
                             help="with --cat062: its system reference point (deg), for its velocities (I062/185); "
                                  "`track --cat062` logs it")
        command.add_argument("--truth", required=True, help="truth Parquet: target_id, time_unix_s, x/y/z_ecef_m "
                                                            "(optionally scenario_id, in_coverage)")
        command.add_argument("--scenario", type=int, help="score this scenario only (default: every scenario)")
        command.add_argument("--update-interval", type=_interval_s,
                             help="the radar's update interval, s (default: 60 / params' radar.rotation_rpm)")
        command.add_argument("--out", required=True, help="output JSON (and Markdown beside it, <stem>.md)")
    elif option == "real_traffic":
        command.add_argument("--states", default="external/opensky/plane_states_2021-07-12.csv",
                             help="OpenSky state-vector CSV (default: %(default)s, credited in its folder)")
        command.add_argument("--latitude", type=float, default=52.5, help="radar site latitude, deg (default: "
                                                                          "%(default)s, central England)")
        command.add_argument("--longitude", type=float, default=-1.5, help="radar site longitude, deg (default: "
                                                                           "%(default)s)")
        command.add_argument("--height", type=float, default=100.0, help="antenna height above WGS-84, m (default: "
                                                                         "%(default)s)")
        command.add_argument("--out", default="data/real_traffic", help="output folder (default: %(default)s)")
    elif option == "association":
        command.add_argument("--tracks", nargs=2, required=True, metavar=("FIRST", "SECOND"),
                             help="the two users' track tables (Parquet, the schema `track` writes)")
        command.add_argument("--radar", nargs=2, required=True, metavar=("FIRST", "SECOND"),
                             help="each table's radar description (Parquet, as for `track`: radar_id, latitude_deg, "
                                  "longitude_deg, height_m), in the same order")
        command.add_argument("--method", default="statistical", choices=ASSOCIATION_METHODS,
                             help="association method (default: %(default)s); network loads "
                                  "<models>/association_net.pt (dvc repro train_association)")
        command.add_argument("--pairs", required=True, help="output Parquet: the pairs at each common time")
        command.add_argument("--fused", required=True, help="output Parquet: the fused air picture at each common time")
    elif option == "export":
        command.add_argument("--plots", required=True, help="simulated plots Parquet")
        command.add_argument("--radar", required=True, help="radar description Parquet")
        command.add_argument("--scenario", type=int, required=True, help="scenario id to export")
        command.add_argument("--out", required=True, help="output ASTERIX file")
    elif option == "readme":
        command.add_argument("--readme", default="README.md", help="README to update (default: %(default)s)")
    elif option == "reference":
        command.add_argument("--out", default="docs/params.md", help="the reference page (default: %(default)s)")
        command.add_argument("--check", action="store_true",
                             help="do not write; exit 1 naming the page if it is out of date")
    elif option == "check":
        command.add_argument("--check", action="store_true",
                             help="do not write; exit 1 if a generated section of the README or docs/ is out of date")
    else:
        default, what = FOLDERS[option]
        command.add_argument(f"--{option}", default=default, help=f"{what} (default: %(default)s)")


def build_parser() -> argparse.ArgumentParser:
    examples = "\n".join(f"  {example}" for _, _, example, _ in COMMANDS.values())
    parser = argparse.ArgumentParser(prog="python -m pipeline", description=__doc__,
                                     epilog="examples (one per command; `<command> --help` gives its options):\n"
                                            + examples, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-q", "--quiet", action="store_true", help="log warnings and errors only")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (handler, summary, example, options) in COMMANDS.items():
        command = commands.add_parser(name, help=summary, description=summary, epilog=f"example:\n  {example}",
                                      formatter_class=argparse.RawDescriptionHelpFormatter)
        command.set_defaults(handler=handler)
        for option in options:
            _add_option(command, option)
    return parser


def configure_logging(quiet: bool) -> None:
    """One format for every line, and Ctrl-C stopping the command.

    A process started with SIGINT ignored (a background job of a non-interactive shell, some
    test runners) passes that on to DVC and its stages; Python then installs no
    KeyboardInterrupt handler and Ctrl-C would not stop a training stage, so it is restored."""
    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s", stream=sys.stderr)
    signal.signal(signal.SIGINT, signal.default_int_handler)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.quiet)
    try:
        return args.handler(args) or 0
    except (ParamError, InputError, RouteGenerationError, SchedulerUnreachable, TrackingError, TrainingDiverged,
            TuningError, UnknownMethod) as error:
        log.error("%s", error)
        return 2

"""The learned trackers' speed against `imm_gnn` on the bench's own materials (issue 29's goal), from a run's reports.

The evaluate and evaluate_scenes stages time every run's tracking alone, unit by unit, on the same plots in the
same stage (`plots_per_second` in reports/tracker_metrics.json and reports/scene_metrics.json). This prints, for
each run of the thesis's networks and the learned Kalman hybrids, its plots per second on the test split and on
the scenes beside the reference run's (default `imm_gnn_4000`), the ratio, and issue 29's goal (at least half).
With `--profile RUN` it also tracks the first scene with that run under cProfile (the scenes stage's plots, the
run's models) and prints where the time goes, by own time.

    python benchmarks/bench_learned_speed.py --run .
    python benchmarks/bench_learned_speed.py --run /tmp/bench-pipeline-abc/repository --profile kalman_net_4000

The stages time their units on `compute.workers` processes that share the machine, so a ratio is the steadier
figure; for plots per CPU second at 1 to 1000 aircraft, `benchmarks/bench_scale.py`.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import io as text_io
import json
import pstats
import sys
import time
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))

from pipeline.tracker import registry  # noqa: E402

GOAL = 0.5  # issue 29: every learned tracker at least half of imm_gnn_4000's plots per second
MATERIALS = {"test split": "tracker_metrics.json", "scenes": "scene_metrics.json"}


def rates(reports: Path) -> dict[str, dict[str, float]]:
    """Each material's plots per second by run name, from the stage reports in `reports` (a material whose report
    is missing is left out)."""
    found = {}
    for material, name in MATERIALS.items():
        path = reports / name
        if path.is_file():
            runs = json.loads(path.read_text())["runs"]
            found[material] = {run: float(metrics["plots_per_second"]) for run, metrics in runs.items()
                               if metrics.get("plots_per_second") is not None}
    return found


def learned(run: str) -> bool:
    """Whether the run's method (the longest registered method name its name starts with, as `{method}_{window}`
    and a management suffix make it) is one of the thesis's networks or a learned Kalman hybrid."""
    methods = [name for name in registry.METHODS if run.startswith(name + "_")]
    return bool(methods) and registry.group(max(methods, key=len)) in (registry.THESIS_NETWORKS,
                                                                       registry.LEARNED_HYBRIDS)


def table(found: dict[str, dict[str, float]], reference: str) -> list[str]:
    """The speed table, one row per learned run of any material, in name order."""
    materials = list(found)
    lines = [f"| run | {' | '.join(f'{m} plots/s (x {reference})' for m in materials)} | goal (>= {GOAL:g}x) |",
             "|---|" + "---|" * (len(materials) + 1)]
    names = sorted({run for runs in found.values() for run in runs if learned(run)})
    for run in names:
        cells, met = [], []
        for material in materials:
            own, base = found[material].get(run), found[material].get(reference)
            if own is None or base is None:
                cells.append("not run")
                continue
            cells.append(f"{own:,.0f} ({own / base:.2f}x)")
            met.append(own / base >= GOAL)
        verdict = "met" if met and all(met) else "missed"
        if verdict == "met" and len(met) < len(materials):
            verdict += f" ({len(met)} of {len(materials)} materials run)"
        lines.append(f"| {run} | {' | '.join(cells)} | {verdict} |")
    base = " | ".join(f"{found[m][reference]:,.0f}" if reference in found[m] else "not run" for m in materials)
    lines.append(f"| {reference} | {base} | |")
    return lines


def profile(run_folder: Path, name: str, top: int) -> str:
    """cProfile of tracking and scoring the first scene with run `name` (by own time, `top` lines)."""
    from pipeline.bench import scene_evaluation
    from pipeline.settings import load_params
    params = load_params(run_folder / "params.yaml")
    params = dataclasses.replace(params, evaluate=dataclasses.replace(params.evaluate, seeds=1, scene_runs=(name,)))
    evaluation = scene_evaluation.prepare(params, run_folder / "data" / "scenes", run_folder / "models")
    run = next(run for run in evaluation.runs if run.name == name)
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiler.enable()
    scene_evaluation.evaluate_unit(evaluation, run, 0)
    profiler.disable()
    stream = text_io.StringIO()
    stream.write(f"{name} on scene 0 ({len(evaluation.scenes[0].plots):,} plots): "
                 f"{time.perf_counter() - start:.2f} s under cProfile, tracking and scoring\n")
    pstats.Stats(profiler, stream=stream).sort_stats("tottime").print_stats(top)
    return stream.getvalue()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, default=REPOSITORY,
                        help="a folder where `dvc repro` ran: its reports/ (default: here)")
    parser.add_argument("--reference", default="imm_gnn_4000", help="the run compared with (default: %(default)s)")
    parser.add_argument("--profile", metavar="RUN", help="also profile the first scene with this run")
    parser.add_argument("--top", type=int, default=15, help="profile lines (default: %(default)s)")
    args = parser.parse_args()
    found = rates(args.run / "reports")
    if not found:
        print(f"{args.run / 'reports'}: neither {' nor '.join(MATERIALS.values())} is there", file=sys.stderr)
        raise SystemExit(2)
    print("\n".join(table(found, args.reference)))
    if args.profile:
        print("\n" + profile(args.run, args.profile, args.top))


if __name__ == "__main__":
    main()

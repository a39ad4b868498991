"""Stone Soup's track management tuned as ours was (issue 33: its peers tuned with the same effort).

Our trackers' process noise comes from the `tune_kalman` stage; Stone Soup's runs take the same tuned CV model
and the same chi-square gate (`pipeline.peers.stone_soup`), so those are tuned alike already. What is left is
track management: ours was chosen by sweeps on data that is not scored (`tracker.management.delete_after_s`, on
validation scenes, docs/comparison.md), Stone Soup's came from its tutorials (`peers.stone_soup.min_points` 3,
`delete_after_s` 20). This script gives Stone Soup the same sweep: each (`min_points`, `delete_after_s`) of the
grid, Stone Soup's tracker of `--association` on validation material, scored as the peers stage scores (GOSPA of
the confirmed updates, `pipeline.bench.scene_evaluation`), the chosen setting the lowest GOSPA.

The validation material is the peers stage's two materials made of data that no stage scores:

- the first `peers.scenarios_per_strategy` scenarios of each route strategy of the `--split` split (default
  `calibration`; the peers stage takes `evaluate.split`, `test`), each its first `peers.window_s`;
- the first `peers.scenes` scenes of `--scenes` (a scenes stage's output made with another `scenes.seed`, as the
  deletion sweep's validation scenes were: `python -m pipeline scenes --params P --out F` with `scenes.seed: 8118`),
  each its first `peers.scene_window_s`; left out when `--scenes` is not given.

Prints each setting's GOSPA on each material and pooled (the scenarios' and scenes' GOSPA weighted by their scans
alike: the mean over every scan of every recording), tracks per aircraft and false tracks, and the setting chosen.
Stone Soup tracks 15-100 plots a second: a setting takes about 5 minutes on one core.

    python benchmarks/tune_stone_soup.py --run . --scenes /tmp/validation_scenes --workers 2
    python benchmarks/tune_stone_soup.py --run /tmp/tiny --delete-after-s 20 32 --min-points 3
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))

from pipeline.bench import engine, peers, scene_evaluation  # noqa: E402
from pipeline.filters import classical_filters  # noqa: E402
from pipeline.params import Params  # noqa: E402
from pipeline.peers import stone_soup  # noqa: E402
from pipeline.settings import load_params  # noqa: E402


def validation_params(params_file: Path, split: str) -> Params:
    """Params of `params_file` with `evaluate.split` set to `split` (the peers stage's test material then comes
    from it), checked as the pipeline checks them."""
    raw = yaml.safe_load(params_file.read_text())
    raw["evaluate"]["split"] = split
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "params.yaml"
        path.write_text(yaml.safe_dump(raw))
        return load_params(path)


def prepare(params_file: Path, split: str, run: Path, scenes_dir: Path | None) -> dict:
    """What every unit reads: params, the validation recordings and our tuned CV filter."""
    params = validation_params(params_file, split)
    recordings = peers.test_recordings(params, run / "data" / "simulated", run / "data" / "routes")
    if scenes_dir is not None:
        recordings += peers.scene_recordings(params, scenes_dir)
    cv = classical_filters.load_settings(run / "models" / "kalman_tuned.json")["cv"]
    return {"params": params, "recordings": recordings, "cv": cv}


def evaluate_unit(state: dict, association: str, min_points: int, delete_after_s: float, index: int
                  ) -> scene_evaluation.SceneResult:
    """Stone Soup with one setting on validation recording `index`, scored as the peers stage scores."""
    params, recording = state["params"], state["recordings"][index]
    peer = params.peers.stone_soup
    settings = stone_soup.StoneSoupSettings.from_params(association, peer, state["cv"],
                                                        params.tracker.association.kalman_gate_probability)
    settings = dataclasses.replace(settings, min_points=min_points, delete_after_s=delete_after_s)
    start = time.perf_counter()
    updates = stone_soup.track_with_stone_soup(recording.scene.plots, settings)
    return scene_evaluation.scene_result(params, recording.scene, updates, updates["confirmed"],
                                         time.perf_counter() - start, update_interval_s=recording.update_interval_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, default=REPOSITORY,
                        help="a folder where `dvc repro` ran: its data/ and models/kalman_tuned.json (default: here)")
    parser.add_argument("--params", type=Path, help="params file (default: the run's params.yaml)")
    parser.add_argument("--split", default="calibration", help="the validation split (default: %(default)s)")
    parser.add_argument("--scenes", type=Path, help="a scenes stage's output of another scenes.seed (default: none)")
    parser.add_argument("--association", default="gnn", choices=stone_soup.ASSOCIATIONS,
                        help="Stone Soup's association swept (default: %(default)s)")
    parser.add_argument("--min-points", type=int, nargs="+", default=[2, 3, 4],
                        help="MultiMeasurementInitiator's updates to confirm (default: %(default)s)")
    parser.add_argument("--delete-after-s", type=float, nargs="+", default=[20.0, 26.0, 32.0, 38.0],
                        help="UpdateTimeDeleter's silence (s) (default: %(default)s)")
    parser.add_argument("--settings", nargs="+", metavar="M:D",
                        help="explicit (min_points:delete_after_s) settings instead of the grid, e.g. 3:20 3:32 2:32")
    parser.add_argument("--workers", type=int, default=1, help="Dask worker processes (default: %(default)s)")
    args = parser.parse_args()
    why = stone_soup.missing()
    if why:
        sys.exit(why)
    arguments = (args.params or args.run / "params.yaml", args.split, args.run, args.scenes)
    state = prepare(*arguments)
    recordings = state["recordings"]
    grid = ([(int(m), float(d)) for m, d in (setting.split(":") for setting in args.settings)] if args.settings
            else list(itertools.product(args.min_points, args.delete_after_s)))
    units = [(args.association, m, d, index) for m, d in grid for index in range(len(recordings))]
    print(f"Stone Soup {args.association}: {len(grid)} settings x {len(recordings)} validation recordings "
          f"({sum(len(r.scene.plots) for r in recordings):,} plots each setting)", flush=True)
    results: dict[tuple, scene_evaluation.SceneResult] = {}
    for done, (unit, result) in enumerate(engine.completed_units(units, args.workers, evaluate_unit, state, prepare,
                                                                 arguments), start=1):
        results[unit] = result
        print(f"  {done}/{len(units)} units", end="\r", flush=True)
    materials = sorted({r.material for r in recordings})
    label = {peers.TEST: f"{args.split} scenarios", peers.SCENES: "validation scenes"}
    print(f"\n| min_points | delete_after_s | {' | '.join(f'GOSPA {label[m]} (m)' for m in materials)} | GOSPA pooled (m) "
          "| tracks per aircraft | false tracks |")
    print("|---|---|" + "---|" * (len(materials) + 3))
    pooled = {}
    for m, d in grid:
        own = [results[args.association, m, d, index] for index in range(len(recordings))]
        per = [scene_evaluation.run_metrics([x for x, r in zip(own, recordings) if r.material == material], 0)
               for material in materials]
        whole = scene_evaluation.run_metrics(own, 0)
        pooled[m, d] = whole["GOSPA"]
        by_material = " | ".join(f"{p['GOSPA']:.1f}" for p in per)
        print(f"| {m} | {d:g} | {by_material} | {whole['GOSPA']:.1f} "
              f"| {whole['tracks_per_aircraft']:.2f} | {whole['false_tracks']:g} |")
    best = min(pooled, key=lambda key: (pooled[key], key))
    print(f"\nchosen (lowest pooled GOSPA): min_points {best[0]}, delete_after_s {best[1]:g} "
          f"({pooled[best]:.1f} m)")
    print(f"the tutorials' set-up (min_points 3, delete_after_s 20): "
          + (f"{pooled[3, 20.0]:.1f} m" if (3, 20.0) in pooled else "not in the grid"))


if __name__ == "__main__":
    main()

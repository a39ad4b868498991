"""Digests of what a tiny `dvc repro evaluate` writes, timing fields aside: a refactor's proof that
nothing a user sees changed.

    python tools/tiny_reports.py --run /tmp/tiny          # run the tiny pipeline in a copy, print digests
    python tools/tiny_reports.py --repository /tmp/tiny --write   # pin them in tests/tiny_reports.json

Every output DVC recorded in the run's `dvc.lock` (data, models, reports) is named with its
digest: DVC's own md5 for files and folders, and for a JSON report a digest of its content with
the timing fields (`TIMING_KEYS`: plots per second, seconds of training or tuning) removed, which
differ from run to run. `tests/test_tiny_reports.py` compares the shared tiny pipeline of the
test session against the pinned digests; a change that means to alter an output regenerates them
here, and the diff of tests/tiny_reports.json names what it altered.

Only what repeats on every machine is pinned and compared (`COMPARED`): the data stages, bit-exact on any
processor (tests/test_determinism.py), and `tune_kalman`. Training repeats to the bit on one machine but not
across machines, not even two of the same kind with PyTorch's kernels pinned (pipeline/__init__.py; docs/data.md,
"Two machines, both pinned: the spread that is left"), so the trained models and everything scored with them
are left to the tests that check them on the machine they run on. `tune_kalman` repeats on one kind of processor,
not always across kinds: on 2026-12-07 an AMD EPYC machine tuned the tiny data's filters to other values than
the machine that pinned them (the same code: commits c5a50a8 and a66897d give the same file there; Nelder-Mead's
path on the tiny data is ill-conditioned, the CV velocity spread runs to 385,755 m/s), and the pins were made
again there. A new kind of machine that fails on `tune_kalman` alone is that: pin again with `--write`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import yaml

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))
from pipeline.io import TIMING_KEYS  # noqa: E402  (a tracker's speed; a tuning's or training's duration)

PINNED = REPOSITORY / "tests" / "tiny_reports.json"
TARGET = "evaluate"  # the tiny run is `dvc repro evaluate` (tests/servers.py)
COMPARED = ("routes", "simulate", "scenes", "windows", "data_report", "tune_kalman")  # the same bytes on any machine


def _without_timing(value: object) -> object:
    if isinstance(value, dict):
        return {k: _without_timing(v) for k, v in value.items() if k not in TIMING_KEYS}
    if isinstance(value, list):
        return [_without_timing(v) for v in value]
    return value


def upstream_stages(stages: dict, target: str) -> set[str]:
    """`target` and every stage of dvc.yaml's `stages` whose outputs it depends on, directly or not."""
    made_by = {}
    for name, stage in stages.items():
        for out in [*stage.get("outs", []), *stage.get("metrics", []), *stage.get("plots", [])]:
            made_by[next(iter(out)) if isinstance(out, dict) else out] = name
    found, todo = set(), [target]
    while todo:
        name = todo.pop()
        if name not in found:
            found.add(name)
            todo += [stage for dep in stages[name].get("deps", []) for out, stage in made_by.items()
                     if dep == out or dep.startswith(out + "/")]
    return found


def output_digests(repository: Path) -> dict[str, dict[str, str]]:
    """Stage -> {output path: digest} for every output in `repository`'s dvc.lock of the stages the
    tiny run ran (`TARGET` and those upstream of it)."""
    ran = upstream_stages(yaml.safe_load((repository / "dvc.yaml").read_text())["stages"], TARGET)
    lock = yaml.safe_load((repository / "dvc.lock").read_text())["stages"]
    digests: dict[str, dict[str, str]] = {}
    for stage, entry in sorted((s, e) for s, e in lock.items() if s in ran):
        outs = {}
        for out in entry.get("outs", []):
            path = out["path"]
            if path.endswith(".json") and (repository / path).is_file():
                content = json.loads((repository / path).read_text())
                text = json.dumps(_without_timing(content), sort_keys=True)
                outs[path] = "json:" + hashlib.sha256(text.encode()).hexdigest()
            else:
                outs[path] = "md5:" + out["md5"]
        digests[stage] = outs
    return digests


def differences(pinned: dict, found: dict[str, dict[str, str]]) -> list[str]:
    """`stage: path` of each output of the COMPARED stages whose digest differs from (or is missing in) the
    pinned ones, and `stage: (not pinned)` for a compared stage the pinned file lacks."""
    out = []
    for stage in COMPARED:
        if stage not in pinned["stages"]:
            out += [f"{stage}: (not pinned)"] if stage in found else []
            continue
        for path, digest in pinned["stages"][stage].items():
            if found.get(stage, {}).get(path) != digest:
                out.append(f"{stage}: {path}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog="example:\n  python tools/tiny_reports.py --run /tmp/tiny --write",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--run", type=Path, help="an empty folder: copy the repository there and run the tiny pipeline")
    where.add_argument("--repository", type=Path, help="a copy in which the tiny pipeline already ran")
    parser.add_argument("--write", action="store_true", help=f"pin the digests in {PINNED.relative_to(REPOSITORY)}")
    args = parser.parse_args()
    repository = args.repository
    if args.run:
        from tests.servers import repro_tiny_pipeline

        repository = repro_tiny_pipeline(args.run)
    found = {"stages": {stage: outs for stage, outs in output_digests(repository).items() if stage in COMPARED}}
    if args.write:
        PINNED.write_text(json.dumps(found, indent=1, sort_keys=True) + "\n")
    print(json.dumps(found, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()

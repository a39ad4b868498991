"""Wall time and peak memory of every stage of a fresh `dvc repro`, as a user runs it.

Copies the repository as a fresh clone would have it (the files git tracks or does not
ignore, so no data, no models, no DVC cache) into a temporary folder, then runs the
pipeline stage by stage in the order `dvc.yaml` lists them (an order DVC accepts:
each stage comes after what it depends on), each with `dvc repro --single-item --force
<stage>` in a fresh process: forced, because a stage whose outputs are committed (the
reports) and whose inputs come out byte-identical would otherwise be skipped. Each stage's wall time includes DVC's own start and hashing, so the
sum is what a user waits for `dvc repro`. Peak memory is the largest resident set of the
processes of that stage (`os.wait4`: DVC and the stage's Python). The result goes to
`reports/pipeline_speed.json` (atomically), and the Speed table of docs/speed.md is regenerated
from it with `python -m pipeline readme`. The report also records what was measured: the commit, each
stage's code as the run's `dvc.lock` hashed it (`tests/test_docs.py` holds it against the committed
`dvc.lock`, so a time older than the code it measures fails), and the stages the README walkthrough's
experiment reruns (`EXPERIMENT_PARAM` and every stage downstream of those that read it) with their time.

A run that stops part way (a stage fails, the machine is needed, the session ends) keeps its copy and resumes
with `--resume FOLDER`: the stages already timed keep their times (`progress.json` in the folder, written after
each stage, holds them with the commit and params the copy was made from), the stage that was cut runs again
whole, and the rest follow. Each stage's time is one uninterrupted measurement either way. A stage can also be
paused where it stands (`kill -USR1 PID`, the PID printed at the start; `kill -USR2 PID` continues it): the time
it stood stopped is not counted. A Dask stage's workers miss their heartbeats while stopped: on continuing, the
scheduler restarts them and their units in flight run again (the engine's lost-worker path, the same results),
which the stage's time includes; its progress line's rate counts the stopped time until it catches up.

    python benchmarks/bench_pipeline.py                      # default params.yaml, 2-3 hours on 2 cores
    python benchmarks/bench_pipeline.py --params tiny.yaml --out /tmp/speed.json --no-readme
    python benchmarks/bench_pipeline.py --resume /tmp/bench-pipeline-abc123   # go on where that run stopped

Run it on an otherwise idle machine: the stages use both cores.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import yaml

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))

from pipeline import io  # noqa: E402  (the repository's package, whichever folder this runs from)
from tests.project import copy_repository  # noqa: E402  (a fresh clone's files in a new git repository)


class Pauses:
    """The stage running now can be paused and continued from outside: `kill -USR1 PID` stops its process group
    (DVC, the stage, its Dask workers), `kill -USR2 PID` continues it; the time it stood stopped is not counted as
    the stage's. So a run that spans two sessions on one machine keeps the stage it was in, and its time."""

    def __init__(self) -> None:
        self.group: int | None = None
        self.stopped_at: float | None = None
        self.stopped_s = 0.0
        signal.signal(signal.SIGUSR1, self.pause)
        signal.signal(signal.SIGUSR2, self.resume)

    def pause(self, *_: object) -> None:
        if self.group is not None and self.stopped_at is None:
            os.killpg(self.group, signal.SIGSTOP)
            self.stopped_at = time.perf_counter()
            print(f"paused (kill -USR2 {os.getpid()} continues)", flush=True)

    def resume(self, *_: object) -> None:
        if self.group is not None and self.stopped_at is not None:
            os.killpg(self.group, signal.SIGCONT)
            self.stopped_s += time.perf_counter() - self.stopped_at
            self.stopped_at = None
            print("continued", flush=True)


def timed(command: list[str], cwd: Path, env: dict[str, str], log: Path, pauses: Pauses) -> tuple[float, float, int]:
    """Wall seconds (less any time `pauses` held it stopped), peak RSS (MiB) of the process tree, and exit code
    of one command, run in a process group of its own."""
    start, pauses.stopped_s = time.perf_counter(), 0.0
    with log.open("ab") as output:
        child = subprocess.Popen(command, cwd=cwd, env=env, stdout=output, stderr=subprocess.STDOUT,
                                 start_new_session=True)
        pauses.group = child.pid
        _, status, usage = os.wait4(child.pid, 0)
        pauses.group = None
    return time.perf_counter() - start - pauses.stopped_s, usage.ru_maxrss / 1024.0, os.waitstatus_to_exitcode(status)


EXPERIMENT_PARAM = "training.predictor.learning_rate"  # the README walkthrough's `dvc exp run -S ...`


def reruns(stages: dict, param: str) -> list[str]:
    """The stages of dvc.yaml's `stages` (in its order) that a change of `param` reruns: those listing it,
    or a section above it, among their params, and every stage downstream of them."""
    def reads(stage: dict) -> bool:
        listed = [key for entry in stage.get("params", []) for key in ([entry] if isinstance(entry, str) else
                                                                       [k for keys in entry.values() for k in keys])]
        return any(param == key or param.startswith(key + ".") for key in listed)

    made_by = {next(iter(out)) if isinstance(out, dict) else out: name for name, stage in stages.items()
               for out in [*stage.get("outs", []), *stage.get("metrics", []), *stage.get("plots", [])]}
    rerun = {name for name, stage in stages.items() if reads(stage)}
    for name, stage in stages.items():  # dvc.yaml lists a stage after what it depends on
        if any(maker in rerun for dep in stage.get("deps", []) for out, maker in made_by.items()
               if dep == out or dep.startswith(out + "/")):
            rerun.add(name)
    return [name for name in stages if name in rerun]


def measured(copy: Path, stages: dict, results: list[dict], commit: str) -> dict:
    """What the run measured: the commit of the code copied, each stage's code deps with the md5 the copy's
    `dvc.lock` gave them, and the walkthrough experiment's stages and seconds."""
    lock = yaml.safe_load((copy / "dvc.lock").read_text())["stages"]
    seconds = {result["stage"]: result["seconds"] for result in results}
    again = reruns(stages, EXPERIMENT_PARAM)
    return {"commit": commit,
            "code": {name: {dep["path"]: dep["md5"] for dep in entry.get("deps", []) if dep["path"].startswith("pipeline/")}
                     for name, entry in sorted(lock.items())},
            "experiment": {"param": EXPERIMENT_PARAM, "stages": again,
                           "seconds": round(sum(seconds.get(name, 0.0) for name in again), 1)}}


def machine() -> dict:
    import torch

    return {"cpus": os.cpu_count(), "python": platform.python_version(), "torch": torch.__version__,
            "processor": platform.processor() or platform.machine()}


PROGRESS = "progress.json"  # in a run's folder: what `--resume` goes on from


def started(args: argparse.Namespace) -> tuple[Path, dict]:
    """The run's folder and its progress: a new copy of the repository (the commit it was made from, no stage
    timed yet), or, with `--resume`, the folder given and the progress written there."""
    if args.resume:
        progress_file = args.resume / PROGRESS
        if not progress_file.is_file():
            print(f"--resume {args.resume}: no {PROGRESS} there (not a folder this benchmark kept)", file=sys.stderr)
            raise SystemExit(2)
        return args.resume, json.loads(progress_file.read_text())
    folder = Path(tempfile.mkdtemp(prefix="bench-pipeline-"))
    copy = copy_repository(folder / "repository")
    if args.params:
        shutil.copyfile(args.params, copy / "params.yaml")
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPOSITORY, capture_output=True, text=True).stdout.strip()
    progress = {"commit": commit, "params": args.params.name if args.params else None, "results": []}
    io.write_json(progress, folder / PROGRESS)
    return folder, progress


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", type=Path, help="params file to run with (default: the repository's params.yaml)")
    parser.add_argument("--out", type=Path, default=REPOSITORY / "reports" / "pipeline_speed.json",
                        help="where the JSON goes (default: %(default)s)")
    parser.add_argument("--no-readme", action="store_true", help="do not regenerate docs/speed.md from the result")
    parser.add_argument("--keep", action="store_true", help="keep the temporary copy and print where it is")
    parser.add_argument("--resume", type=Path, metavar="FOLDER",
                        help="go on with the run kept in FOLDER (the folder a stopped run printed)")
    args = parser.parse_args()

    folder, progress = started(args)
    copy, results, finished = folder / "repository", progress["results"], False
    try:
        stages = list(yaml.safe_load((copy / "dvc.yaml").read_text())["stages"])
        env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
        env.pop("MLFLOW_TRACKING_URI", None)  # the copy's own mlflow.db, as on a fresh clone
        log = folder / "repro.log"
        pauses = Pauses()
        print(f"pid {os.getpid()}: kill -USR1 {os.getpid()} pauses the stage running, kill -USR2 continues it",
              flush=True)
        total = sum(result["seconds"] for result in results)
        for result in results:
            print(f"{result['stage']:18s} {result['seconds']:7.1f} s  (timed before the resume)", flush=True)
        timed_already = {result["stage"] for result in results}
        for stage in [stage for stage in stages if stage not in timed_already]:
            command = [sys.executable, "-m", "dvc", "repro", "--single-item", "--force", stage]
            seconds, peak, code = timed(command, copy, env, log, pauses)
            if code != 0:
                raise SystemExit(f"stage {stage} failed (exit {code}); its output:\n{log.read_text()[-4000:]}")
            total += seconds
            results.append({"stage": stage, "seconds": round(seconds, 1), "peak_memory_mib": round(peak),
                            "load_1min": round(os.getloadavg()[0], 2)})  # other work on the machine shows here
            io.write_json(progress, folder / PROGRESS)
            print(f"{stage:18s} {seconds:7.1f} s  {peak:6.0f} MiB  (total {total / 60:.1f} min)", flush=True)
        params = yaml.safe_load((copy / "params.yaml").read_text())
        report = {
            "what": "a fresh `dvc repro`, stage by stage (`dvc repro --single-item --force`), default params"
                    if not progress["params"] else f"a fresh `dvc repro`, stage by stage, params from {progress['params']}",
            "command": "python benchmarks/bench_pipeline.py",
            "date": datetime.now(timezone.utc).strftime("%Y-%m-%d"),
            "machine": machine(),
            "workers": params.get("compute", {}).get("workers"),
            "total_seconds": round(total, 1),
            "stages": results,
            **measured(copy, yaml.safe_load((copy / "dvc.yaml").read_text())["stages"], results, progress["commit"]),
        }
        io.write_json(report, args.out)
        finished = True
        print(f"fresh dvc repro: {total / 60:.1f} min; written to {args.out}")
        if not args.no_readme:
            subprocess.run([sys.executable, "-m", "pipeline", "readme", "--readme", str(REPOSITORY / "README.md"),
                            "--docs", str(REPOSITORY / "docs"), "--reports", str(REPOSITORY / "reports"),
                            "--package", str(REPOSITORY / "pipeline")], cwd=REPOSITORY, check=True)
    finally:
        if args.keep or args.resume or not finished:
            print(f"the copy is in {folder}" + ("" if finished else f"; go on with --resume {folder}"))
        else:
            shutil.rmtree(folder, ignore_errors=True)

if __name__ == "__main__":
    main()

"""The import contract of `pipeline/` (pyproject.toml `[tool.importlinter]`, checked by import-linter,
which counts every import: module level, inside functions and under TYPE_CHECKING): the wings in
layers, the stages and commands on top, the ground floor at the bottom, and no circle."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import yaml

from tests.project import REPOSITORY

LINT_IMPORTS = Path(sys.executable).parent / "lint-imports"


def lint_imports(root: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(LINT_IMPORTS), "--no-cache"], cwd=root, capture_output=True, text=True,
                          env={"PYTHONPATH": str(root), "PATH": str(LINT_IMPORTS.parent)})


def test_the_package_keeps_its_import_contract() -> None:
    result = lint_imports(REPOSITORY)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


def test_a_lower_wing_importing_a_higher_one_breaks_the_contract(tmp_path: Path) -> None:
    """The same check on a copy of the package in which the tracker imports the bench (a lower wing
    importing a higher one) and the geometry imports the tracker back (a circle): both are named."""
    shutil.copytree(REPOSITORY / "pipeline", tmp_path / "pipeline", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPOSITORY / "pyproject.toml", tmp_path)
    (tmp_path / "pipeline" / "tracker" / "upward.py").write_text("from pipeline.bench import gospa\n")
    (tmp_path / "pipeline" / "geometry" / "circle.py").write_text("from pipeline.tracker import upward\n")
    result = lint_imports(tmp_path)
    assert result.returncode != 0
    assert "pipeline.tracker.upward -> pipeline.bench.gospa" in result.stdout
    assert "No cycles are allowed in pipeline" in result.stdout


def test_every_stage_lists_the_code_it_runs_as_its_deps() -> None:
    """dvc.yaml's `pipeline/...` deps of each stage are exactly the modules its command imports,
    directly or not (`tools/stage_code_deps.py`): a module a stage runs but does not list would leave
    `dvc repro` calling a stale output current. `python tools/stage_code_deps.py --write` mends it."""
    from tools import stage_code_deps

    stages = yaml.safe_load((REPOSITORY / "dvc.yaml").read_text())["stages"]
    wanted = stage_code_deps.stage_code_deps(stages, (REPOSITORY / "pipeline" / "cli.py").read_text())
    assert stage_code_deps.differences(stages, wanted) == {}


def test_dvc_yaml_lists_every_stage_after_the_stages_it_reads() -> None:
    """A stage comes after every stage whose outputs its deps name (a folder's or a file inside it), so a run in
    dvc.yaml's order (`benchmarks/bench_pipeline.py` times the stages so) never reads a stale output: the compare
    stage once came before fusion and read the committed fusion.json rather than the run's."""
    stages = yaml.safe_load((REPOSITORY / "dvc.yaml").read_text())["stages"]
    made_by = {}
    for name, stage in stages.items():
        for kind in ("outs", "metrics", "plots"):
            for out in stage.get(kind, []):
                made_by[next(iter(out)) if isinstance(out, dict) else out] = name
    position = {name: index for index, name in enumerate(stages)}
    late = [(name, dep, made_by[out]) for name, stage in stages.items() for dep in stage.get("deps", [])
            for out in made_by if dep == out or dep.startswith(out + "/") or out.startswith(dep + "/")
            if made_by[out] != name and position[made_by[out]] > position[name]]
    assert late == []

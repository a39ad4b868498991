"""Each DVC stage's code dependencies, from the imports of the module its command runs.

    python tools/stage_code_deps.py            # list, per stage, code deps missing from dvc.yaml or extra
    python tools/stage_code_deps.py --write    # rewrite the `pipeline/...` entries of every stage's deps

A stage `python -m pipeline <command>` runs the module its handler in `pipeline/cli.py` imports;
its code deps are that module and every module of the package it imports, directly or through
others, counting every import (module level, inside functions, under TYPE_CHECKING: import-linter's
graph, grimp). `pipeline/cli.py` is not one: it parses the options and hands them on, and every
stage would rerun after a new command's help text. A hand-kept list misses some (the
evaluate stage imported 42 modules and listed 19), so a changed module would leave `dvc repro`
believing a stale output current; `tests/test_import_contract.py` keeps dvc.yaml equal to this.
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

import grimp
import yaml

REPOSITORY = Path(__file__).resolve().parent.parent


def handler_modules(cli_source: str) -> dict[str, set[str]]:
    """Command name -> the package modules its handler function in cli.py imports."""
    tree = ast.parse(cli_source)
    imports = {node.name: {child.module for child in ast.walk(node)
                           if isinstance(child, ast.ImportFrom) and child.module and child.module.startswith("pipeline")}
               for node in tree.body if isinstance(node, ast.FunctionDef)}
    table = next(node.value for node in tree.body if isinstance(node, ast.Assign)
                 and any(isinstance(t, ast.Name) and t.id == "COMMANDS" for t in node.targets))
    return {key.value: imports[value.elts[0].id] for key, value in zip(table.keys, table.values)}


def module_file(module: str) -> str | None:
    """The file of `module`; None for a package whose `__init__.py` holds nothing but its docstring
    and `__version__` (a wing's), which no stage's output depends on."""
    path = Path(*module.split("."))
    init = REPOSITORY / path / "__init__.py"
    if not init.is_file():
        return path.with_suffix(".py").as_posix()
    body = ast.parse(init.read_text()).body
    if all(isinstance(node, (ast.Expr, ast.Assign)) and not isinstance(getattr(node, "value", None), ast.Call)
           for node in body):
        return None
    return (path / "__init__.py").as_posix()


def parents(module: str) -> list[str]:
    """The packages Python imports before `module` ("pipeline", "pipeline.tracker" for
    "pipeline.tracker.run"): their `__init__.py` runs first (the package's pins the kernels)."""
    parts = module.split(".")
    return [".".join(parts[:n]) for n in range(1, len(parts))]


def stage_code_deps(stages: dict, cli_source: str) -> dict[str, list[str]]:
    """Stage name -> the sorted files of the package its command runs (module docstring)."""
    sys.path.insert(0, str(REPOSITORY))
    graph = grimp.build_graph("pipeline", cache_dir=None)
    handlers = handler_modules(cli_source)
    deps = {}
    for name, stage in stages.items():
        words = stage["cmd"].split()
        command = words[words.index("pipeline") + 1]
        modules: set[str] = set()
        for entry in handlers[command]:
            modules |= {entry, *graph.find_upstream_modules(entry)}
        modules |= {parent for module in modules for parent in parents(module)}  # Python runs them first
        deps[name] = sorted({f for f in map(module_file, modules) if f})
    return deps


def differences(stages: dict, wanted: dict[str, list[str]]) -> dict[str, tuple[list[str], list[str]]]:
    """Stage -> (code deps missing from dvc.yaml, code deps dvc.yaml lists beyond them)."""
    out = {}
    for name, stage in stages.items():
        listed = {d for d in stage.get("deps", []) if d.startswith("pipeline")}
        missing = sorted(set(wanted[name]) - listed)
        extra = sorted(listed - set(wanted[name]))
        if missing or extra:
            out[name] = (missing, extra)
    return out


def rewritten(text: str, wanted: dict[str, list[str]]) -> str:
    """dvc.yaml's text with each stage's `- pipeline/...` deps replaced by `wanted`'s, in place of the
    first of them (after the data deps when the stage listed none)."""
    out, stage, in_deps, placed = [], None, False, False
    for line in text.splitlines(keepends=True):
        stage_match = re.match(r"^  ([a-z_]+):\s*(#.*)?$", line)
        if stage_match:
            stage, in_deps, placed = stage_match.group(1), False, False
        if re.match(r"^    deps:\s*(#.*)?$", line):
            in_deps = True
            out.append(line)
            continue
        if in_deps and not line.startswith("      - "):
            if not placed and stage in wanted:
                out.extend(f"      - {f}\n" for f in wanted[stage])
            in_deps, placed = False, True
        if in_deps and line.startswith("      - pipeline"):
            if not placed:
                out.extend(f"      - {f}\n" for f in wanted[stage])
                placed = True
            continue
        out.append(line)
    return "".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog="example:\n  python tools/stage_code_deps.py --write",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--write", action="store_true", help="rewrite dvc.yaml's code deps")
    args = parser.parse_args()
    dvc_yaml = REPOSITORY / "dvc.yaml"
    text = dvc_yaml.read_text()
    stages = yaml.safe_load(text)["stages"]
    wanted = stage_code_deps(stages, (REPOSITORY / "pipeline" / "cli.py").read_text())
    if args.write:
        dvc_yaml.write_text(rewritten(text, wanted))
        return
    for name, (missing, extra) in differences(stages, wanted).items():
        print(f"{name}: missing {missing}; extra {extra}")


if __name__ == "__main__":
    main()

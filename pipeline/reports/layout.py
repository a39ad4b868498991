"""The package's layout in Markdown, from its folders and each module's docstring, so no module goes unlisted.

The wings come in the order of the import contract's layers (`[tool.importlinter]` in the pyproject.toml beside
the package), lowest first, each with the first paragraph of its `__init__` docstring and one line per module:
a link to the file and the first paragraph of the module's docstring. A module the layers do not name (a new
top-level module) is listed after them, so every `.py` file under the package appears exactly once. The `readme`
command writes it into docs/architecture.md and `--check` fails when a module was added, removed or redescribed.
"""

from __future__ import annotations

import ast
import os
import tomllib
from pathlib import Path

from pipeline import io


def summary(path: Path) -> str:
    """The first paragraph of the module's docstring, on one line (a summary that wraps stays whole)."""
    docstring = ast.get_docstring(ast.parse(path.read_text(), str(path)))
    if not docstring:
        raise io.InputError(f"{path}: the module has no docstring; the layout lists every module with the first "
                            "paragraph of its docstring")
    return " ".join(docstring.split("\n\n", 1)[0].split())


def layers(package: Path) -> list[list[str]]:
    """The dotted names of the import contract's layers, lowest layer first (`a | b` is one layer of two)."""
    pyproject = package.parent / "pyproject.toml"
    try:
        contracts = tomllib.loads(pyproject.read_text())["tool"]["importlinter"]["contracts"]
        layered = next(contract for contract in contracts if contract["type"] == "layers")
    except (OSError, KeyError, StopIteration, tomllib.TOMLDecodeError) as error:
        raise io.InputError(f"{pyproject}: no import contract of type 'layers' under [tool.importlinter] "
                            f"to order the package's wings ({type(error).__name__}: {error})") from None
    return [[name.strip() for name in layer.split("|")] for layer in reversed(layered["layers"])]


def _path_of(package: Path, dotted: str) -> Path:
    parts = dotted.split(".")[1:]  # below the package itself
    folder = package.joinpath(*parts)
    return folder if folder.is_dir() else folder.with_suffix(".py")


def _modules(folder: Path) -> list[Path]:
    return sorted(path for path in folder.rglob("*.py") if "__pycache__" not in path.parts)


def layout_section(package: Path, document_folder: Path) -> str:
    """The Markdown layout of `package`, its links relative to `document_folder` (where the page lies)."""

    def line(path: Path) -> str:
        link = Path(os.path.relpath(path, document_folder)).as_posix()
        shown = path.relative_to(package.parent).as_posix()
        return f"- [`{shown}`]({link}): {summary(path)}"

    listed: set[Path] = set()
    parts = [f"`{package.name}/`: {summary(package / '__init__.py')} Its modules and wings, lowest "
             "first (the layers of the import contract in `pyproject.toml`):", ""]
    listed.add(package / "__init__.py")
    for layer in layers(package):
        modules = []
        for dotted in layer:
            path = _path_of(package, dotted)
            if path.is_dir():
                if modules:
                    parts += [*modules, ""]
                    modules = []
                listed.update(_modules(path))
                heading = f"**`{path.relative_to(package.parent).as_posix()}/`**: {summary(path / '__init__.py')}"
                parts += [heading, "", *(line(module) for module in _modules(path) if module.name != "__init__.py"
                                         or module.parent != path), ""]
            elif path.is_file():
                listed.add(path)
                modules.append(line(path))
        if modules:
            parts += [*modules, ""]
    unlisted = [path for path in _modules(package) if path not in listed]
    if unlisted:
        parts += ["Not in the contract's layers:", "", *(line(path) for path in unlisted), ""]
    return "\n".join(parts).rstrip("\n")

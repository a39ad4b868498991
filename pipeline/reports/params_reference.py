"""docs/params.md, written from the declarations: one table per section, each key with its type, bounds,
value in params.yaml and doc (`python -m pipeline params-reference`; `--check` fails when it is stale)."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any, Iterator, Mapping

from pipeline.params.declare import INF, declared, interval_text, load_params_tree
from pipeline.params.tracking import Params

HEAD = ("# Params reference\n\nEvery key of `params.yaml`, written from its declaration in `pipeline/params/` by "
        "`python -m pipeline params-reference` (do not edit by hand; `--check` fails when this page is stale). "
        "`<name>` is an entry the user names (an aircraft type, a split), `[]` an entry of a list. A value out of "
        "its bounds stops every command with the key and the value named (exit 2).\n")


def values_at(tree: Any, key: str) -> list[Any]:
    """The values params.yaml gives `key` (`<name>` and `[]` stand for every entry)."""
    found = [tree]
    for part in key.replace("[]", ".[]").split("."):
        step = []
        for node in found:
            if part in ("<name>", "[]"):
                step += list(node.values()) if isinstance(node, Mapping) else list(node) if isinstance(node, list) else []
            elif isinstance(node, Mapping) and part in node:
                step.append(node[part])
        found = step
    return found


def type_text(field: dataclasses.Field, kind: Any) -> str:
    meta, args = field.metadata, typing.get_args(kind)
    if meta["pair"]:
        return "[lower, upper] of " + ("int" if (args[0] if args else kind) is int else "float")
    if meta["read"] is not None and meta["keys"]:
        return "list of float"
    if typing.get_origin(kind) is tuple:
        inner = args[0]
        return f"list of {getattr(inner, '__name__', inner)}" if not dataclasses.is_dataclass(inner) else "list"
    if meta["keys"]:
        inner = args[1]
        return "section" if dataclasses.is_dataclass(inner) else getattr(inner, "__name__", str(inner))
    if dataclasses.is_dataclass(kind) or (args and dataclasses.is_dataclass(args[-1])):
        return "section"
    if typing.get_origin(kind) is not None and args and args[-1] is float:
        return "name -> weight"
    return getattr(kind, "__name__", str(kind)).replace("NoneType", "none") if not args else \
        " or ".join(getattr(arg, "__name__", str(arg)).replace("NoneType", "absent") for arg in args)


def bounds_text(field: dataclasses.Field) -> str:
    meta = field.metadata
    if meta["choices"]:
        return "one of " + ", ".join(meta["choices"])
    low, high = meta["low"], meta["high"]
    if isinstance(low, str):
        return f">= {low}"
    if low == -INF and high == INF:
        return ""
    if isinstance(low, int) and not isinstance(low, bool) and not meta["open_low"] and (high == INF or
                                                                                       isinstance(high, int)):
        return f">= {low}" if high == INF else f"[{low}, {high}]"
    return interval_text(meta)


def cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def rows(tree: Mapping[str, Any]) -> Iterator[tuple[str, str, str, str, str]]:
    """(key, type, bounds, value in params.yaml, doc) of every declared key."""
    for key, field, kind in declared(Params):
        found = values_at(tree, key)
        section = type_text(field, kind) in ("section", "list") and not field.metadata["read"]
        shown = [str(v).lower() if isinstance(v, bool) else v for v in found]
        value = "" if section else "; ".join(f"`{v}`" for v in shown) if len(shown) < 6 else f"{len(shown)} values"
        yield key, type_text(field, kind), bounds_text(field), value, field.metadata["doc"]


def reference(tree: Mapping[str, Any]) -> str:
    """The page: a table per top-level section (its nested sections' keys in it)."""
    lines, current = [HEAD], None
    for key, kind, bounds, value, doc in rows(tree):
        top = key.split(".")[0].split("[")[0]
        if top != current:
            current = top
            lines += [f"\n## {top}\n", "| key | type | bounds | params.yaml | doc |", "|---|---|---|---|---|"]
        lines.append(f"| `{key}` | {cell(kind)} | {cell(bounds)} | {cell(value)} | {cell(doc)} |")
    return "\n".join(lines) + "\n"



def write_reference(params_path: Path, out: Path, check: bool = False) -> bool:
    """Write (or with `check`, compare) the reference of the params file at `params_path`; whether `out` was
    out of date."""
    text = reference(load_params_tree(params_path))
    stale = not out.is_file() or out.read_text() != text
    if stale and not check:
        out.write_text(text)
    return stale

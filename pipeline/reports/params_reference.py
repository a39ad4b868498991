"""docs/params.md, written from the declarations: one table per section, each key with its type, bounds,
value in params.yaml and doc (`python -m pipeline params-reference`; `--check` fails when it is stale)."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any, Iterator, Mapping

from pipeline.params.declare import INF, declared, interval_text, is_named, load_params_tree
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
                step += list(node.values() if isinstance(node, Mapping) else node if isinstance(node, list) else [])
            elif isinstance(node, Mapping) and part in node:
                step.append(node[part])
        found = step
    return found


def _name(kind: Any) -> str:
    return getattr(kind, "__name__", str(kind)).replace("NoneType", "absent")


def type_text(field: dataclasses.Field, kind: Any, found: list[Any]) -> str:
    """The knob's type as params.yaml writes it (a `keys` mapping: each key's; a knob of its own reader: its
    values' when they are strings, as a time is)."""
    if field.metadata["keys"]:
        kind = typing.get_args(kind)[1]
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if field.metadata["pair"]:
        return f"[lower, upper] of {_name((args or (kind,))[0])}"
    if field.metadata["read"] is not None and found and all(isinstance(value, str) for value in found):
        return "str"
    if dataclasses.is_dataclass(kind):
        return "section"
    if origin is tuple:
        if dataclasses.is_dataclass(args[0]):
            return "sections by name" if is_named(args[0]) else "list"
        return f"list of {_name(args[0])}"
    if args and dataclasses.is_dataclass(args[-1]):
        return "sections by name"
    if args and origin is not None and args[-1] is float:
        return "name -> weight"
    return " or ".join(map(_name, args)) if args else _name(kind)


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
        if not found and ("[]" in key or "<name>" in key):
            continue  # a key an entry may give and none does (a fusion radar's own sigma_range_m)
        kind_text = type_text(field, kind, found)
        shown = [str(v).lower() if isinstance(v, bool) else v for v in found]
        value = "; ".join(f"`{v}`" for v in shown) if len(shown) < 6 else f"{len(shown)} values"
        sections = kind_text in ("section", "sections by name", "list")
        yield key, kind_text, bounds_text(field), "" if sections else value, field.metadata["doc"]


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

"""A knob declared once, and the one parser that reads every section by its declarations.

A section is a frozen dataclass; each field is a knob, declared beside its siblings with `knob(...)`:
its type is the field's annotation, its bounds and its doc the knob's (Hydra's dataclass-as-schema,
Stone Soup's knobs on their components). `parse_section` reads a section's mapping field by field:
numbers (int or float, a bool is no number), booleans, strings and choices, [lower, upper] pairs,
lists of numbers or names, weights, nested sections, mappings and lists of sections. A field that is
no key of params.yaml (a name the user gave the entry, a value derived from other sections) is
declared `given()`. Rules across a section's knobs are the section's `check` method, run once the
section is read. Errors name the key and the value (``radar.latitude_deg = 95.0: must be in [-90.0,
90.0]``); a key no declaration reads is named with the nearest known one (`Tracked.unread`).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import yaml

INF = math.inf


class ParamError(ValueError):
    """A value in params.yaml is missing or invalid; the message names the key."""


def knob(doc: str, low: float = -INF, high: float = INF, *, open_low: bool = False, open_high: bool = False,
         key: str | None = None, choices: tuple = (), why: str = "", pair: bool = False, count: int = 0,
         keys: tuple = (), only: tuple = (), otherwise: Any = None, read: Callable | None = None,
         default: Any = dataclasses.MISSING) -> Any:
    """A field of a section read from params.yaml, its type the field's annotation.

    `low`/`high`: bounds of a number (or of each number of a list or pair), closed unless `open_low`/
    `open_high`; `low` may name another section's knob read before (`"windows.autoencoder_length"`).
    `key`: its params.yaml key when not the field's name (dotted: a key of another mapping). `choices`:
    the values a string (or each name of a list) may take. `why`: the message of a value out of bounds, in
    place of the interval. `pair`: a [lower, upper] pair, held in this field (a tuple) or split with the
    next field, `upper()` (the key then is the field's name less `_min`). `count`: a list of exactly this
    many numbers. `keys`: a mapping of these keys of the section, each read as the annotation's value
    type. `only`: read in these entries of a mapping alone (the others get `otherwise`, or what `check`
    derives). `read`: a reader `(tree, key, path, context) -> value` for a knob none of these describes.
    `default`: the value when the key is absent (an optional key)."""
    meta = dict(doc=doc, low=low, high=high, open_low=open_low, open_high=open_high, key=key, choices=choices,
                why=why, pair=pair, count=count, keys=keys, only=only, otherwise=otherwise, read=read)
    return dataclasses.field(default=default, metadata=meta)


def positive(doc: str, **options: Any) -> Any:
    """A knob of a number above 0 (or a list or pair of them)."""
    return knob(doc, 0.0, open_low=True, **options)


def upper(doc: str) -> Any:
    """The upper bound of the pair declared on the field before it (`knob(..., pair=True)`)."""
    return dataclasses.field(metadata=dict(doc=doc, upper=True))


def given(default: Any = dataclasses.MISSING) -> Any:
    """A field that is no key of params.yaml: given by the parser (an entry's name; a section whose keys the
    entry may change, as fusion.radars[] changes `radar`'s) or derived in `check`."""
    return dataclasses.field(default=default, metadata=dict(given=True))


class Section:
    """Base of every section: `check` holds the rules across its knobs (and against the sections read
    before it, in `context`), raising ParamError; it returns the section, with derived fields filled. The
    parser runs it, not `__post_init__`: `dataclasses.replace` (a site's radar, a run's rule) builds a
    section without the other sections its rules read."""

    def check(self, path: str, context: Mapping[str, Any]) -> Any:
        return self


class Tracked(Mapping):
    """A mapping of the params tree that remembers which of its keys the parser read.

    The parser's reads are the one list of known keys: whatever it never read is a key nobody
    uses (a misspelt `sigma_rnage_m` beside the real `sigma_range_m`, which would otherwise
    leave the run on the old value without a word). Iterating a section reads all of its
    keys, because the parser iterates only sections whose keys the user names (aircraft
    types, splits, aircraft mixes)."""

    def __init__(self, tree: Mapping[Any, Any], path: str) -> None:
        self._tree = tree
        self._path = path
        self._values = {key: _tracked(value, f"{path}.{key}" if path else str(key)) for key, value in tree.items()}
        self._read: set[Any] = set()

    def __getitem__(self, key: Any) -> Any:
        value = self._values[key]
        self._read.add(key)
        return value

    def __iter__(self) -> Iterator[Any]:
        self._read.update(self._values)
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __repr__(self) -> str:
        return repr(self._tree)

    def unread(self) -> list[str]:
        """'<path> = <value>: unknown key (did you mean <nearest read key>?)' for every key never read."""
        problems = []
        for key, value in self._values.items():
            if key in self._read:
                for child in value if isinstance(value, list) else [value]:
                    if isinstance(child, Tracked):
                        problems += child.unread()
                continue
            near = difflib.get_close_matches(str(key), [str(known) for known in self._read], n=1)
            hint = f"did you mean {near[0]}?" if near else f"known: {', '.join(sorted(map(str, self._read)))}"
            path = f"{self._path}.{key}" if self._path else str(key)
            problems.append(f"{path} = {self._tree[key]!r}: unknown key ({hint})")
        return problems


def _tracked(value: Any, path: str) -> Any:
    if isinstance(value, Mapping):
        return Tracked(value, path)
    if isinstance(value, list):
        return [_tracked(item, f"{path}[{index}]") for index, item in enumerate(value)]
    return value


def get(tree: Any, key: str, path: str) -> Any:
    """`tree[key]`; ParamError '<path>.<key>: missing' (the top level's path: params)."""
    if not isinstance(tree, Mapping) or key not in tree:
        raise ParamError(f"{path or 'params'}.{key}: missing")
    return tree[key]


def is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def interval_text(meta: Mapping[str, Any]) -> str:
    return f"{'(' if meta['open_low'] else '['}{meta['low']}, {meta['high']}{')' if meta['open_high'] else ']'}"


def inside(value: float, meta: Mapping[str, Any]) -> bool:
    low, high = meta["low"], meta["high"]
    return low <= value <= high and not (meta["open_low"] and value == low or meta["open_high"] and value == high)


def number(value: Any, path: str, meta: Mapping[str, Any], whole: bool = False) -> Any:
    """A finite number within the knob's bounds ('<path> = <value>: must be in [low, high]'); an integer
    (never a bool) when `whole`, '>= low' and 'at most high'."""
    if whole:
        if isinstance(value, bool) or not isinstance(value, int) or not inside(value, meta):
            most = f" and at most {meta['high']}" if meta["high"] < INF else ""
            text = f"must be an integer >= {meta['low']}{most}"
            raise ParamError(f"{path} = {value!r}: {meta['why'] or text}")
        return value
    if not is_number(value):
        raise ParamError(f"{path} = {value!r}: must be a finite number")
    if not inside(value, meta):
        raise ParamError(f"{path} = {value!r}: {meta['why'] or 'must be in ' + interval_text(meta)}")
    return float(value)


def _pair(value: Any, path: str, meta: Mapping[str, Any], whole: bool) -> tuple:
    """An ordered [lower, upper] pair: each at least `low` (checked as `<path>.lower`), then the whole pair
    in the knob's interval ('must lie in'), whole numbers when the annotation says int."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ParamError(f"{path} = {value!r}: must be a [lower, upper] pair")
    closed = dict(meta, high=INF, open_low=False, open_high=False, why="")
    lower, upper_ = (number(item, f"{path}.{end}", closed) for item, end in zip(value, ("lower", "upper")))
    if lower > upper_:
        raise ParamError(f"{path} = {value!r}: lower bound {lower} is above upper bound {upper_}")
    if whole and (lower != int(lower) or upper_ != int(upper_)):
        raise ParamError(f"{path} = {[lower, upper_]}: must be whole numbers, at least {meta['low']:g}")
    if not (inside(lower, meta) and inside(upper_, meta)):
        text = f"({meta['low']:g}, {meta['high']}]" if meta["open_low"] else interval_text(meta)
        raise ParamError(f"{path} = {[lower, upper_]}: {meta['why'] or 'must lie in ' + text}")
    return (int(lower), int(upper_)) if whole else (lower, upper_)


def _numbers(value: Any, path: str, meta: Mapping[str, Any], whole: bool) -> tuple:
    """A non-empty list of numbers in the knob's bounds (of exactly `count` when it is given)."""
    count = meta["count"]
    fits = isinstance(value, list) and bool(value) and (not count or len(value) == count) and all(
        (isinstance(v, int) if whole else is_number(v)) and not isinstance(v, bool) and inside(v, meta) for v in value)
    if not fits:
        kind = "integers" if whole else "numbers"
        adjective = {(0, True): "positive", (0, False): "non-negative"}.get((meta["low"], meta["open_low"]), "")
        what = f"{adjective} {kind}" if meta["high"] == INF and adjective else f"{kind} in {interval_text(meta)}"
        words = {1: "one", 2: "two"}
        text = f"must be {words.get(count, count)} {what}" if count else f"must list {what}"
        raise ParamError(f"{path} = {value!r}: {meta['why'] or (text[:-1] if count == 1 else text)}")
    return tuple(value if whole else (float(v) for v in value))


def _names(value: Any, path: str, meta: Mapping[str, Any]) -> tuple:
    """A list of names (of `choices`, each once, when the knob gives them)."""
    choices = meta["choices"]
    if not isinstance(value, list) or (choices and (not all(isinstance(v, str) and v in choices for v in value)
                                                    or len(set(value)) != len(value))):
        text = f"must list distinct names of {choices}" if choices else "must be a list of names"
        raise ParamError(f"{path} = {value!r}: {meta['why'] or text}")
    return tuple(value)


WEIGHT = {"low": 0.0, "high": INF, "open_low": False, "open_high": False, "why": ""}


def _weights(value: Any, path: str, known: list[str], what: str) -> dict[str, float]:
    """A mapping of some of `known` names to weights >= 0, not all zero (an aircraft mix, strategy weights)."""
    if not isinstance(value, Mapping) or not value:
        raise ParamError(f"{path} = {value!r}: must map {what}s to weights")
    for name in value:
        if name not in known:
            raise ParamError(f"{path}.{name}: unknown {what} (known: {sorted(known)})")
    weights = {name: number(value[name], f"{path}.{name}", WEIGHT) for name in value}
    if sum(weights.values()) <= 0.0:
        raise ParamError(f"{path} = {weights}: weights must not all be zero")
    return weights


def weights_of(known: str | tuple[str, ...], what: str) -> Callable:
    """A reader of weights over `known` names (a tuple, or the name of a section read before, whose keys they are)."""
    def read(tree: Mapping[str, Any], key: str, path: str, context: Mapping[str, Any]) -> dict[str, float]:
        names = list(context[known]) if isinstance(known, str) else list(known)
        return _weights(get(tree, key, path), f"{path}.{key}", names, what)
    return read


def _section_of(kind: Any) -> type | None:
    return kind if isinstance(kind, type) and dataclasses.is_dataclass(kind) else None


def value_of(kind: Any, meta: Mapping[str, Any], tree: Any, key: str, path: str, context: Mapping[str, Any]) -> Any:
    """The field of type `kind` (its annotation) read from `tree[key]` as its declaration says."""
    here = f"{path}.{key}" if path else key
    if meta["read"] is not None:
        return meta["read"](tree, key, path, context)
    if meta["keys"]:
        inner = typing.get_args(kind)[1]
        return {name: value_of(inner, dict(meta, keys=()), tree, name, path, dict(context, entry=name))
                for name in meta["keys"]}
    value = get(tree, key, path)
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if meta["pair"]:
        return _pair(value, here, meta, whole=(args[0] if origin is tuple else kind) is int)
    if kind is bool:
        if not isinstance(value, bool):
            raise ParamError(f"{here} = {value!r}: must be true or false")
        return value
    if kind in (int, float):
        return number(value, here, meta, whole=kind is int)
    if kind is str or (origin in (typing.Union, types.UnionType) and str in args):
        if meta["choices"] and value not in meta["choices"]:
            raise ParamError(f"{here} = {value!r}: {meta['why'] or 'must be one of ' + repr(meta['choices'])}")
        if not isinstance(value, str) or not value:
            raise ParamError(f"{here} = {value!r}: must be a non-empty string")
        return value
    if _section_of(kind):
        return parse_section(kind, value, here, context)
    if origin is tuple and _section_of(args[0]):
        return _entries(args[0], value, here, context)
    if origin is tuple and args[0] is str:
        return _names(value, here, meta)
    if origin is tuple:
        return _numbers(value, here, meta, whole=args[0] is int)
    if _section_of(args[1]):
        return _named(args[1], value, here, context)
    raise TypeError(f"{here}: no reader for the annotation {kind!r}")  # a declaration this parser cannot read


def _named(cls: type, value: Any, path: str, context: dict[str, Any]) -> dict[str, Any]:
    """Sections the user names (aircraft types, splits): a non-empty mapping, each entry given its name."""
    if not isinstance(value, Mapping) or not value:
        raise ParamError(f"{path} = {value!r}: must name at least one {cls.__name__.lower()} (a mapping of names "
                         "to sections)")
    return {name: parse_section(cls, value[name], f"{path}.{name}", context, dict(name=name)) for name in value}


def is_named(cls: type) -> bool:
    """Whether the user names the section's entries (its `name` is given): aircraft types, splits."""
    return any(field.name == "name" and field.metadata.get("given") for field in dataclasses.fields(cls))


def _entries(cls: type, value: Any, path: str, context: dict[str, Any]) -> tuple:
    """A list of sections, each a mapping (of named ones when the section's `name` is given)."""
    if is_named(cls):
        return tuple(_named(cls, value, path, context).values())
    keys = ", ".join(field.name for field in dataclasses.fields(cls) if not field.metadata.get("given"))
    if not isinstance(value, list):
        raise ParamError(f"{path} = {value!r}: must be a list of {{{keys}}}")
    sections = []
    for index, entry in enumerate(value):
        if not isinstance(entry, Mapping):
            raise ParamError(f"{path}[{index}] = {entry!r}: must be a mapping {{{keys}}}")
        sections.append(parse_section(cls, entry, f"{path}[{index}]", context))
    return tuple(sections)


@functools.cache
def hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def key_of(field: dataclasses.Field, kind: Any) -> str:
    """A field's params.yaml key: its declared `key`, a split pair's name less `_min` (speed_min_mps: speed_mps)."""
    split_pair = field.metadata["pair"] and typing.get_origin(kind) is not tuple
    return field.metadata["key"] or (field.name.replace("_min", "", 1) if split_pair else field.name)


def _read_field(field: dataclasses.Field, kind: Any, tree: Any, path: str, context: dict[str, Any]) -> Any:
    """A knob's value: its key found (through the parents of a dotted key), its default when it is absent."""
    meta = field.metadata
    if isinstance(meta["low"], str):  # a bound that is another section's knob: windows.autoencoder_length
        section, name = meta["low"].split(".")
        meta = dict(meta, low=getattr(context[section], name))
    *parents, key = key_of(field, kind).split(".")
    for parent in parents:
        tree, path = get(tree, parent, path), f"{path}.{parent}" if path else parent
    if field.default is not dataclasses.MISSING and (not isinstance(tree, Mapping) or key not in tree):
        return field.default
    return value_of(kind, meta, tree, key, path, context)


def build(cls: type, tree: Any, path: str, context: dict[str, Any], supplied: Mapping[str, Any] = {}) -> Any:
    """The section `cls` read field by field from `tree`, unchecked: its `given()` fields from `supplied`
    (else their default); at the top level each field is also put in `context`, for the sections after it."""
    if not isinstance(tree, Mapping):
        raise ParamError(f"{path} = {tree!r}: must be a mapping of {cls.__name__} keys")
    kinds, values, pending = hints(cls), {}, None
    for field in dataclasses.fields(cls):
        meta = field.metadata
        if meta.get("given"):
            values[field.name] = supplied.get(field.name, field.default)
        elif meta.get("upper"):
            values[field.name] = pending
        elif meta["only"] and context.get("entry") not in meta["only"]:
            values[field.name] = meta["otherwise"]
        else:
            value = _read_field(field, kinds[field.name], tree, path, context)
            if meta["pair"] and not typing.get_origin(kinds[field.name]):
                value, pending = value
            values[field.name] = value
        if not path:
            context[field.name] = values[field.name]
    return cls(**values)


def parse_section(cls: type, tree: Any, path: str, context: dict[str, Any], supplied: Mapping[str, Any] = {}) -> Any:
    """The section `cls` read from `tree` (`build`) and checked (`Section.check`)."""
    return build(cls, tree, path, context, supplied).check(path, context)


def declared(cls: type, path: str = "", entry: str | None = None) -> Iterator[tuple[str, dataclasses.Field, Any]]:
    """(params.yaml key, field, annotation) of every knob of `cls` and of its sections, depth first; a
    mapping of user-named entries as `<name>`, a list's entries as `[]`. `given` and `upper` fields are none,
    but a given section's knobs are keys of the entry (fusion.radars[]: any key of radar)."""
    kinds = hints(cls)
    for field in dataclasses.fields(cls):
        meta, kind = field.metadata, kinds[field.name]
        if meta.get("given") and _section_of(kind):
            yield from declared(kind, path)
        if meta.get("given") or meta.get("upper") or (meta["only"] and entry not in meta["only"]):
            continue
        keys = [f"{path}.{key}" if path else key for key in (meta["keys"] or [key_of(field, kind)])]
        args = typing.get_args(kind)
        inner = _section_of(kind) or next((arg for arg in args if _section_of(arg)), None)
        for key in keys:
            yield key, field, kind
            if inner is not None:
                tail = "" if _section_of(kind) or meta["keys"] else ".<name>" if is_named(inner) else "[]"
                yield from declared(inner, key + tail, key.rsplit(".", 1)[-1] if meta["keys"] else None)


class ParamsLoader(yaml.SafeLoader):
    """PyYAML's safe loader, reading floats as YAML 1.2 does.

    DVC writes params.yaml as YAML 1.2: `dvc exp run -S training.predictor.learning_rate=0.000001`
    gives `learning_rate: 1e-06`, which YAML 1.1 (PyYAML) takes for a string. Every float
    YAML 1.2 accepts (1e-06, 2e-3, 1E-4, -.5, 5.) is read as a float here; plain integers still
    resolve as integers, because the float pattern needs a point or an exponent."""


ParamsLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:(?:[0-9]+\.[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?|[0-9]+[eE][-+]?[0-9]+)$"),
    list("-+0123456789."))


def load_params_tree(path: str | Path = "params.yaml") -> dict[str, Any]:
    """The params file as a plain tree, read as DVC reads it (see ParamsLoader), not validated."""
    path = Path(path)
    try:
        tree = yaml.load(path.read_text(), Loader=ParamsLoader)
    except FileNotFoundError:
        raise ParamError(f"{path}: params file not found") from None
    except (OSError, UnicodeDecodeError) as error:  # a folder, an unreadable file, a binary file
        raise ParamError(f"{path}: not a readable params file ({type(error).__name__}: {error})") from None
    except yaml.YAMLError as error:
        raise ParamError(f"{path}: not valid YAML ({error})") from None
    if not isinstance(tree, Mapping):
        raise ParamError(f"{path}: must hold a mapping of sections, got {type(tree).__name__}")
    return tree

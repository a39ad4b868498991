"""Every knob declared once: each key of params.yaml has a declaration with a doc (and bounds where it is a
number), each declaration a key in params.yaml, and docs/params.md is written from them as they are."""

from __future__ import annotations

import dataclasses
from typing import Any, Iterator, Mapping

import pytest

from pipeline.params import Params, Radar, load_params_tree
from pipeline.params.declare import INF, declared
from pipeline.reports.params_reference import reference, values_at
from tests.project import REPOSITORY, run_pipeline

TREE = load_params_tree(REPOSITORY / "params.yaml")
DECLARED = {key: field for key, field, _ in declared(Params)}
USER_NAMED = ("aircraft", "routes.splits")  # mappings whose keys the user names: `<name>` in the declarations
# a fusion radar may change any key of `radar` (each is declared there); params.yaml changes some
OVERLAID = {f"fusion.radars[].{field.name}" for field in dataclasses.fields(Radar)}


def yaml_keys(tree: Any, path: str = "") -> Iterator[str]:
    """Every key of params.yaml as the declarations write it (`<name>` for a user-named entry, `[]` for a list's
    entries); a knob's own value (a mapping of weights, a list of names) is not walked."""
    if path in DECLARED and not _holds_sections(path):
        return
    if isinstance(tree, Mapping):
        for key, value in tree.items():
            child = f"{path}.<name>" if path in USER_NAMED else f"{path}.{key}" if path else str(key)
            if path not in USER_NAMED:
                yield child
            yield from yaml_keys(value, child)
    elif isinstance(tree, list) and _holds_sections(path):
        for entry in tree:
            yield from yaml_keys(entry, f"{path}[]")


def _holds_sections(path: str) -> bool:
    """Whether the declared key `path` (or a section above it that is no key) holds sections of knobs."""
    if path not in DECLARED:
        return True  # `simulate`, `report`, `compute`: mappings of top-level knobs
    return any(key.startswith((path + ".", path + "[]")) for key in DECLARED)


def test_every_key_of_params_yaml_is_declared() -> None:
    undeclared = sorted(set(yaml_keys(TREE)) - set(DECLARED) - {"simulate", "report", "compute"})
    assert undeclared == []


def test_every_declaration_has_a_key_in_params_yaml() -> None:
    assert sorted(key for key in DECLARED if not values_at(TREE, key) and key not in OVERLAID) == []


def is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@pytest.mark.parametrize("key", sorted(DECLARED))
def test_every_declaration_has_a_doc_and_a_number_its_bounds(key: str) -> None:
    """A knob whose value in params.yaml is a number (or a list or pair of them) declares its bounds."""
    meta = DECLARED[key].metadata
    assert meta["doc"].strip(), f"{key}: no doc"
    values = values_at(TREE, key)
    numeric = values and all(is_number(v) or (isinstance(v, list) and v and all(map(is_number, v))) for v in values)
    if numeric and meta["low"] == -INF and meta["high"] == INF:
        assert key.split(".")[-1] in UNBOUNDED, f"{key}: a number without bounds"


# numbers that may take any finite value: a decibel level and the registration biases (either sign)
UNBOUNDED = {"reference_snr_db", "bias_range_m", "bias_azimuth_deg", "bias_east_m", "bias_north_m"}


def test_the_params_reference_is_current() -> None:
    """docs/params.md is what `python -m pipeline params-reference` writes; `--check` says so (exit 0)."""
    assert (REPOSITORY / "docs" / "params.md").read_text() == reference(TREE)
    result = run_pipeline("params-reference", "--check")
    assert result.returncode == 0, result.stderr


def test_a_stale_reference_is_named_and_exit_1(tmp_path) -> None:
    stale = tmp_path / "params.md"
    stale.write_text("# Params reference\n")
    result = run_pipeline("params-reference", "--out", str(stale), "--check")
    assert result.returncode == 1 and f"{stale}: out of date" in result.stderr
    assert stale.read_text() == "# Params reference\n"
    assert run_pipeline("params-reference", "--out", str(stale)).returncode == 0
    assert stale.read_text() == reference(TREE)

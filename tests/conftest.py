"""Shared fixtures: the default params tree, and small params built from it."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Callable, Mapping

import pytest
import yaml

from pipeline.params import Params, parse_params

PARAMS_YAML = Path(__file__).resolve().parents[1] / "params.yaml"
_DEFAULT_TREE = yaml.safe_load(PARAMS_YAML.read_text())


@pytest.fixture
def params_tree() -> dict[str, Any]:
    """The default params.yaml as read by yaml.safe_load; a fresh copy for each test to edit."""
    return copy.deepcopy(_DEFAULT_TREE)


@pytest.fixture(scope="session")
def make_params() -> Callable[..., Params]:
    """Build validated params from the defaults with few routes, e.g.
    ``make_params(2, {"routes.start_spread_s": 0.0})``: 2 routes per strategy and split, one key changed."""

    def make(routes_per_strategy: int = 3, changes: Mapping[str, Any] | None = None) -> Params:
        tree = copy.deepcopy(_DEFAULT_TREE)
        for split in tree["routes"]["splits"].values():
            split["constant_jerk"] = split["random_turns"] = routes_per_strategy
        for dotted, value in (changes or {}).items():
            *parents, key = dotted.split(".")
            node = tree
            for parent in parents:
                node = node[parent]
            node[key] = value
        return parse_params(tree)

    return make

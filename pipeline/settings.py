"""The one checked loader of params.yaml: params' parser, and the names each registry owns.

`pipeline.params` is the ground floor and imports nothing of the package, so it cannot know which
tracking methods, track management rules, track-to-track associators or fusion criteria exist. Each
owner checks its own names (`check_params`: the tracker's registry, the association registry,
`track_fusion`), and this module, above them all, hands those checks to the parser. Every command,
benchmark and test that reads params reads them through here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from pipeline.association import registry as associators
from pipeline.association import track_fusion
from pipeline.params import ParamError, Params, load_params_tree, parse_tree
from pipeline.tracker import registry

NAME_CHECKS = (registry.check_params, associators.check_params, track_fusion.check_params)


def parse_params(tree: Mapping[str, Any]) -> Params:
    """Validate a params tree (as read from YAML), every registry's names included."""
    return parse_tree(tree, NAME_CHECKS)


def load_params(path: str | Path = "params.yaml") -> Params:
    """Read and validate a params file; errors name the file, the key and the value."""
    tree = load_params_tree(path)
    try:
        return parse_params(tree)
    except ParamError as error:
        raise ParamError(f"{path}: {error}") from None

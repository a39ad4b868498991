"""The one list of track-to-track association methods: each name, how its associator is built, what it needs.

A method is a name (what params' `fusion.methods`, `associate --method` and the association reports use), a
builder of its associator (`pipeline.association.associator.Associator`) from params `association` and, for
the network, the trained association network (`models/association_net.pt`, `needs_network`). Params
validation, the `associate` command's choices, `table_association.decide` (the `associate` command, the fusion
stage and its bias sweep) and the association report (`association_report`) read the names from here; nothing
else lists them. A new method is one associator class and one entry here, as a tracking method is one entry of
`pipeline.tracker.registry`.

The associators are imported inside the builders, so naming or validating a method loads neither scipy nor torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

from pipeline.params import ParamError

if TYPE_CHECKING:
    from pipeline.association.association_net import AssociationNet
    from pipeline.association.associator import Associator
    from pipeline.params import Association, Params


class UnknownAssociator(ValueError):
    """A track-to-track method name that is not registered; the message lists the registered ones."""


@dataclass(frozen=True)
class AssociationMethod:
    """One track-to-track method: `build(association, network)` gives its associator; `needs_network`: it reads
    the trained association network (given None, the others ignore it)."""

    name: str
    build: Callable[["Association", "AssociationNet | None"], "Associator"]
    needs_network: bool = False


def _statistical(association: "Association", network: "AssociationNet | None") -> "Associator":
    from pipeline.association.track_association import StatisticalAssociator
    return StatisticalAssociator(association.gate_probability)


def _double_threshold(association: "Association", network: "AssociationNet | None") -> "Associator":
    """Over the last track_points - 1 common times: a track segment's common times (`association_scenes`)."""
    from pipeline.association.track_association import DoubleThresholdAssociator
    return DoubleThresholdAssociator(association.gate_probability, association.double_threshold_hits,
                                     association.track_points - 1)


def _bias_robust(association: "Association", network: "AssociationNet | None") -> "Associator":
    from pipeline.association.bias_robust_association import BiasRobustAssociator
    return BiasRobustAssociator(association.gate_probability, association.max_bias_m, association.vote_radius_m,
                                association.max_iterations, association.max_time_offset_s)


def _network(association: "Association", network: "AssociationNet | None") -> "Associator":
    from pipeline.association.association_net import NetworkAssociator
    return NetworkAssociator(network, association.decision_threshold)


ASSOCIATORS: dict[str, AssociationMethod] = {method.name: method for method in [
    AssociationMethod("statistical", _statistical),
    AssociationMethod("double_threshold", _double_threshold),
    AssociationMethod("bias_robust", _bias_robust),
    AssociationMethod("network", _network, needs_network=True),
]}
NAMES = tuple(ASSOCIATORS)  # every way to associate two radars' tracks, in the reports' order


def associator(name: str, association: "Association", network: "AssociationNet | None") -> "Associator":
    """The associator of method `name` with params `association`'s knobs (and `network`, for the network's);
    UnknownAssociator names the registered methods."""
    found = ASSOCIATORS.get(name)
    if found is None:
        raise UnknownAssociator(f"track-to-track association method {name!r}: must be one of {list(ASSOCIATORS)}")
    return found.build(association, network)


def needs_network(names: list[str] | tuple[str, ...]) -> bool:
    """Whether any of the methods `names` reads the trained association network."""
    return any(ASSOCIATORS[name].needs_network for name in names)


def check_params(params: "Params") -> None:
    """The fusion stage's association methods: distinct names of NAMES, at least one (ParamError)."""
    methods = list(params.fusion.methods)
    if not methods or not set(methods) <= set(NAMES) or len(set(methods)) != len(methods):
        raise ParamError(f"fusion.methods = {methods!r}: must list distinct methods of {NAMES}")

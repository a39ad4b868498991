"""The one list of tracking methods: each name, its composition of roles, and what it needs.

A method is a name (what params' `evaluate.runs`, `track --method` and the reports use), a
label for the tables, a family (`neural`, `classical`, or `reference` for the oracle, which is
given the true association and is run only as an evaluation reference), the pieces it loads
(`pipeline.tracker.loading`: the `predictor`, `filter` and `autoencoder` networks, the tuned
classical filters `kalman_tuned`, the network-scaled filter `kalman_net`), and `compose`, which
builds its tracker (`pipeline.tracker.run.Composition`) from the loaded pieces, the tracker
params, the window (metres: the VIA window, the young-track radius of every method) and a seed
(MIA's sampling). A compose function reads each piece as `models[name]`
(`pipeline.tracker.models`; the pieces' files and loaders are `pipeline.learning.kinds.PIECES`).

Params validation, the evaluate and compare stages, the tables and `track` read the names from
here; nothing else lists methods. Adding a method is one entry here (and the modules of its
parts); docs/architecture.md has a worked example.

Track management is composed the same way: `MANAGEMENT` names the rules (`thesis`, the default
of every method, `m_of_n` and `sprt`), and `compose(..., management_rule=...)` runs any method under any.

The implementations are imported inside the compose functions, so naming or validating a method
loads no network library.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

from pipeline.params import ParamError

if TYPE_CHECKING:
    from collections.abc import Iterable

    from pipeline.params import Params, TrackerParams
    from pipeline.tracker.assigner import Assigner
    from pipeline.tracker.estimator import Estimator
    from pipeline.tracker.gate import Gate
    from pipeline.tracker.management import TrackManagement
    from pipeline.tracker.models import Models
    from pipeline.tracker.network_estimator import NetworkEstimator
    from pipeline.tracker.run import Composition

NEURAL, CLASSICAL, REFERENCE = "neural", "classical", "reference"
NETWORKS = ("predictor", "filter")  # the estimator of every neural method
TUNED_FILTERS = "kalman_tuned"
LSTM_UPDATE = "lstm_update"  # the LSTM update on a Kalman prediction (models/lstm_update.pt)
KALMAN_NET = "kalman_net"  # the network-scaled Kalman filter (issue 17)
GLOBAL_SUFFIX = "_gnn"  # a method with scan-wise global-nearest-neighbour association
JPDA_SUFFIX = "_jpda"   # ... with scan-wise joint probabilistic data association (the classical filters)
NOT_MATURE = 1 << 62    # `mature_from` of a method whose tracks all stay young

Seed = int | list[int]
THESIS_RULE, M_OF_N_RULE, SPRT_RULE, LEARNED_RULE = "thesis", "m_of_n", "sprt", "learned"
MANAGEMENT = (THESIS_RULE, M_OF_N_RULE, SPRT_RULE, LEARNED_RULE)  # track management rules (`tracker.management.rule`,
                                                                  # a run's `management`)
CONFIRMATION = "confirmation"  # the learned rule's network (models/confirmation.pt, the train_confirmation stage)


class UnknownMethod(ValueError):
    """A method name that is not registered; the message lists the registered ones."""


@dataclass(frozen=True)
class Method:
    """One tracking method. `filter_kind`: the tuned classical filter it runs (one of `kalman.filters`), if any.
    `relative_cost`: rough tracking time per plot relative to `via`, measured on the default test
    split; only the order in which the evaluate stage hands out work depends on it."""

    name: str
    label: str
    family: str
    needs: tuple[str, ...]
    compose: Callable[["Models", "TrackerParams", float, Seed], "Composition"]
    relative_cost: float
    filter_kind: str | None = None


def _composition(label: str, estimator: "Estimator", gate: "Gate", mature_from: int, window_m: float,
                 params: "TrackerParams", assigner: "Assigner | None" = None, prefilter_m: float | None = None,
                 young_gate: "Gate | None" = None, learned: tuple[bool, bool] = (False, False)) -> "Composition":
    """A composition with the defaults every method shares: the young-track radius gate, the
    pre-filter distance of params, nearest neighbour per plot, the tracker's management rule, its
    association priority (`tracker.association.mature_first`) and its revisit limit
    (`tracker.association.revisit_scans`).
    `learned`: whether its (young, mature) gate is learned, sized by a network's output; such a
    composition counts the plots its learned gates refuse that the window would take
    (`pipeline.tracker.refusals`)."""
    from pipeline.tracker.assigner import NearestPerPlot
    from pipeline.tracker.gate import RadiusGate
    from pipeline.tracker.refusals import RefusalWatch
    from pipeline.tracker.run import Composition
    gating = params.association
    return Composition(label, estimator, gate, young_gate or RadiusGate(window_m), "radius", mature_from,
                       gating.prefilter_m if prefilter_m is None else prefilter_m, assigner or NearestPerPlot(),
                       management(THESIS_RULE, params), gating.mature_first,
                       refusals=RefusalWatch(window_m, *learned) if any(learned) else None,
                       revisit_scans=gating.revisit_scans)


def _network_estimator(models: "Models") -> "NetworkEstimator":
    from pipeline.tracker.network_estimator import NetworkEstimator
    return NetworkEstimator(models)


def _radius(models: "Models", params: "TrackerParams", window_m: float, seed: Seed) -> "Composition":
    from pipeline.tracker.gate import RadiusGate
    return _composition("radius", _network_estimator(models), RadiusGate(window_m), NOT_MATURE, window_m, params)


def _via(models: "Models", params: "TrackerParams", window_m: float, seed: Seed) -> "Composition":
    from pipeline.tracker.gate import WindowGate
    return _composition("via", _network_estimator(models), WindowGate(window_m), params.association.young_track_plots,
                        window_m, params)


def _mia(models: "Models", params: "TrackerParams", window_m: float, seed: Seed) -> "Composition":
    from pipeline.tracker.network_gates import MonteCarloGate
    estimator = _network_estimator(models)
    return _composition("mia", estimator, MonteCarloGate(estimator, params.mia, seed),
                        params.association.young_track_plots, window_m, params, learned=(False, True))


def _ae(models: "Models", params: "TrackerParams", window_m: float, seed: Seed) -> "Composition":
    from pipeline.tracker.network_gates import AutoencoderGate
    return _composition("ae", _network_estimator(models),
                        AutoencoderGate(models["autoencoder"], models.runnable["autoencoder"]),
                        params.association.young_track_plots_ae, window_m, params, learned=(False, True))


def _assigner(association: str, params: "TrackerParams") -> "Assigner | None":
    """The assigner of a method's `association` suffix: None (nearest neighbour per plot, the default) for
    '', global nearest neighbour per scan for GLOBAL_SUFFIX, JPDA per scan for JPDA_SUFFIX (with the knobs
    `tracker.association.jpda_*` and the chi-square gate's probability)."""
    from pipeline.tracker.assigner import GlobalNearestPerScan
    from pipeline.tracker.jpda import JointProbabilisticPerScan
    gating = params.association
    if association == GLOBAL_SUFFIX:
        return GlobalNearestPerScan()
    if association == JPDA_SUFFIX:
        return JointProbabilisticPerScan(gating.jpda_detection_probability, gating.kalman_gate_probability,
                                         gating.jpda_clutter_density_per_m3)
    return None


def _classical(name: str, kind: str, association: str):
    """A tuned filter of `kind` with the chi-square gate, under the assigner of `association` (`_assigner`)."""
    def compose(models: "Models", params: "TrackerParams", window_m: float, seed: Seed) -> "Composition":
        from pipeline.tracker.gate import ChiSquareGate
        from pipeline.tracker.kalman import KalmanEstimator
        gating = params.association
        return _composition(name, KalmanEstimator(models[TUNED_FILTERS][kind]),
                            ChiSquareGate(gating.kalman_gate_probability), gating.young_track_plots, window_m, params,
                            assigner=_assigner(association, params))
    return compose


def _lstm_update(global_nearest: bool):
    """The LSTM update on a CA Kalman prediction (issue 18), the chi-square gate on its MC-dropout covariance,
    young tracks too: the prediction from a track's first plot is calibrated for the gate like any other
    (`lstm_update.calibrate`, age 1: the copies' start velocities), so a one-plot track is gated by its own
    covariance rather than the `window_m` ball, which let clutter through to confirmed tracks (issue 18);
    and never beyond `tracker.lstm_update.gate_m` of the prediction (`BoundedChiSquareGate`). The start
    velocities span the training's speeds, so a faster target's second plot falls outside every young
    gate and each plot starts a track (issue 27): with `tracker.lstm_update.young_window_fallback` the young gate
    also takes what the `window_m` ball takes (`RadiusFloorGate`), as every other method's does. Nearest
    neighbour per plot (the thesis's association) or, `global_nearest`, per antenna scan (issue 29: a scan's
    mature tracks step through the LSTM in one call)."""
    def compose(models: "Models", params: "TrackerParams", window_m: float, seed: Seed) -> "Composition":
        from pipeline.tracker.assigner import GlobalNearestPerScan
        from pipeline.tracker.gate import BoundedChiSquareGate, RadiusFloorGate
        from pipeline.tracker.lstm_update_estimator import LSTMUpdateEstimator
        gate = BoundedChiSquareGate(params.association.kalman_gate_probability,
                                    params.lstm_update.gate_m)
        young_gate = RadiusFloorGate(gate, window_m) if params.lstm_update.young_window_fallback else gate
        estimator = LSTMUpdateEstimator(models[LSTM_UPDATE], seed, runtime=params.learned_runtime,
                                        device=params.device)
        return _composition(LSTM_UPDATE + GLOBAL_SUFFIX if global_nearest else LSTM_UPDATE, estimator, gate,
                            params.association.young_track_plots, window_m, params, young_gate=young_gate,
                            assigner=GlobalNearestPerScan() if global_nearest else None, learned=(True, True))
    return compose


def _kalman_net(name: str, association: str):
    """The network-scaled filter with the chi-square gate on its own scales; nearest neighbour per plot
    (`association` ''), global nearest neighbour per scan (GLOBAL_SUFFIX) or JPDA per scan (JPDA_SUFFIX)."""
    def compose(models: "Models", params: "TrackerParams", window_m: float, seed: Seed) -> "Composition":
        from pipeline.tracker.kalman_net_estimator import KalmanNetEstimator, PlotScaledGate
        estimator = KalmanNetEstimator(models[KALMAN_NET], runtime=params.learned_runtime, device=params.device)
        return _composition(name, estimator, PlotScaledGate(estimator, params.association.kalman_gate_probability),
                            params.association.young_track_plots, window_m, params,
                            assigner=_assigner(association, params), learned=(False, True))
    return compose


def _oracle(models: "Models", params: "TrackerParams", window_m: float, seed: Seed) -> "Composition":
    """The tuned IMM given the true association: every live track a candidate, none gated."""
    from pipeline.tracker.assigner import TrueAssociation
    from pipeline.tracker.gate import AcceptAll
    from pipeline.tracker.kalman import KalmanEstimator
    return _composition("oracle", KalmanEstimator(models[TUNED_FILTERS]["imm"]), AcceptAll(), 1, window_m, params,
                        assigner=TrueAssociation(), prefilter_m=float("inf"))


def _classical_methods() -> list[Method]:
    methods = []
    for association, suffix_label, extra_cost in (("", "", 1.0), (GLOBAL_SUFFIX, " + GNN", 1.1),
                                                  (JPDA_SUFFIX, " + JPDA", 1.5)):
        for base, kind, label, cost in (("kalman_cv", "cv", "Kalman CV", 1.5), ("kalman_ca", "ca", "Kalman CA", 1.5),
                                        ("imm", "imm", "IMM", 2.0), ("imm_ct", "imm_ct", "IMM with turns", 3.0),
                                        ("imm_ca_ct", "imm_ca_ct", "IMM with CA and turns", 4.0)):
            methods.append(Method(base + association, label + suffix_label, CLASSICAL, (TUNED_FILTERS,),
                                  _classical(base + association, kind, association), cost * extra_cost, kind))
    return methods


METHODS: dict[str, Method] = {method.name: method for method in [
    Method("radius", "radius", NEURAL, NETWORKS, _radius, 0.7),
    Method("via", "VIA", NEURAL, NETWORKS, _via, 1.0),
    Method("mia", "MIA", NEURAL, NETWORKS, _mia, 2.2),
    Method("ae", "AE", NEURAL, (*NETWORKS, "autoencoder"), _ae, 1.0),
    *_classical_methods(),
    *(Method(name, label, NEURAL, (LSTM_UPDATE,), _lstm_update(gnn), cost)
      for name, label, gnn, cost in ((LSTM_UPDATE, "LSTM update", False, 3.0),
                                     (LSTM_UPDATE + GLOBAL_SUFFIX, "LSTM update + GNN", True, 3.0))),
    *(Method(KALMAN_NET + association, label, NEURAL, (KALMAN_NET,), _kalman_net(KALMAN_NET + association, association),
             cost)
      for association, label, cost in (("", "Network-scaled KF", 8.0),
                                       (GLOBAL_SUFFIX, "Network-scaled KF + GNN", 8.8),
                                       (JPDA_SUFFIX, "Network-scaled KF + JPDA", 10.0))),
    Method("oracle", "oracle (true association, IMM)", REFERENCE, (TUNED_FILTERS,), _oracle, 0.9, "imm"),
]}
TRACKERS = tuple(name for name, method in METHODS.items() if method.family != REFERENCE)
# the three families the results are told in (the README's headline): the thesis's networks (predictor and filter,
# with its association methods), the learned Kalman hybrids (a Kalman filter with a learned part), tuned classical
GROUPS = THESIS_NETWORKS, LEARNED_HYBRIDS, TUNED_CLASSICAL = ("the thesis's networks", "learned Kalman hybrids",
                                                              "tuned classical filters")


def group(name: str) -> str | None:
    """Which of GROUPS the method `name` belongs to (None for a reference, the oracle); UnknownMethod if none."""
    found = method(name)
    if found.family == REFERENCE:
        return None
    if found.family == CLASSICAL:
        return TUNED_CLASSICAL
    return LEARNED_HYBRIDS if set(found.needs) & {KALMAN_NET, LSTM_UPDATE} else THESIS_NETWORKS

REFERENCES = tuple(name for name, method in METHODS.items() if method.family == REFERENCE)
# the trackers whose updates carry a position covariance (what track-to-track association and fusion read): all
# but the thesis's networks, whose estimator (`network_estimator`, the predictor and filter) gives none
COVARIANCE_TRACKERS = tuple(name for name in TRACKERS if not set(METHODS[name].needs) & set(NETWORKS))
EVALUATION_REFERENCES = ("plots", *REFERENCES)  # evaluate.references: raw target plots, the registry's references


def check_params(params: "Params") -> None:
    """The names params gives that this registry owns (ParamError naming the key and the value): the
    tracker's management rule, every evaluation run's method and rule, the evaluation's references,
    and the fusion stage's local tracker, which must give covariances; and that the tuned filter each of
    these methods runs is one `kalman.filters` has `tune_kalman` tune, so a run that could not load stops
    the first stage, not the evaluation an hour later."""
    if params.tracker.management.rule not in MANAGEMENT:
        raise ParamError(f"tracker.management.rule = {params.tracker.management.rule!r}: must be one of {MANAGEMENT}")
    for index, run in enumerate(params.evaluate.runs):
        if run.method not in TRACKERS:
            raise ParamError(f"evaluate.runs[{index}].method = {run.method!r}: must be one of {TRACKERS}")
        if run.management is not None and run.management not in MANAGEMENT:
            raise ParamError(f"evaluate.runs[{index}].management = {run.management!r}: must be one of {MANAGEMENT}")
        _check_tuned(f"evaluate.runs[{index}].method", run.method, params)
    rules = {params.tracker.management.rule, *(run.management for run in params.evaluate.runs)}
    from pipeline.tracker.learned_confirmation import MAX_N
    if LEARNED_RULE in rules and params.tracker.management.confirm_n > MAX_N:
        raise ParamError(f"tracker.management.confirm_n = {params.tracker.management.confirm_n}: the learned rule "
                         f"keeps at most {MAX_N} opportunities")
    confirming = params.confirmation.method
    if confirming not in TRACKERS or not set(METHODS[confirming].needs) <= {TUNED_FILTERS}:
        raise ParamError(f"confirmation.method = {confirming!r}: must be a method that needs no network, one of "
                         f"{[name for name in TRACKERS if set(METHODS[name].needs) <= {TUNED_FILTERS}]}")
    _check_tuned("confirmation.method", confirming, params)
    references = list(params.evaluate.references)
    if any(name not in EVALUATION_REFERENCES for name in references):
        raise ParamError(f"evaluate.references = {references!r}: must list some of {EVALUATION_REFERENCES}")
    if params.fusion.tracker not in COVARIANCE_TRACKERS:  # a network's tracks would stop the stage after a scene
        without = [name for name in TRACKERS if name not in COVARIANCE_TRACKERS]
        raise ParamError(f"fusion.tracker = {params.fusion.tracker!r}: must be one of {COVARIANCE_TRACKERS} "
                         f"(association and fusion read each track's covariance; the networks of "
                         f"{', '.join(without)} give none)")
    _check_tuned("fusion.tracker", params.fusion.tracker, params)


def _check_tuned(key: str, name: str, params: "Params") -> None:
    kind = METHODS[name].filter_kind
    if kind is not None and kind not in params.kalman.filters:
        raise ParamError(f"{key} = {name!r}: runs the {kind} filter, which kalman.filters = "
                         f"{list(params.kalman.filters)} does not tune (list {kind} there)")


def method(name: str) -> Method:
    """The registered method `name`; UnknownMethod names the registered ones."""
    found = METHODS.get(name)
    if found is None:
        raise UnknownMethod(f"tracking method {name!r}: must be one of {list(METHODS)}")
    return found


def management(rule: str, params: "TrackerParams", models: "Models | None" = None) -> "TrackManagement":
    """The track management rule named `rule` (one of `MANAGEMENT`) with the tracker params'
    settings: `thesis`, the thesis's weights; `m_of_n`, M-of-N confirmation and a time-out; `sprt`, the
    sequential probability ratio test on hits and misses; `learned`, M-of-N with each hit weighed by the
    confirmation network of `models` (`rule_needs`), its threshold set by
    `management.learned_false_track_probability` (with no `models`: a rule that reads weights, and refuses to
    track). ValueError for another name, or `learned` with `models` that lack the network or hold one whose
    hold-out sums were taken over another window than `management.confirm_n`."""
    from pipeline.tracker.m_of_n import MOfN
    from pipeline.tracker.management import ThesisWeights
    from pipeline.tracker.sprt import SequentialRatioTest
    rules = {THESIS_RULE: ThesisWeights.from_params, M_OF_N_RULE: MOfN.from_params,
             SPRT_RULE: SequentialRatioTest.from_params}
    if rule == LEARNED_RULE:
        return _learned(params, models)
    if rule not in rules:
        raise ValueError(f"track management {rule!r}: must be one of {list(MANAGEMENT)}")
    return rules[rule](params.management)


def _learned(params: "TrackerParams", models: "Models | None") -> "TrackManagement":
    """The learned rule with `models`' confirmation network; with no `models`, one that reads weights (whether an
    update's track was confirmed: what scoring asks) and refuses to track."""
    from pipeline.tracker.learned_confirmation import LearnedConfirmation, threshold_for
    m = params.management
    if models is None:
        return LearnedConfirmation(m.confirm_n, math.inf, m.delete_after_s, m.delete_after_scans, _no_network)
    if CONFIRMATION not in models.pieces:
        _no_network()
    trained = models[CONFIRMATION]
    if trained.window != m.confirm_n:
        raise ValueError(f"the confirmation network's threshold sums were taken over {trained.window} opportunities, "
                         f"tracker.management.confirm_n is {m.confirm_n}: run `dvc repro train_confirmation` again")
    return LearnedConfirmation(m.confirm_n, threshold_for(trained.clutter_maxima, m.learned_false_track_probability),
                               m.delete_after_s, m.delete_after_scans, trained.scorer)


def _no_network(*_: object) -> float:
    raise ValueError(f"track management {LEARNED_RULE!r} needs the confirmation network (models/confirmation.pt, "
                     "`dvc repro train_confirmation`)")


def rule_needs(rules: "Iterable[str | None]") -> set[str]:
    """The pieces the management rules `rules` need (None: the tracker's own, which the caller resolves)."""
    return {CONFIRMATION} if LEARNED_RULE in set(rules) else set()


def compose(name: str, models: "Models", params: "TrackerParams", window_m: float, seed: Seed,
            management_rule: str | None = None) -> "Composition":
    """The tracker of method `name` for one run (its estimator keeps per-track state: one per run),
    under the track management rule `management_rule` (None: `params.management.rule`), which reads `models` where
    it needs a network (`rule_needs`)."""
    from dataclasses import replace
    composition = method(name).compose(models, params, window_m, seed)
    rule = params.management.rule if management_rule is None else management_rule
    return replace(composition, management=management(rule, params, models))


def needs(names: list[str]) -> set[str]:
    """The pieces the methods `names` need together."""
    return {piece for name in names for piece in method(name).needs}

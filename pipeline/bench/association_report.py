"""Scoring the track-to-track association methods on the seed's synthetic setting (issue 19, point 5).

Every method decides pairs on the same scenes (`association_scenes`, scene k of `eval_seed` for every bias,
so the biases differ only by the bias: common random numbers). Per method and bias length:
- accuracy: correct pairs / true pairs (issue 19's measure; the seed's "87.5 %" is read as this);
- false pairs: decided pairs that are not true pairs, per true pair;
- missed pairs: true pairs not decided, per true pair (1 - accuracy);
and the bias-robust method's offset error: mean length (m), and how often the true offset lies inside its
stated accuracy (squared Mahalanobis error under the chi-square 99 % quantile, 2 degrees of freedom: 0.99
expected when the stated accuracy holds).
The "seed setting" row draws each scene's bias length uniformly in `train_bias_m` (0-200 m), as the seed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from pipeline.association.association_net import (  # noqa: E402
    AssociationNet,
    AssociationNetConfig,
    SceneInputs,
    scene_inputs,
)
from pipeline.association.association_scenes import Scene, SceneSetting, make_scene  # noqa: E402
from pipeline.association.associator import Associator, TrackSet  # noqa: E402
from pipeline.association.registry import ASSOCIATORS, associator  # noqa: E402
from pipeline.figure_png import png  # noqa: E402
from pipeline.params import Association  # noqa: E402
from pipeline.sections import subset  # noqa: E402

BIAS_ESTIMATOR = "bias_robust"  # the method whose offset estimate the report scores
SEED_ACCURACY = 0.875          # the seed's reported accuracy on a new scene of its setting (section 4.2)
STATED_ACCURACY_PROBABILITY = 0.99


def scene_setting(a: Association, bias_m: tuple[float, float]) -> SceneSetting:
    """The seed's setting of params `association`, radar 2's bias length uniform in `bias_m`."""
    return subset(SceneSetting, a, bias_m=bias_m)


def network_config(a: Association) -> AssociationNetConfig:
    """The network of params `association` (its `scene_*` keys: the bundle's config keeps the network's names)."""
    return subset(AssociationNetConfig, a, size=a.scene_size, diameter_m=a.scene_diameter_m)


def inputs_of(scene: Scene, config: AssociationNetConfig) -> SceneInputs:
    """The network's inputs of a scene at its common time (the last of the history), labelled."""
    return scene_inputs(scene.states1[-1], scene.covariances1[-1], scene.states2[-1], scene.covariances2[-1], config,
                        scene.true_pairs)


def training_epoch(a: Association) -> Callable[[int], list[SceneInputs]]:
    """`epoch -> scenes` of the training: scene k of epoch e is scene e * scenes_per_epoch + k of `seed`."""
    setting, config = scene_setting(a, a.train_bias_m), network_config(a)

    def make_epoch(epoch: int) -> list[SceneInputs]:
        first = epoch * a.scenes_per_epoch
        return [inputs_of(make_scene(setting, a.seed, first + k), config) for k in range(a.scenes_per_epoch)]

    return make_epoch


def associators(a: Association, model: AssociationNet) -> dict[str, Associator]:
    """Every registered method's associator with params `a`'s knobs; the scenes' radars share one clock
    (`association_scenes`), so bias_robust estimates no clock offset here."""
    same_clock = replace(a, max_time_offset_s=0.0)
    return {name: associator(name, same_clock, model) for name in ASSOCIATORS}


def scene_tracks(scene: Scene) -> tuple[TrackSet, TrackSet]:
    """Each radar's tracks of a scene at its common times (the history, the common time last), ids by row."""
    return tuple(TrackSet(tuple(np.arange(states.shape[1]) for _ in states), tuple(states), tuple(covariances))
                 for states, covariances in ((scene.states1, scene.covariances1),
                                             (scene.states2, scene.covariances2)))


def decide_all(methods: dict[str, Associator], scene: Scene) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """Every method's pairs of a scene, and the bias-robust offset estimate (2,) with its covariance (2, 2)."""
    tracks = scene_tracks(scene)
    decisions = {name: method.associate_tracks(*tracks) for name, method in methods.items()}
    robust = decisions[BIAS_ESTIMATOR]
    return {name: decision.pairs for name, decision in decisions.items()}, robust.bias_m, robust.bias_covariance_m2


def count_pairs(pairs: np.ndarray, true_pairs: np.ndarray) -> dict[str, int]:
    """True, correct, false and missed pair counts of decided `pairs` (K, 2) against `true_pairs` (T, 2)."""
    truth = {tuple(pair) for pair in true_pairs.tolist()}
    correct = sum(tuple(pair) in truth for pair in pairs.tolist())
    return {"true": len(truth), "correct": correct, "false": len(pairs) - correct, "missed": len(truth) - correct}


def score_scenes(a: Association, model: AssociationNet, bias_m: tuple[float, float]) -> dict:
    """The module docstring's measures over `eval_scenes` scenes with bias lengths uniform in `bias_m`."""
    setting, methods = scene_setting(a, bias_m), associators(a, model)
    totals = {method: dict.fromkeys(("true", "correct", "false", "missed"), 0) for method in methods}
    errors, inside = [], 0
    limit = chi2.ppf(STATED_ACCURACY_PROBABILITY, 2)
    for index in range(a.eval_scenes):
        scene = make_scene(setting, a.eval_seed, index)
        pairs, bias, covariance = decide_all(methods, scene)
        for method, found in pairs.items():
            for key, value in count_pairs(found, scene.true_pairs).items():
                totals[method][key] += value
        error = bias - scene.bias_m
        errors.append(float(np.linalg.norm(error)))
        inside += bool(np.all(np.isfinite(covariance)) and error @ np.linalg.solve(covariance, error) <= limit)
    methods = {method: {"accuracy": t["correct"] / max(t["true"], 1), "false_pairs": t["false"] / max(t["true"], 1),
                        "missed_pairs": t["missed"] / max(t["true"], 1), **{f"{k}_count": v for k, v in t.items()}}
               for method, t in totals.items()}
    return {"scenes": a.eval_scenes, "methods": methods,
            "bias_estimate": {"mean_error_m": float(np.mean(errors)),
                              f"within_stated_{STATED_ACCURACY_PROBABILITY:g}": inside / a.eval_scenes}}


def association_report(a: Association, model: AssociationNet, epoch_losses: list[float]) -> dict:
    """Scores at every `eval_bias_m` and on the seed setting, with the seed's accuracy beside ours."""
    return {"by_bias_m": {f"{bias:g}": score_scenes(a, model, (bias, bias)) for bias in a.eval_bias_m},
            "seed_setting": {**score_scenes(a, model, a.train_bias_m), "seed_accuracy": SEED_ACCURACY},
            "training": {"epoch_losses": epoch_losses}}


def bias_figure(report: dict) -> bytes:
    """PNG: accuracy and false pairs per true pair against the bias length, one line per method."""
    biases = sorted(report["by_bias_m"], key=float)
    figure, axes = plt.subplots(1, 2, figsize=(10, 4))
    for method in ASSOCIATORS:
        for axis, key in zip(axes, ("accuracy", "false_pairs")):
            axis.plot([float(b) for b in biases], [report["by_bias_m"][b]["methods"][method][key] for b in biases],
                      marker="o", label=method)
    axes[0].axhline(SEED_ACCURACY, color="grey", linestyle=":", label="seed 002 (87.5 %, bias 0-200 m)")
    axes[0].set(xlabel="radar 2 bias (m)", ylabel="correct pairs / true pairs", title="Association accuracy")
    axes[1].set(xlabel="radar 2 bias (m)", ylabel="false pairs / true pairs", title="False pairs")
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    return png(figure)

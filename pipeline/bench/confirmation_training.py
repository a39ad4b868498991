"""Stage `train_confirmation` (`CONFIRMATION_NET`, a `pipeline.learning.kinds.Kind`): the learned track
confirmation's network (issue 34). Its entry is here, not in `pipeline.learning.kinds`: it learns from the
tracker's candidate tracks, and the tracker is above the learning wing.

Material: `confirmation.method` tracks every scenario of `confirmation.split` (the simulate stage's plots:
aircraft and clutter) under the learned rule with no threshold (`LearnedConfirmation`, threshold infinite: its
tracks stay tentative and die as tentative tracks do, so the associations are those a candidate track makes
before it is confirmed), the rule handing each association's `Evidence` to a recorder
(`candidate_associations`). The k-th evidence is the k-th association of the update table, so each gets its
label from the plot table: 1 when the plot is an aircraft's and the track's previous plot the same aircraft's.

Every `confirmation.validation_every`-th scenario is held out. On it the trained scorer tracks again
(`window_sums`), and each candidate track's (one of at least two plots: a lone plot is confirmed by no rule)
highest window sum over its tentative life is kept, for clutter's tracks (those with fewer than half their plots
an aircraft's) in the bundle: the tracker's threshold for a
false-track probability comes from them (`learned_confirmation.threshold_for`). The report
(`reports/confirmation.json`) gives, on the hold-out, the per-association log loss and accuracy, and for
the default probability the threshold, the share of aircraft's candidate tracks confirmed and the plots they
needed, beside M-of-N's (`tracker.management.confirm_m` of `confirm_n`) on the same tracks.
"""

from __future__ import annotations

import dataclasses
import logging
import math

from typing import TYPE_CHECKING

import numpy as np

from pipeline.learning.confirmation import Scorer, features
from pipeline.learning.kinds import CONFIRMATION, Kind
from pipeline.learning.recipe import Folders, Inputs, Outcome, SectionRecipe, Trained
from pipeline.params import Params
from pipeline.recordings import plot_table
from pipeline.recordings.plot_table import NO_TARGET, Plots
from pipeline.tracker import registry
from pipeline.tracker.learned_confirmation import LEVELS, LearnedConfirmation, threshold_for
from pipeline.tracker.loading import load_models
from pipeline.tracker.management import Evidence
from pipeline.tracker.run import track
from pipeline.tracker.updates import START

if TYPE_CHECKING:
    from torch import nn

    from pipeline.learning.fit import Task

log = logging.getLogger("pipeline")


@dataclasses.dataclass
class Associations:
    """Candidate tracks' associations (N,): `inputs` (N, 5) features (`confirmation.features`), `labels` (N,) 0/1."""

    inputs: np.ndarray
    labels: np.ndarray


def _tracked(params: Params, models: object, plots: Plots, scenario_id: int, score) -> tuple[dict, LearnedConfirmation]:
    """One scenario's update table under the learned rule with no threshold and the score `score`."""
    m = params.tracker.management
    rule = LearnedConfirmation(m.confirm_n, math.inf, m.delete_after_s, m.delete_after_scans, score)
    c = params.confirmation
    tracker = dataclasses.replace(registry.compose(c.method, models, params.tracker, c.window_m,
                                                   [params.tracker.seed, scenario_id], registry.THESIS_RULE),
                                  management=rule)
    return track(plots, tracker), rule


def _labels(updates: dict, plots: Plots) -> np.ndarray:
    """Per association of `updates` (its rows not a start, in order): whether its plot is an aircraft's and the
    track's previous plot the same aircraft's."""
    target = dict(zip(plots.plot_id.tolist(), plots.target_id.tolist()))
    previous, labels = {}, []
    for track_id, plot_id, association in zip(updates["track_id"].tolist(), updates["plot_id"].tolist(),
                                              updates["association"].tolist()):
        mine = target[plot_id]
        if association != START:
            labels.append(mine != NO_TARGET and previous.get(track_id) == mine)
        previous[track_id] = mine
    return np.asarray(labels, dtype=np.float32)


def _scenarios(params: Params, folders: Folders, held_out: bool) -> list[tuple[int, Plots]]:
    """The scenarios of `confirmation.split`, those held out or the others."""
    c = params.confirmation
    folder = folders.simulated / c.split
    plots = plot_table.read_parquet_plots(folder / "plots.parquet", folder / "radar.parquet", params.radar)
    return [(s, part) for s, part in plots.scenarios() if (s % c.validation_every == 0) == held_out]


def candidate_associations(params: Params, models: object, scenarios: list[tuple[int, Plots]]) -> Associations:
    """Every association of the candidate tracks `confirmation.method` makes on `scenarios` (module docstring)."""
    inputs, labels = [], []
    for scenario_id, plots in scenarios:
        evidence: list[Evidence] = []
        updates, _ = _tracked(params, models, plots, scenario_id, lambda e: evidence.append(e) or 1.0)
        labels.append(_labels(updates, plots))
        inputs.append(features(*np.array(evidence, dtype=float).reshape(-1, 5).T))
        if len(labels[-1]) != len(inputs[-1]):
            raise AssertionError(f"scenario {scenario_id}: {len(inputs[-1])} evidences for {len(labels[-1])} "
                                 "associations")
    return Associations(np.concatenate(inputs).astype(np.float32), np.concatenate(labels))


def window_sums(params: Params, models: object, scenarios: list[tuple[int, Plots]], scorer: Scorer
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per candidate track of `scenarios` (a track of at least two plots) tracked with `scorer` and no threshold: its
    highest window sum (levels),
    whether it is clutter's (fewer than half its plots an aircraft's), and, per update of each aircraft's track,
    the sums in order as a list of arrays flattened with their track's place ((T,), (T,), (T,) object)."""
    maxima, clutter, sums = [], [], []
    for scenario_id, plots in scenarios:
        updates, rule = _tracked(params, models, plots, scenario_id, scorer)
        target = dict(zip(plots.plot_id.tolist(), plots.target_id.tolist()))
        ids = updates["track_id"]
        is_target = np.array([target[p] != NO_TARGET for p in updates["plot_id"].tolist()])
        window = np.array([rule.window_sum(w) for w in updates["weight"].tolist()])
        for track_id in np.unique(ids).tolist():
            mine = ids == track_id
            if np.count_nonzero(mine) < 2:  # a lone plot: no candidate track, and never confirmed
                continue
            maxima.append(int(window[mine].max()))
            clutter.append(bool(is_target[mine].mean() < 0.5))
            sums.append(window[mine])
    holder = np.empty(len(sums), dtype=object)
    holder[:] = sums
    return np.asarray(maxima, dtype=np.int64), np.asarray(clutter), holder


def plots_to_confirm(sums: np.ndarray, threshold: float) -> np.ndarray:
    """Per track (`window_sums`' per-update sums), the plots it took to reach `threshold` (its first update's
    sum reached counts 1), NaN for one that never did."""
    out = np.full(len(sums), np.nan)
    for k, track_sums in enumerate(sums):
        reached = np.flatnonzero(np.asarray(track_sums) >= threshold)
        if len(reached):
            out[k] = reached[0] + 1
    return out


def log_loss(scores: np.ndarray, labels: np.ndarray) -> float:
    """Mean binary cross-entropy (nats) of scores in (0, 1) against 0/1 labels."""
    p = np.clip(scores, 1e-12, 1 - 1e-12)
    return float(-np.mean(labels * np.log(p) + (1 - labels) * np.log(1 - p)))


class ConfirmationRecipe(SectionRecipe):
    """The confirmation network's training (module docstring)."""

    section = "confirmation"

    def data(self, params: Params, folders: Folders) -> Inputs:
        c = params.confirmation
        models = load_models(folders.models, params, [c.method], rules=())
        train = candidate_associations(params, models, _scenarios(params, folders, held_out=False))
        if not len(train.labels) or train.labels.min() == train.labels.max():
            raise ValueError(f"{folders.simulated / c.split}: {len(train.labels)} candidate associations of "
                             f"{c.method}, {int(train.labels.sum())} an aircraft's: both kinds are needed to learn")
        return Inputs((train, models), f"{len(train.labels):,} candidate associations of {c.method} on {c.split} "
                                       f"({train.labels.mean():.1%} an aircraft's next plot)",
                      folders.simulated / c.split / "plots.parquet")

    def build(self, params: Params, inputs: Inputs) -> nn.Module:
        from pipeline.learning.confirmation import ConfirmationConfig, HitScorer
        return HitScorer(ConfirmationConfig(params.confirmation.hidden))

    def task(self, network: nn.Module, inputs: Inputs, params: Params) -> Task:
        from pipeline.learning.confirmation_fit import training_task
        train = inputs.data[0]
        return training_task(network, train.inputs, train.labels, params.confirmation, params.training.deterministic)

    def holdout(self, trained: Trained) -> Outcome:
        params, folders = trained.params, trained.folders
        management, models = params.tracker.management, trained.inputs.data[1]
        scorer = Scorer(trained.network)
        held_out = _scenarios(params, folders, held_out=True)
        validation = candidate_associations(params, models, held_out)
        scores = scorer.scores(validation.inputs)
        maxima, clutter, sums = window_sums(params, models, held_out, scorer)
        if not clutter.any():
            raise ValueError(f"{folders.simulated / params.confirmation.split}: no clutter track in the held-out "
                             "scenarios to set the threshold from")
        threshold = threshold_for(maxima[clutter], management.learned_false_track_probability)
        learned = plots_to_confirm(sums[~clutter], threshold)
        counted = plots_to_confirm(_hits_only(held_out, params, models), management.confirm_m * LEVELS)
        report = {
            "associations": {"train": int(len(trained.inputs.data[0].labels)), "held_out": int(len(scores))},
            "held_out": {"log_loss": log_loss(scores, validation.labels),
                         "accuracy": float(np.mean((scores > 0.5) == (validation.labels > 0.5))),
                         "aircraft_share": float(validation.labels.mean())},
            "candidate_tracks": {"aircraft": int((~clutter).sum()), "clutter": int(clutter.sum())},
            "at_default_probability": {
                "false_track_probability": management.learned_false_track_probability, "threshold_levels": threshold,
                "clutter_confirmed": float(np.mean(maxima[clutter] >= threshold)),
                "aircraft_confirmed": float(np.mean(np.isfinite(learned))),
                "aircraft_plots_to_confirm": float(np.nanmean(learned)) if np.isfinite(learned).any() else None,
                "m_of_n_aircraft_confirmed": float(np.mean(np.isfinite(counted))),
                "m_of_n_plots_to_confirm": float(np.nanmean(counted)) if np.isfinite(counted).any() else None},
            "epoch_losses": trained.fitted.train_loss, "seconds": trained.fitted.seconds}
        path = folders.reports / "confirmation.json"
        metrics = {"confirmation.held_out_log_loss": report["held_out"]["log_loss"],
                   "confirmation.held_out_accuracy": report["held_out"]["accuracy"],
                   "confirmation.train_seconds": trained.fitted.seconds}
        at = report["at_default_probability"]
        summary = (f"train_confirmation: hold-out log loss {report['held_out']['log_loss']:.3f}, accuracy "
                   f"{report['held_out']['accuracy']:.3f}; at a false-track probability of "
                   f"{at['false_track_probability']} the threshold is {threshold} levels: "
                   f"{at['aircraft_confirmed']:.1%} of aircraft's candidate tracks confirmed after "
                   f"{at['aircraft_plots_to_confirm']} plots on average (M-of-N: {at['m_of_n_plots_to_confirm']})")
        return Outcome({"epoch_losses": trained.fitted.train_loss, "window": management.confirm_n,
                        "clutter_maxima": np.sort(maxima[clutter]).tolist()},
                       {path: report}, (path,), metrics, summary)


def _hits_only(held_out: list[tuple[int, Plots]], params: Params, models: object) -> np.ndarray:
    """`window_sums`' per-update sums of the aircraft's tracks when every hit counts alike (M-of-N's count, in
    levels): the same tracks as the learned rule's, the threshold confirm_m x LEVELS."""
    _, clutter, sums = window_sums(params, models, held_out, lambda evidence: 1.0)
    return sums[~clutter]



CONFIRMATION_NET = Kind(name=CONFIRMATION.name, file=CONFIRMATION.file, stage=CONFIRMATION.stage,
                        command="train-confirmation", load=CONFIRMATION.load, recipe=ConfirmationRecipe)

"""Stage `train_association` (`pipeline.learning.kinds`): the seed's association network trained on freshly
simulated scenes of the seed's setting, then every association method scored against the bias.

Its entry is here rather than in `pipeline.learning.kinds`: its scenes and the methods it is scored
against are the association wing's and the bench's, above the tracker, which loads no association
network. Writes `models/association_net.pt` (`association_net.load`), `reports/association.json`
(DVC metrics: per bias and method accuracy, false and missed pairs; the seed setting beside the
seed's 87.5 %; the bias-robust offset error) and `reports/association_bias.png`.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.learning.kinds import Kind
from pipeline.learning.recipe import Folders, Inputs, Outcome, Recipe, SectionRecipe, Trained

if TYPE_CHECKING:
    from torch import nn

    from pipeline.learning.fit import Task
    from pipeline.params import Params


class AssociationNetRecipe(SectionRecipe):
    """The association network's training on fresh scenes, then the methods scored against the bias."""

    section = "association"

    def data(self, params: Params, folders: Folders) -> Inputs:
        from pipeline.bench import association_report
        a = params.association
        return Inputs(association_report.training_epoch(a), f"{a.epochs} epochs of {a.scenes_per_epoch} fresh scenes")

    def build(self, params: Params, inputs: Inputs) -> nn.Module:
        from pipeline.association.association_net import AssociationNet
        from pipeline.bench import association_report
        return AssociationNet(association_report.network_config(params.association))

    def task(self, network: nn.Module, inputs: Inputs, params: Params) -> Task:
        from pipeline.association.association_net import training_task
        return training_task(network, inputs.data, params.association, params.training.deterministic)

    def holdout(self, trained: Trained) -> Outcome:
        from pipeline.bench import association_report
        losses = trained.fitted.train_loss
        report = association_report.association_report(trained.params.association, trained.network, losses)
        seed_setting = report["seed_setting"]["methods"]
        reports = trained.folders.reports
        files = {reports / "association.json": report,
                 reports / "association_bias.png": association_report.bias_figure(report)}
        metrics = {"association.train_seconds": trained.fitted.seconds,
                   **{f"association.seed_setting.{m}.accuracy": v["accuracy"] for m, v in seed_setting.items()},
                   **{f"association.bias_{b}.{m}.accuracy": v["accuracy"]
                      for b, row in report["by_bias_m"].items() for m, v in row["methods"].items()}}
        summary = (f"train_association: {trained.fitted.seconds:.0f} s of training; seed setting accuracy "
                   + ", ".join(f"{m} {v['accuracy']:.3f}" for m, v in seed_setting.items())
                   + f" (seed: {100 * association_report.SEED_ACCURACY:.1f} %)")
        return Outcome({"epoch_losses": losses}, files, tuple(files), metrics, summary)


def _load(path: Path, params: Params) -> Any:
    from pipeline.association import association_net
    return association_net.load(path)


def _recipe() -> Recipe:
    return AssociationNetRecipe()


ASSOCIATION_NET = Kind(name="association_net", file="association_net.pt", stage="train_association",
                       command="train-association", load=_load, recipe=_recipe)

"""The training stages: `train_<kind>` for every trained piece, one MLflow run each
(`pipeline.learning.runner.run_training`), and `models_report`, the thesis networks' hold-out metrics in one file."""

from __future__ import annotations

from pathlib import Path

from pipeline import io
from pipeline.bench.association_training import ASSOCIATION_NET
from pipeline.bench.confirmation_training import CONFIRMATION_NET
from pipeline.learning.kinds import KINDS, Kind
from pipeline.learning.recipe import Folders
from pipeline.params import Params

TRAINED: dict[str, Kind] = {**KINDS, **{kind.name: kind for kind in (ASSOCIATION_NET, CONFIRMATION_NET)}}  # by name


def run_train(params: Params, kind: str, folders: Folders) -> None:
    """Stage `train_<kind>`: train the piece `kind`, write its model and reports, log its MLflow run."""
    from pipeline.learning.runner import run_training
    run_training(TRAINED[kind], params, folders)


def run_models_report(reports_dir: Path) -> None:
    """Stage `models_report`: the three networks' hold-out metrics in one file, beside the thesis's."""
    from pipeline.learning import model_eval
    merged = {}
    for kind in ("filter", "predictor", "autoencoder"):
        path = reports_dir / "models" / f"{kind}.json"
        if not path.is_file():
            raise io.InputError(f"{path}: file not found (run train_{kind})")
        merged[kind] = io.read_metrics(path)
    merged["thesis"] = model_eval.THESIS
    io.write_metrics(merged, reports_dir / "models.json")

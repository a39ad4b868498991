"""The one training task: every trained piece (`kinds.Kind`) is trained by `run_training`, the same steps in
the same order.

1. the kind's data, read and checked (everything that can fail on bad input fails here, before the
   tracking store is touched or a thread is set);
2. the store checked and the stage's one MLflow run opened (`tracking_logger.training_run`), with the
   kind's params, and its training windows as the run's input where it has them;
3. seeded with its section's `seed`, its network built (the initial weights), its task fitted once
   (`fit.fit`, logging into the run), then its hold-out;
4. the bundle written (`model_store.save_network`), then the kind's reports, its metrics logged, the
   bundle and reports logged as artifacts, and the thesis's networks registered as MLflow models.
Nothing is written when training fails (TrainingDiverged: the run FAILED, nothing registered); a store
that fails during the run costs no output (TrackingError after the outputs are written).

On several devices or machines (`training.devices`, `training.num_nodes` with `strategy: ddp`), Lightning runs
this same command once per device: the processes of rank 0 and of the others read the same data and build the
same network, and fit it together (the gradients averaged), but only rank 0 opens the MLflow run, runs the
hold-out and writes: one run, one bundle, one set of reports (`rank_zero`).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline import io
from pipeline.learning import mlflow_models
from pipeline.learning.experiment_tracking import SESSION_TAG, data_hash
from pipeline.learning.fit import Fitted, Task, fit
from pipeline.learning.kinds import Kind
from pipeline.learning.model_store import save_network
from pipeline.learning.recipe import Folders, Inputs, Recipe, Trained
from pipeline.learning.tracking_logger import training_run
from pipeline.params import Params

if TYPE_CHECKING:
    from lightning.pytorch.loggers import Logger
    from torch import nn

log = logging.getLogger("pipeline")


def _write(content: bytes | str | dict, path: Path, reports: Path) -> None:
    """A JSON report in the reports folder is a metrics file (rounded, its timings apart: `io.write_metrics`);
    one beside the models is an input of a later stage, written whole."""
    if isinstance(content, bytes):
        io.write_bytes(content, path)
    elif isinstance(content, str):
        io.write_text(content, path)
    elif path.resolve().is_relative_to(reports.resolve()):
        io.write_metrics(content, path)
    else:
        io.write_json(content, path)


def rank_zero() -> bool:
    """Whether this process is the training's rank 0: the first device (Lightning's `LOCAL_RANK`, which its
    launcher sets in the processes it starts) of the first machine (`NODE_RANK`, or `GROUP_RANK` as torchrun
    names it, set by the user on each machine). A training of one process is its own rank 0."""
    return all(int(os.environ.get(name) or 0) == 0 for name in ("LOCAL_RANK", "NODE_RANK", "GROUP_RANK"))


def _fitted(recipe: Recipe, inputs: Inputs, params: Params, logger: Logger | bool) -> tuple[nn.Module, Task, Fitted]:
    """Seeded with the section's `seed`, the network built (its initial weights) and its task fitted once."""
    import lightning as L

    L.seed_everything(recipe.knobs(params).seed, workers=True, verbose=False)
    network = recipe.build(params, inputs)
    task = recipe.task(network, inputs, params)
    return network, task, fit(*task, logger=logger)


def run_training(kind: Kind, params: Params, folders: Folders) -> None:
    """Stage `kind.stage`: train the piece `kind` (module docstring)."""
    import torch

    recipe = kind.recipe()
    inputs = recipe.data(params, folders)
    torch.set_num_threads(params.training.threads)
    if not rank_zero():
        log.info("%s: a further process of a training on several devices; rank 0 logs and writes", kind.stage)
        _fitted(recipe, inputs, params, logger=False)
        return
    bundle = folders.models / kind.file
    tags = {"input_data_sha256": data_hash(inputs.source)} if inputs.source is not None else {}
    with training_run(params, kind.stage, kind.command, tags, f"{bundle} and the reports") as (run, logger):
        log.info("%s: %s, MLflow run %s in %s", kind.stage, inputs.described, run.info.run_id, logger.uri)
        logger.log_hyperparams(recipe.logged(params))
        if inputs.windows is not None:
            logger.write("logging the training windows", mlflow_models.log_training_windows, kind.name,
                         inputs.source, *inputs.windows)
        network, task, fitted = _fitted(recipe, inputs, params, logger)
        outcome = recipe.holdout(Trained(network, task, fitted, inputs, params, folders, logger))
        save_network(bundle, network, outcome.extras, inputs.scaler)
        for path, content in outcome.files.items():
            _write(content, path, folders.reports)
        logger.log_metrics(outcome.metrics)
        for artifact in (bundle, *outcome.artifacts):
            logger.log_artifact(artifact)
        if kind.registers:
            logger.write("registering the network", mlflow_models.log_network, kind.name, network, inputs.windows[0],
                         params.training.experiment, bundle, run.data.tags[SESSION_TAG])
    log.info("%s", outcome.summary)

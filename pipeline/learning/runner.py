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
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import io
from pipeline.learning import mlflow_models
from pipeline.learning.experiment_tracking import SESSION_TAG, data_hash
from pipeline.learning.fit import fit
from pipeline.learning.kinds import Kind
from pipeline.learning.model_store import save_network
from pipeline.learning.recipe import Folders, Trained
from pipeline.learning.tracking_logger import training_run
from pipeline.params import Params

log = logging.getLogger("pipeline")


def _write(content: bytes | str | dict, path: Path) -> None:
    if isinstance(content, bytes):
        io.write_bytes(content, path)
    elif isinstance(content, str):
        io.write_text(content, path)
    else:
        io.write_json(content, path)


def run_training(kind: Kind, params: Params, folders: Folders) -> None:
    """Stage `kind.stage`: train the piece `kind` (module docstring)."""
    import lightning as L
    import torch

    recipe = kind.recipe()
    inputs = recipe.data(params, folders)
    torch.set_num_threads(params.training.threads)
    bundle = folders.models / kind.file
    tags = {"input_data_sha256": data_hash(inputs.source)} if inputs.source is not None else {}
    with training_run(params, kind.stage, kind.command, tags, f"{bundle} and the reports") as (run, logger):
        log.info("%s: %s, MLflow run %s in %s", kind.stage, inputs.described, run.info.run_id, logger.uri)
        logger.log_hyperparams(recipe.logged(params))
        if inputs.windows is not None:
            logger.write("logging the training windows", mlflow_models.log_training_windows, kind.name,
                         inputs.source, *inputs.windows)
        L.seed_everything(recipe.knobs(params).seed, workers=True, verbose=False)  # the initial weights
        network = recipe.build(params, inputs)
        task = recipe.task(network, inputs, params)
        fitted = fit(*task, logger=logger)
        outcome = recipe.holdout(Trained(network, task, fitted, inputs, params, folders, logger))
        save_network(bundle, network, outcome.extras, inputs.scaler)
        for path, content in outcome.files.items():
            _write(content, path)
        logger.log_metrics(outcome.metrics)
        for artifact in (bundle, *outcome.artifacts):
            logger.log_artifact(artifact)
        if kind.registers:
            logger.write("registering the network", mlflow_models.log_network, kind.name, network, inputs.windows[0],
                         params.training.experiment, bundle, run.data.tags[SESSION_TAG])
    log.info("%s", outcome.summary)

"""Stage `train_association`: the seed's association network trained on freshly simulated scenes of the seed's
setting, then every association method scored against the bias; one MLflow run.

Writes `models/association_net.pt` (`association_net.load`), `reports/association.json` (DVC metrics:
per bias and method accuracy, false and missed pairs; the seed setting beside the seed's 87.5 %; the
bias-robust offset error) and `reports/association_bias.png`. The tracking store is checked before training.
"""

from __future__ import annotations

import logging
from dataclasses import asdict
from pathlib import Path

from pipeline import io
from pipeline.association import association_net
from pipeline.bench import association_report
from pipeline.learning import experiment_tracking
from pipeline.params import Params

log = logging.getLogger("pipeline")


def run_train_association(params: Params, models_dir: Path, reports_dir: Path) -> None:
    import torch

    from pipeline.learning.tracking_logger import TrainingLogger

    a = params.association
    uri = experiment_tracking.tracking_uri(params.training.tracking_uri)
    experiment_tracking.check_tracking_store(uri, params.training.experiment, "train_association")
    torch.set_num_threads(params.training.threads)
    logger = TrainingLogger(uri, experiment_name=params.training.experiment, run_name="train_association",
                            tags={**experiment_tracking.run_tags("train_association"),
                                  **experiment_tracking.session_tags(params),
                                  "mlflow.source.name": "python -m pipeline train-association"})
    experiment_tracking.write_to_store(uri, "starting the run", lambda: logger.run_id)
    log.info("train_association: %d epochs of %d fresh scenes, MLflow run %s in %s", a.epochs, a.scenes_per_epoch,
             logger.run_id, uri)
    with experiment_tracking.ended_run(logger, f"{models_dir / 'association_net.pt'} and the reports"):
        logger.log_hyperparams({f"association.{key}": value for key, value in asdict(a).items()})
        torch.manual_seed(a.seed)  # the initial weights: the same for a seed, whatever ran before in the process
        model = association_net.AssociationNet(association_report.network_config(a))
        losses, seconds = association_net.train(model, association_report.training_epoch(a),
                                                association_report.train_config(a, params.training.deterministic),
                                                logger)
        report = association_report.association_report(a, model, losses)
        association_net.save(model, models_dir / "association_net.pt", {"epoch_losses": losses})
        io.write_json(report, reports_dir / "association.json")
        io.write_bytes(association_report.bias_figure(report), reports_dir / "association_bias.png")
        seed_setting = report["seed_setting"]["methods"]
        logger.log_metrics({"association.train_seconds": seconds,
                            **{f"association.seed_setting.{m}.accuracy": v["accuracy"]
                               for m, v in seed_setting.items()},
                            **{f"association.bias_{b}.{m}.accuracy": v["accuracy"]
                               for b, row in report["by_bias_m"].items() for m, v in row["methods"].items()}})
        for path in (models_dir / "association_net.pt", reports_dir / "association.json",
                     reports_dir / "association_bias.png"):
            logger.log_artifact(path)
    log.info("train_association: %.0f s of training; seed setting accuracy %s (seed: %.1f %%)", seconds,
             ", ".join(f"{m} {v['accuracy']:.3f}" for m, v in seed_setting.items()),
             100 * association_report.SEED_ACCURACY)

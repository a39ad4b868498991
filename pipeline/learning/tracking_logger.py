"""A training stage's one MLflow run, and Lightning's MLflow logger bound to it, for a store that may go
away mid-run.

`training_run` checks the store (before any training), opens the stage's run (`experiment_tracking.
stage_run`, so the run spans the work) and yields it with a `TrainingLogger` on it; the run ends
FAILED if the block raises (even KeyboardInterrupt or TrainingDiverged), else FINISHED.

Every write of the logger is retried (`experiment_tracking.write_to_store`); when one still fails, a
warning names the store and the run's later writes are skipped, so that the training, and the
writing of its model and reports, go on; after the block the stage raises the failure
(`raise_if_failed`): exit 2 naming the URI and the outputs written, never a traceback after an hour
of training with nothing kept, and the run is ended FAILED. Lightning ends the logger's run "failed"
when training raises: that write, too, is warned about only, and the error goes on.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lightning.pytorch.loggers import MLFlowLogger

from pipeline.learning.experiment_tracking import (
    TrackingError,
    check_tracking_store,
    stage_run,
    tracking_uri,
    write_to_store,
)

if TYPE_CHECKING:
    from mlflow import ActiveRun

    from pipeline.params import Params

log = logging.getLogger("pipeline")


class TrainingLogger(MLFlowLogger):
    """MLFlowLogger (`keywords`: its arguments) for the store at `uri` (module docstring)."""

    def __init__(self, uri: str, **keywords: Any) -> None:
        super().__init__(tracking_uri=uri, **keywords)
        self.uri = uri
        self.failure: TrackingError | None = None

    def write(self, what: str, call: Callable[..., Any], *arguments: Any, **keywords: Any) -> Any:
        """`write_to_store(uri, what, call, ...)`, skipped (None) after a failed write; a failure is kept and
        warned about (None)."""
        if self.failure is not None:
            return None
        try:
            return write_to_store(self.uri, what, call, *arguments, **keywords)
        except TrackingError as error:
            self.failure = error
            log.warning("%s; the stage goes on without MLflow and fails at its end", error)
            return None

    def log_metrics(self, metrics: dict[str, float], step: int | None = None) -> None:
        """Log `metrics`; those Lightning logs with the epoch (every training metric here is one value per
        epoch: the losses, `pipeline.learning.fit`) at the epoch as their MLflow step, so the UI draws the loss
        curves against the epoch, not against the optimiser's step count; the epoch itself is not logged."""
        if "epoch" in metrics:  # Lightning adds it to what it logs during a fit
            step = int(metrics["epoch"])
            metrics = {name: value for name, value in metrics.items() if name != "epoch"}
        self.write("logging metrics", super().log_metrics, metrics, step)

    def log_hyperparams(self, params: dict[str, Any]) -> None:  # type: ignore[override]
        self.write("logging params", super().log_hyperparams, params)

    def log_artifact(self, path: Path) -> None:
        """Log the file `path` as an artifact of the run."""
        self.write(f"logging {path}", self.experiment.log_artifact, self.run_id, str(path))

    def finalize(self, status: str = "success") -> None:
        self.write(f"ending the run ({status})", super().finalize, status)

    def raise_if_failed(self, written: str) -> None:
        """TrackingError if a write failed, saying that the stage's outputs (`written`) are written."""
        if self.failure is not None:
            raise TrackingError(f"{self.failure}; {written} written, its MLflow run incomplete: run the stage "
                                "again once the store is back")


@contextmanager
def training_run(params: Params, stage: str, command: str, tags: dict[str, str], written: str
                 ) -> Iterator[tuple[ActiveRun, TrainingLogger]]:
    """The stage's MLflow run (tagged as `experiment_tracking.stage_run` tags it, and with `tags`, `command`
    its `python -m pipeline` command) and a TrainingLogger bound to it, the store checked first (module
    docstring); `written` names the outputs the block writes, for the TrackingError after it."""
    uri = tracking_uri(params.training.tracking_uri)
    check_tracking_store(uri, params.training.experiment, stage)
    with stage_run(uri, params, stage, command, tags) as run:
        # Lightning marks the run FINISHED at the end of each fit; the stage's run ends it again.
        logger = TrainingLogger(uri, experiment_name=params.training.experiment, run_id=run.info.run_id)
        yield run, logger
        logger.raise_if_failed(written)

"""MLflow runs as a user finds them in the store: a run whose stage was killed does not stay RUNNING."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import mlflow

from pipeline.experiment_tracking import check_tracking_store, run_tags

EXPERIMENT = "radar-nn-tracker"


def _running_run(client: mlflow.MlflowClient, experiment_id: str, stage: str, **changes: str) -> str:
    """A RUNNING run tagged as `stage` tags it, with some tags changed (pid, host): what a stage
    killed with SIGKILL leaves behind, or what a stage still going shows."""
    return client.create_run(experiment_id, tags={**run_tags(stage), **changes}, run_name=stage).info.run_id


def test_a_stage_start_marks_killed_the_runs_its_killed_predecessors_left_running(tmp_path: Path, caplog) -> None:
    """When train_filter starts, a RUNNING train_filter run of this host whose process is gone is
    marked KILLED, with one log line naming it; a run whose process still runs, a run of another
    host (whose pids mean nothing here) and a run of another stage are left as they are."""
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    client = mlflow.MlflowClient(tracking_uri=uri)
    experiment_id = client.create_experiment(EXPERIMENT)
    finished = subprocess.Popen([sys.executable, "-c", "pass"])
    finished.wait()
    still_going = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        killed = _running_run(client, experiment_id, "train_filter", pid=str(finished.pid))
        live = _running_run(client, experiment_id, "train_filter", pid=str(still_going.pid))
        elsewhere = _running_run(client, experiment_id, "train_filter", pid=str(finished.pid), host="another-host")
        other_stage = _running_run(client, experiment_id, "evaluate", pid=str(finished.pid))
        with caplog.at_level(logging.INFO, logger="pipeline"):
            check_tracking_store(uri, EXPERIMENT, "train_filter")
    finally:
        still_going.kill()
        still_going.wait()
    status = {run_id: client.get_run(run_id).info.status for run_id in (killed, live, elsewhere, other_stage)}
    assert status == {killed: "KILLED", live: "RUNNING", elsewhere: "RUNNING", other_stage: "RUNNING"}
    assert client.get_run(killed).info.end_time is not None
    closing = [record.getMessage() for record in caplog.records if "KILLED" in record.getMessage()]
    assert len(closing) == 1 and killed in closing[0] and str(finished.pid) in closing[0]

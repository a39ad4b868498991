"""A team's MLflow server backed by PostgreSQL: the pipeline reaches it through MLFLOW_TRACKING_URI alone.

The team set-up of docs/team.md, end to end: a real PostgreSQL server, `mlflow server` over it
with artifacts in a folder of its own, and a training stage and `evaluate` run by DVC in a
copy of the repository whose params still say `sqlite:///mlflow.db`. Nothing may land in
that local store.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

import mlflow
import pytest
import sqlalchemy

from tests.servers import dvc, mlflow_server, postgres_database

pytestmark = pytest.mark.slow

EXPERIMENT = "radar-nn-tracker"
RERUN = ("train_filter", "evaluate")


@dataclass
class TeamServer:
    database_uri: str
    url: str
    artifacts: Path
    repository: Path
    local_runs_before: set[str]


def local_run_ids(repository: Path) -> set[str]:
    """The runs in the copy's own SQLite store (where params send them)."""
    with closing(sqlite3.connect(repository / "mlflow.db")) as database:
        return {run_id for (run_id,) in database.execute("SELECT run_uuid FROM runs")}


@pytest.fixture(scope="module")
def team_server(tiny_pipeline: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[TeamServer]:
    """PostgreSQL, an MLflow server over it, and `train_filter` and `evaluate` run against that server.

    They reuse the shared tiny pipeline's data and models (`dvc repro --force --single-item`):
    the stages run exactly as in a full repro, without rebuilding what they read.
    """
    server_directory = tmp_path_factory.mktemp("mlflow-team-server")
    local_runs_before = local_run_ids(tiny_pipeline)
    with postgres_database() as database_uri, mlflow_server(database_uri, server_directory) as url:
        dvc(tiny_pipeline, "repro", "--force", "--single-item", *RERUN, tracking_uri=url)
        yield TeamServer(database_uri, url, server_directory / "artifacts", tiny_pipeline, local_runs_before)


def test_runs_land_on_the_server(team_server: TeamServer) -> None:
    """Each stage's run is on the server, finished, with its metrics."""
    client = mlflow.MlflowClient(tracking_uri=team_server.url)
    experiment = client.get_experiment_by_name(EXPERIMENT)
    assert experiment is not None, f"no experiment {EXPERIMENT!r} on {team_server.url}"
    runs = {run.info.run_name: run for run in client.search_runs([experiment.experiment_id])}
    assert set(runs) == set(RERUN)
    assert {run.info.status for run in runs.values()} == {"FINISHED"}
    assert {"filter_error_m", "val_loss"} <= set(runs["train_filter"].data.metrics)
    assert "via_4000.MAE" in runs["evaluate"].data.metrics


def test_runs_are_stored_in_postgres(team_server: TeamServer) -> None:
    """The server's store is the PostgreSQL database itself."""
    engine = sqlalchemy.create_engine(team_server.database_uri)
    try:
        with engine.connect() as connection:
            names = list(connection.execute(sqlalchemy.text("SELECT name FROM runs")).scalars())
    finally:
        engine.dispose()
    assert sorted(names) == sorted(RERUN)


def test_artifacts_go_through_the_server(team_server: TeamServer) -> None:
    """The model file a training stage logs is uploaded to the server's artifact folder."""
    client = mlflow.MlflowClient(tracking_uri=team_server.url)
    experiment = client.get_experiment_by_name(EXPERIMENT)
    [run] = client.search_runs([experiment.experiment_id], "attributes.run_name = 'train_filter'")
    assert "filter.pt" in {artifact.path for artifact in client.list_artifacts(run.info.run_id)}
    stored = list(team_server.artifacts.rglob(f"{run.info.run_id}/artifacts/filter.pt"))
    assert len(stored) == 1 and stored[0].stat().st_size > 0, f"filter.pt not under {team_server.artifacts}"


def test_nothing_lands_in_the_local_store(team_server: TeamServer) -> None:
    """MLFLOW_TRACKING_URI overrides params' `sqlite:///mlflow.db`: the copy's store gets no new run."""
    assert local_run_ids(team_server.repository) == team_server.local_runs_before

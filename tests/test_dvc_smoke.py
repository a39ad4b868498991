"""`dvc repro` as a user runs it, in a fresh copy of the repository with tiny params."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from pipeline.params import STRATEGIES
from tests.project import copy_repository, environment, tiny_params_tree, write_params

pytestmark = pytest.mark.slow


def dvc(repository: Path, *arguments: str) -> str:
    result = subprocess.run([sys.executable, "-m", "dvc", *arguments], cwd=repository, env=environment(),
                            capture_output=True, text=True)
    assert result.returncode == 0, f"dvc {' '.join(arguments)} failed:\n{result.stdout}\n{result.stderr}"
    return result.stdout


@pytest.fixture(scope="module")
def repository(tmp_path_factory: pytest.TempPathFactory) -> Path:
    repository = copy_repository(tmp_path_factory.mktemp("clone"))
    write_params(tiny_params_tree(), repository / "params.yaml")
    dvc(repository, "repro")
    return repository


def test_repro_makes_every_split(repository: Path) -> None:
    """The stages write routes, plots, truth and radar description for each split."""
    for split in ("train", "test", "calibration"):
        routes = pq.read_table(repository / "data" / "routes" / f"{split}.parquet")
        assert len(set(routes.column("route_id").to_pylist())) == 2 * len(STRATEGIES)  # tiny_params_tree: 2 each
        for name in ("plots", "truth", "radar"):
            assert pq.read_metadata(repository / "data" / "simulated" / split / f"{name}.parquet").num_rows > 0
    assert (repository / "reports" / "data.json").is_file()
    assert (repository / "reports" / "data_routes.png").stat().st_size > 10_000


def test_second_repro_does_nothing(repository: Path) -> None:
    """Nothing changed, so nothing runs again."""
    output = dvc(repository, "repro")
    assert "Running stage" not in output
    assert "Data and pipelines are up to date" in dvc(repository, "status")


def test_radar_param_change_reruns_only_what_depends_on_it(repository: Path) -> None:
    """A radar noise change reruns simulate (and its reports), never the routes."""
    tree = tiny_params_tree()
    tree["radar"]["sigma_range_m"] = 55.0
    write_params(tree, repository / "params.yaml")
    output = dvc(repository, "repro")
    assert "Running stage 'simulate'" in output
    assert "Running stage 'routes'" not in output
    tree["routes"]["random_turns"]["turn_duration_s"] = [20.0, 100.0]
    write_params(tree, repository / "params.yaml")
    output = dvc(repository, "repro")
    assert "Running stage 'routes'" in output and "Running stage 'simulate'" in output

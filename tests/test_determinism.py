"""The same params and seeds give byte-identical outputs."""

from __future__ import annotations

from pathlib import Path

from tests.project import run_pipeline, tiny_params_tree, write_params


def run_all(folder: Path, params: Path) -> dict[str, bytes]:
    for arguments in (("routes", "--out", "routes"), ("simulate", "--routes", "routes", "--out", "simulated"),
                      ("data-report", "--routes", "routes", "--simulated", "simulated", "--out", "reports")):
        result = run_pipeline(arguments[0], "--params", str(params), *arguments[1:], cwd=folder)
        assert result.returncode == 0, result.stderr
    return {str(path.relative_to(folder)): path.read_bytes() for path in sorted(folder.rglob("*"))
            if path.is_file() and path != params}


def test_same_params_give_identical_files(tmp_path: Path) -> None:
    """Two runs in different folders write the same bytes: Parquet, JSON and PNG."""
    first, second = tmp_path / "first", tmp_path / "second"
    first.mkdir()
    second.mkdir()
    tree = tiny_params_tree()
    files_first = run_all(first, write_params(tree, first / "params.yaml"))
    files_second = run_all(second, write_params(tree, second / "params.yaml"))
    assert sorted(files_first) == sorted(files_second)
    assert any(name.endswith("plots.parquet") for name in files_first)
    for name, content in files_first.items():
        assert content == files_second[name], f"{name} differs between two identical runs"


def test_simulation_seed_changes_plots_not_routes(tmp_path: Path) -> None:
    """The radar's seed is independent of the routes' seeds."""
    tree = tiny_params_tree()
    first = run_all(tmp_path, write_params(tree, tmp_path / "params.yaml"))
    tree["simulate"]["seed"] += 1
    second = run_all(tmp_path, write_params(tree, tmp_path / "params.yaml"))
    assert first["routes/train.parquet"] == second["routes/train.parquet"]
    assert first["simulated/train/plots.parquet"] != second["simulated/train/plots.parquet"]

"""The command line as a user meets it: help, clear errors, no partial output."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline import io
from pipeline.cli import COMMANDS
from tests.project import REPOSITORY, run_pipeline, tiny_params_tree, write_params


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_command_has_help_with_an_example(command: str) -> None:
    """`--help` works for each command and shows how to call it."""
    result = run_pipeline(command, "--help")
    assert result.returncode == 0
    assert "example:" in result.stdout and f"python -m pipeline {command}" in result.stdout


def test_the_top_level_help_shows_an_example_of_every_command() -> None:
    """`python -m pipeline --help` lists each command with a line that calls it, so a new user sees how to
    start without opening each command's help."""
    result = run_pipeline("--help")
    assert result.returncode == 0, result.stderr
    examples = result.stdout.split("examples (one per command")[1]
    for command in COMMANDS:
        assert f"python -m pipeline {command} " in examples, command


@pytest.mark.parametrize("window", ["0", "-1", "nan", "inf", "4km"])
def test_a_window_that_is_not_a_positive_distance_is_a_usage_error(window: str, tmp_path: Path) -> None:
    """`track --window` of 0, below 0, NaN or infinity ran and gave tracks of nothing (every plot a new track);
    now argparse refuses it (exit 2) naming the option and the value, and nothing is written."""
    result = run_pipeline("track", "--plots", "plots.parquet", "--radar", "radar.parquet", "--window", window,
                          "--out", str(tmp_path / "tracks.parquet"))
    assert result.returncode == 2
    assert f"argument --window: '{window}' is not a window: a finite distance above 0 in metres" in result.stderr
    assert not any(tmp_path.iterdir())


def test_invalid_param_names_key_and_value_and_writes_nothing(tmp_path: Path) -> None:
    """A bad radar latitude stops the stage before any output exists."""
    tree = tiny_params_tree()
    tree["radar"]["latitude_deg"] = 95.0
    params = write_params(tree, tmp_path / "params.yaml")
    result = run_pipeline("routes", "--params", str(params), "--out", str(tmp_path / "routes"))
    assert result.returncode == 2
    assert "radar.latitude_deg = 95.0" in result.stderr
    assert not (tmp_path / "routes").exists()


def test_missing_routes_file_is_named(tmp_path: Path) -> None:
    """Simulating without routes names the missing file."""
    params = write_params(tiny_params_tree(), tmp_path / "params.yaml")
    result = run_pipeline("simulate", "--params", str(params), "--routes", str(tmp_path / "nowhere"),
                          "--out", str(tmp_path / "simulated"))
    assert result.returncode == 2
    assert "nowhere/train.parquet: file not found" in result.stderr
    assert not (tmp_path / "simulated").exists()


def test_nan_or_missing_column_in_routes_is_named(tmp_path: Path) -> None:
    """Malformed routes: the error names file and column."""
    params = write_params(tiny_params_tree(), tmp_path / "params.yaml")
    assert run_pipeline("routes", "--params", str(params), "--out", str(tmp_path / "routes")).returncode == 0
    path = tmp_path / "routes" / "train.parquet"
    table = pq.read_table(path)
    x = table.column("x_ecef_m").to_numpy().copy()
    x[3] = np.nan
    pq.write_table(table.set_column(table.schema.get_field_index("x_ecef_m"), "x_ecef_m", pa.array(x)), path)
    result = run_pipeline("simulate", "--params", str(params), "--routes", str(tmp_path / "routes"),
                          "--out", str(tmp_path / "simulated"))
    assert result.returncode == 2 and "train.parquet: column 'x_ecef_m' is NaN in 1 rows" in result.stderr
    pq.write_table(table.drop_columns(["vz_ecef_mps"]), path)
    result = run_pipeline("simulate", "--params", str(params), "--routes", str(tmp_path / "routes"),
                          "--out", str(tmp_path / "simulated"))
    assert result.returncode == 2 and "column 'vz_ecef_mps' is missing" in result.stderr
    assert not (tmp_path / "simulated").exists()


def test_corrupt_parquet_is_named(tmp_path: Path) -> None:
    """A file that is not Parquet gives an error naming it, not a traceback."""
    path = tmp_path / "train.parquet"
    path.write_bytes(b"PAR1 this is not really parquet")
    with pytest.raises(io.InputError, match="train.parquet: not a readable Parquet file"):
        io.read_parquet(path, pa.schema([pa.field("x", pa.float64())]))


def test_interrupted_write_leaves_no_file(tmp_path: Path) -> None:
    """A failure while writing leaves neither the destination nor a temporary file."""
    destination = tmp_path / "out.parquet"
    with pytest.raises(RuntimeError):
        with io.atomic_path(destination) as temporary:
            temporary.write_bytes(b"half a file")
            raise RuntimeError("killed half-way")
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_gives_the_users_file_mode(tmp_path: Path) -> None:
    """A new output gets what a plain open() would give (0666 less the umask), not the temporary
    file's private 0600; an output that is replaced keeps the mode its owner gave it."""
    previous = os.umask(0o022)
    try:
        fresh = tmp_path / "metrics.json"
        io.write_json({"a": 1}, fresh)
        assert stat.S_IMODE(fresh.stat().st_mode) == 0o644
        fresh.chmod(0o640)
        io.write_json({"a": 2}, fresh)
        assert stat.S_IMODE(fresh.stat().st_mode) == 0o640
    finally:
        os.umask(previous)


def _writer_in_the_middle_of_a_write(destination: Path) -> tuple[subprocess.Popen, Path]:
    """Another process inside `atomic_path(destination)`, stopped half-way, and its temporary file."""
    writer = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from pipeline import io\n"
         "with io.atomic_path(sys.argv[1]) as temporary:\n"
         "    temporary.write_bytes(b'half a file'); print(temporary, flush=True); time.sleep(60)",
         str(destination)], stdout=subprocess.PIPE, text=True, cwd=REPOSITORY)
    return writer, Path(writer.stdout.readline().strip())


def test_next_write_removes_the_temporary_of_a_killed_writer(tmp_path: Path) -> None:
    """A writer killed with SIGKILL cannot clean up; the next write of the same output removes
    what it left, and nothing but the output stays in the folder."""
    destination = tmp_path / "holdout.parquet"
    writer, temporary = _writer_in_the_middle_of_a_write(destination)
    writer.send_signal(signal.SIGKILL)
    writer.wait()
    assert temporary.exists()
    io.write_text("whole file", destination)
    assert sorted(tmp_path.iterdir()) == [destination]


def test_next_write_keeps_the_temporary_of_a_live_writer(tmp_path: Path) -> None:
    """Another process still writing the same output keeps its temporary file."""
    destination = tmp_path / "holdout.parquet"
    writer, temporary = _writer_in_the_middle_of_a_write(destination)
    try:
        io.write_text("whole file", destination)
        assert sorted(tmp_path.iterdir()) == sorted([destination, temporary])
    finally:
        writer.kill()
        writer.wait()


def test_generated_sections_are_current() -> None:
    """Every generated section (the README's headline, docs/results.md, docs/speed.md, the layout in
    docs/architecture.md) is what `python -m pipeline readme` generates from reports/ and the package."""
    result = run_pipeline("readme", "--check")
    assert result.returncode == 0, result.stderr

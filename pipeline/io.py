"""Files in and out: atomic writes, and Parquet reads that name what is wrong.

Every output is written to a temporary file beside its destination and renamed into
place, so an interrupted stage never leaves a half file that the next stage (or DVC)
would take for a result. A writer killed outright (SIGKILL, the OOM killer) cannot remove
its temporary; the next write of the same destination does, so leftovers never pile up. The
same holds for the temporary folders commands work in (`temporary_folder`): each is named with
its owner's pid and host, and removed by the next command to make one there once its owner is dead.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import socket
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

log = logging.getLogger("pipeline")


def schema(*columns: tuple) -> pa.Schema:
    """An Arrow schema from (name, type) pairs: columns are required (non-null) unless the pair
    carries a third element `True`, as in ("true_x_ecef_m", pa.float64(), True)."""
    return pa.schema([pa.field(name, kind, nullable=bool(rest and rest[0])) for name, kind, *rest in columns])


class InputError(ValueError):
    """An input file is missing or malformed; the message names the file and the column."""


class TrainingDiverged(RuntimeError):
    """A network's training went non-finite (NaN or infinite loss or weights) and was stopped; the message names
    the network, the epoch and what went non-finite. Nothing of the training was written (`training.FiniteTraining`)."""


def _same_file(first: Path, second: Path) -> bool:
    """Whether two paths name one file: the same resolved path, or (both existing) the same inode,
    so a symbolic or hard link to an input counts as the input."""
    if first.resolve() == second.resolve():
        return True
    try:
        return os.path.samefile(first, second)
    except OSError:
        return False


def check_outputs(inputs: dict[str, list[Path]], outputs: dict[str, Path]) -> None:
    """InputError, before anything is read, for an output that could not be written or would destroy a file.

    `inputs` and `outputs` map what the user calls each file (an option such as '--plots') to its
    path(s). Refused: an output that names an input (writing is atomic, so `track --out plots.parquet`
    would silently replace the user's recording with its result) or an earlier output (only the last
    written would be left); an output that is a folder, or whose nearest existing folder is not a
    writable folder: found only at the rename, after all the work, and after any output written
    before it (a summary without its tracks)."""
    named = [(option, Path(path)) for option, paths in inputs.items() for path in paths]
    for number, (option, path) in enumerate(outputs.items()):
        path = Path(path)
        for other, earlier in [*named, *list(outputs.items())[:number]]:
            if _same_file(path, Path(earlier)):
                raise InputError(f"{path}: {option} names the same file as {other} ({earlier}); writing it would "
                                 f"replace that file: give {option} another path")
        if path.is_dir():
            raise InputError(f"{path}: {option} is a folder; give the path of a file")
        folder = next(folder for folder in path.absolute().parents if folder.exists())
        if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
            raise InputError(f"{path}: {option} cannot be written: {folder} is not a folder this user can write to")


def _mode_for(destination: Path) -> int:
    try:
        return stat.S_IMODE(destination.stat().st_mode)
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def process_alive(pid: int) -> bool:
    """Whether process `pid` runs on this machine; another user's process counts as running."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


HOST = re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname().split(".")[0]) or "host"  # as temporaries' names carry it


def owned_prefix(prefix: str) -> str:
    """The start of a temporary's name made by this process: `<prefix>.<pid>.<host>.`; `mkstemp` or
    `mkdtemp` add `<random>` and the suffix `.tmp`, so that `remove_stale_temporaries` can tell a dead
    owner's leftover from a live one's."""
    return f"{prefix}.{os.getpid()}.{HOST}."


def remove_stale_temporaries(folder: Path, prefix: str) -> list[Path]:
    """Remove the temporaries in `folder` named `<prefix>.<pid>.<host>.<random>.tmp` (files or folders,
    `owned_prefix`) whose owner is dead: made on this host, by this user, by a process that no longer
    runs. A live owner's, another host's (a pid means nothing on another machine: a shared disk) and
    another user's are left alone. Returns what was removed. A process killed outright (SIGKILL, the
    OOM killer) runs no cleanup of its own, so its temporaries are removed by the next that makes one
    of the same prefix in the same folder."""
    pattern = re.compile(rf"{re.escape(prefix)}\.(\d+)\.([A-Za-z0-9-]+)\.[^.]+\.tmp")
    removed = []
    for candidate in folder.iterdir() if folder.is_dir() else ():
        match = pattern.fullmatch(candidate.name)
        if not match or match.group(2) != HOST or process_alive(int(match.group(1))):
            continue
        try:
            if candidate.lstat().st_uid != os.getuid():
                continue
            if candidate.is_dir() and not candidate.is_symlink():
                shutil.rmtree(candidate)
            else:
                candidate.unlink()
        except FileNotFoundError:  # removed meanwhile by another process cleaning up
            continue
        except OSError as error:  # a leftover that cannot be removed must not stop the command
            log.warning("%s: a dead process's temporary, left in place: %s", candidate, _first_line(error))
            continue
        removed.append(candidate)
    return removed


@contextmanager
def temporary_folder(prefix: str, parent: str | Path | None = None) -> Iterator[Path]:
    """A new folder `<parent>/<prefix>.<pid>.<host>.<random>.tmp` (the system's temporary folder if
    `parent` is None), removed when the block ends, however it ends; dead owners' folders of the same
    prefix in `parent` are removed first (`remove_stale_temporaries`). Every temporary folder a command
    makes is made here: `tempfile.TemporaryDirectory` cannot clean up after a SIGKILL, and its
    random name does not say whose it was."""
    parent = Path(parent) if parent is not None else Path(tempfile.gettempdir())
    remove_stale_temporaries(parent, prefix)
    folder = Path(tempfile.mkdtemp(prefix=owned_prefix(prefix), suffix=".tmp", dir=parent))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def atomic_path(destination: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write to; it replaces `destination` only if the block succeeds.

    The temporary's name carries the writer's pid and host (`owned_prefix`), so that the next write
    of `destination` can tell a killed writer's leftover from a live one's and remove it. The new file gets the
    mode a plain `open` would give it (0666 less the umask), or the mode of the file it
    replaces: mkstemp's private 0600 would otherwise hide outputs from a team's other accounts."""
    destination = Path(destination)
    destination.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(destination.parent, f".{destination.name}")
    handle, temporary = tempfile.mkstemp(prefix=owned_prefix(f".{destination.name}"), suffix=".tmp",
                                         dir=destination.parent)
    os.close(handle)
    try:
        yield Path(temporary)
        os.chmod(temporary, _mode_for(destination))
        os.replace(temporary, destination)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


def write_parquet(table: pa.Table, destination: str | Path) -> None:
    """Write a table deterministically (same table, same bytes) and atomically."""
    with atomic_path(destination) as temporary:
        pq.write_table(table, temporary, compression="zstd", write_statistics=True)


ROW_GROUP_ROWS = 1024 * 1024  # pyarrow's default row group length, which `write_parquet` leaves in place


class ParquetChunks:
    """Write a table a part at a time with the bytes `write_parquet` gives the whole, where the
    whole is `pa.concat_tables(chunks)` and each chunk arrives in parts (`add`). Parquet's bytes
    follow the Arrow chunks within a row group, so each row group is written as the whole would
    hold it: one Arrow array per chunk (its rows in that group), joined a column at a time (the
    parts' arrays of a column are let go as it is joined). Holds at most one row group's rows
    (`row_group_rows`) and the part being added."""

    def __init__(self, writer: pq.ParquetWriter, schema: pa.Schema, row_group_rows: int = ROW_GROUP_ROWS) -> None:
        self.writer, self.schema, self.row_group_rows = writer, schema, row_group_rows
        self._chunks: list[list[list[pa.Array]]] = []  # per chunk not written yet, per column, its arrays
        self._rows = 0
        self.written = 0

    def add(self, part: pa.Table, new_chunk: bool) -> None:
        """Add `part` (rows in `schema`) to the current chunk, or as the first part of a new one."""
        if new_chunk or not self._chunks:
            self._chunks.append([[] for _ in self.schema])
        for arrays, column in zip(self._chunks[-1], part.columns):
            arrays.extend(column.chunks)
        self._rows += part.num_rows
        while self._rows >= self.row_group_rows:
            self._write(self.row_group_rows)

    def _write(self, rows: int) -> None:
        """Write the first `rows` rows held as one row group."""
        group: list[list[pa.Array]] = [[] for _ in self.schema]
        left, rest = rows, []
        for chunk in self._chunks:
            count = sum(len(array) for array in chunk[0])
            taken = min(left, count)
            for column, arrays in zip(group, chunk if taken else ()):
                joined = pa.concat_arrays(arrays)
                arrays[:] = [joined.slice(taken)] if taken < count else []
                column.append(joined.slice(0, taken))
            left -= taken
            if taken < count:
                rest.append(chunk)
        table = pa.Table.from_arrays([pa.chunked_array(arrays, type=field.type)
                                      for arrays, field in zip(group, self.schema)], schema=self.schema)
        self.writer.write_table(table, row_group_size=rows)
        self._chunks, self._rows, self.written = rest, self._rows - rows, self.written + rows

    def close(self) -> None:
        """Write what is held (an empty table if nothing was ever added, as `write_parquet` does)."""
        if self._rows:
            self._write(self._rows)
        elif not self.written:
            self.writer.write_table(self.schema.empty_table())


@contextmanager
def parquet_chunks(destination: str | Path, schema: pa.Schema, row_group_rows: int = ROW_GROUP_ROWS
                   ) -> Iterator[ParquetChunks]:
    """A `ParquetChunks` writing atomically to `destination` (as `write_parquet`, with row groups of
    `row_group_rows`): the file appears, whole, only if the block succeeds; nothing is left on an error."""
    with atomic_path(destination) as temporary:
        with pq.ParquetWriter(temporary, schema, compression="zstd", write_statistics=True) as writer:
            chunks = ParquetChunks(writer, schema, row_group_rows)
            yield chunks
            chunks.close()


def _finite(data: Any) -> Any:
    """NaN and infinities become null: JSON has no NaN, and DVC and browsers reject it."""
    if isinstance(data, float) and not np.isfinite(data):
        return None
    if isinstance(data, dict):
        return {key: _finite(value) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [_finite(value) for value in data]
    return data


def write_json(data: Any, destination: str | Path) -> None:
    with atomic_path(destination) as temporary:
        temporary.write_text(json.dumps(_finite(data), indent=2, sort_keys=True, allow_nan=False) + "\n")


METRIC_DIGITS = 6   # significant digits a metrics file keeps
TIMING_DIGITS = 3   # and its timings file
TIMING_KEYS = frozenset({"plots_per_second", "seconds"})  # a tracker's speed; a tuning's or training's duration


def rounded(data: Any, digits: int = METRIC_DIGITS) -> Any:
    """Every float of `data` (nested in dicts and lists) rounded to `digits` significant digits.

    Why: a metric is the mean of a few hundred noisy draws, so its Monte Carlo spread shows in the second or
    third digit; what lies past the sixth is the machine's arithmetic (two processors differ in the twelfth
    digit of the same sum), and `dvc metrics diff` would list it as a change. Integers and booleans are kept."""
    if isinstance(data, float):
        return float(f"{data:.{digits}g}") if np.isfinite(data) else data
    if isinstance(data, dict):
        return {key: rounded(value, digits) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [rounded(value, digits) for value in data]
    return data


def split_timings(data: Any) -> tuple[Any, dict]:
    """(`data` without its timing fields, the timing fields in the same nesting): the keys of `TIMING_KEYS`
    in any dict of `data`, a list's dicts excepted (a timing is named by its path of keys)."""
    if not isinstance(data, dict):
        return data, {}
    results, timings = {}, {}
    for key, value in data.items():
        if key in TIMING_KEYS:
            timings[key] = value
            continue
        results[key], inner = split_timings(value)
        if inner:
            timings[key] = inner
    return results, timings


def timings_path(metrics: str | Path) -> Path:
    """Where the timings of the metrics file `metrics` go: `timings/` beside it, same name."""
    metrics = Path(metrics)
    return metrics.parent / "timings" / metrics.name


def write_metrics(data: dict, destination: str | Path) -> None:
    """A metrics file DVC compares (`dvc metrics diff`): `data`'s results rounded to `METRIC_DIGITS`
    significant digits at `destination`, its timings (`TIMING_KEYS`, which differ on every run) to
    `timings_path(destination)`, so that a diff of two runs lists only what a change moved. Both atomic.
    `read_metrics` puts them back together."""
    results, timings = split_timings(data)
    write_json(rounded(results), destination)
    if timings:
        write_json(rounded(timings, TIMING_DIGITS), timings_path(destination))


def _merged(results: Any, timings: Any) -> Any:
    if not (isinstance(results, dict) and isinstance(timings, dict)):
        return timings
    return {**results, **{key: _merged(results.get(key), value) for key, value in timings.items()}}


def read_metrics(path: str | Path) -> dict:
    """A metrics file as `write_metrics` was given it (its timings, if it has a timings file, put back)."""
    path = Path(path)
    data = json.loads(path.read_text())
    timings = timings_path(path)
    return _merged(data, json.loads(timings.read_text())) if timings.is_file() else data


def write_text(text: str, destination: str | Path) -> None:
    with atomic_path(destination) as temporary:
        temporary.write_text(text)


def write_bytes(data: bytes, destination: str | Path) -> None:
    with atomic_path(destination) as temporary:
        temporary.write_bytes(data)


def read_parquet(path: str | Path, schema: pa.Schema, optional: tuple[str, ...] = ()) -> pa.Table:
    """Read a Parquet file and check it against a schema.

    Columns must be present (unless listed in `optional`) with the schema's type, and
    non-nullable float columns must hold no NaN. Extra columns are dropped.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:
        table = pq.read_table(path)
    except (pa.ArrowInvalid, OSError) as error:
        raise InputError(f"{path}: not a readable Parquet file ({error})") from None
    columns = {}
    for field in schema:
        if field.name not in table.column_names:
            if field.name in optional:
                columns[field.name] = pa.nulls(table.num_rows, field.type)
                continue
            raise InputError(f"{path}: column '{field.name}' is missing (expected {field.type})")
        column = table.column(field.name)
        try:
            column = converted(column, field)
        except ColumnTypeError as error:
            raise InputError(f"{path}: column '{field.name}' has type {column.type}, expected {field.type} "
                             f"({error})") from None
        if not field.nullable and column.null_count:
            raise InputError(f"{path}: column '{field.name}' has {column.null_count} missing values")
        if pa.types.is_floating(field.type) and not field.nullable:
            nan = np.isnan(column.to_numpy(zero_copy_only=False))
            if nan.any():
                raise InputError(f"{path}: column '{field.name}' is NaN in {int(nan.sum())} rows "
                                 f"(first at row {int(np.argmax(nan))})")
        columns[field.name] = column
    return pa.Table.from_arrays(list(columns.values()), schema=schema)


def _first_line(error: Exception) -> str:
    return str(error).splitlines()[0] if str(error) else type(error).__name__


UNIX_TIME_SUFFIX = "_unix_s"  # every column of Unix seconds the project reads is named so (`time_unix_s`)
# The integers a float type holds one by one (its significand's bits plus one): past them a float
# id may be a rounded one (IEEE 754-2008, table 3.5: binary32 p = 24, binary64 p = 53).
_EXACT_INTEGERS = {pa.float16(): 2.0 ** 11, pa.float32(): 2.0 ** 24, pa.float64(): 2.0 ** 53}


class ColumnTypeError(ValueError):
    """A column's type cannot be read as its schema's without losing what it means; the message
    says why (the readers add the file, the column and both types)."""


def converted(column: pa.Array | pa.ChunkedArray, field: pa.Field, first_row: int = 0
              ) -> pa.Array | pa.ChunkedArray:
    """`column` as `field.type`, where the conversion cannot change what a value means; `first_row`
    is the file row of the column's first value (for the message).

    Arrow's safe cast already refuses an integer that does not fit (an int64 id past int32 is
    refused, not wrapped), a float with a fraction read as an integer and an integer past 2^53 read
    as float64. Refused here as well, where Arrow would convert without a word:
    - a Unix-time column (`*_unix_s`) of any type but float64. float32 holds a present-day Unix time
      only to 128 s (its 24-bit significand over 2^30..2^31 s, 2004 to 2038), float16 not at all;
      integers could be seconds, milliseconds or nanoseconds, and a timestamp type is not Unix
      seconds either: which one is meant is not guessed.
    - float16 for any float column: an 11-bit significand holds an azimuth to 0.25 deg, a range of
      50 km to 32 m.
    - a float column read as integers (ids) with a value past the integers its type holds one by
      one (2^24 for float32, 2^53 for float64): the id may have been rounded when it was written.
    Raises ColumnTypeError."""
    if column.type.equals(field.type):
        return column
    if field.name.endswith(UNIX_TIME_SUFFIX) and pa.types.is_floating(field.type):
        raise ColumnTypeError(_time_type_reason(column.type))
    if pa.types.is_floating(field.type) and column.type.equals(pa.float16()):
        raise ColumnTypeError("a float16 holds about 3 significant digits: write the column as float64 or float32")
    if pa.types.is_integer(field.type) and pa.types.is_floating(column.type):
        _check_float_integers(column, first_row)
    try:
        return column.cast(field.type)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as error:
        raise ColumnTypeError(_first_line(error)) from None


def _time_type_reason(kind: pa.DataType) -> str:
    """Why a column of `kind` is not read as Unix seconds (`converted`)."""
    if kind.equals(pa.float32()):
        return ("a float32 holds a present-day Unix time only to 128 s, so the times are already lost: write "
                "them as float64 Unix seconds")
    if pa.types.is_floating(kind):
        return f"a {kind} cannot hold a present-day Unix time: write the times as float64 Unix seconds"
    if pa.types.is_integer(kind):
        return ("integer times could be seconds, milliseconds or nanoseconds, which is not guessed: write them "
                "as float64 Unix seconds")
    return f"Unix seconds are read from float64 only, not converted from {kind}: write them as float64 Unix seconds"


def _check_float_integers(column: pa.Array | pa.ChunkedArray, first_row: int) -> None:
    """Raise ColumnTypeError for a float `column` read as integers with a value past the integers
    its type holds one by one (`_EXACT_INTEGERS`)."""
    exact = _EXACT_INTEGERS[column.type]
    values = column.to_numpy(zero_copy_only=False) if column.null_count == 0 else \
        column.fill_null(0).to_numpy(zero_copy_only=False)
    beyond = np.abs(values) > exact
    if beyond.any():
        row = int(np.argmax(beyond))
        raise ColumnTypeError(f"row {first_row + row} is {float(values[row])!r}, past 2^{int(np.log2(exact))}, "
                              f"beyond which a {column.type} no longer holds every integer: the id may have been "
                              "rounded; write the column as integers")


READ_BATCH_ROWS = 65536  # rows `read_numeric_parquet` decodes at a time


def parquet_batches(file: pq.ParquetFile, columns: list[str] | None = None, batch_rows: int | None = None
                    ) -> Iterator[pa.RecordBatch]:
    """The rows of `file` (its `columns`, all if None) `batch_rows` (READ_BATCH_ROWS if None) at a
    time, a row group at a time, a batch never crossing a row group's end. `iter_batches` over the
    whole file pre-buffers ahead, across row groups: its memory grows with the file (measured:
    Arrow's pool peaked at 12, 22 and 35 MiB reading 0.2, 0.8 and 1.7 M plots); a row group at a
    time it holds one row group (6 MiB for each of those)."""
    for group in range(file.num_row_groups):
        yield from file.iter_batches(batch_size=batch_rows or READ_BATCH_ROWS, row_groups=[group], columns=columns)


def parquet_file(path: str | Path) -> pq.ParquetFile:
    """`path` opened to be read a batch at a time (`iter_batches`) in memory that does not grow with
    the file. pyarrow's default `pre_buffer` keeps the bytes of every row group read so far in the
    reader's cache until the file is let go: by its end the whole compressed file (measured with
    pyarrow 25: 85 MiB of Arrow memory held by the end of a 24-hour dense recording of 84 MB, 6 MiB
    without; issue 16, item 4). Without it each column chunk is read when it is decoded, which on a
    local disk costs nothing. Raises what `pq.ParquetFile` raises."""
    return pq.ParquetFile(path, pre_buffer=False)


def read_numeric_parquet(path: str | Path, schema: pa.Schema, optional: tuple[str, ...] = ()) -> pa.Table:
    """`read_parquet` (the same checks, in the same order, with the same errors) for a schema of
    integer and float columns, in a fraction of its memory: the columns are numpy arrays filled
    READ_BATCH_ROWS rows at a time and handed to Arrow without a copy. `pq.read_table` peaks at
    two to three times the data and its memory pool keeps most of that; this holds the data once
    (`track` reads a 24-hour recording with it). Each column comes as one chunk."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:
        file = parquet_file(path)
        present = [field for field in schema if field.name in file.schema_arrow.names]
        columns = {field.name: _NumericColumn(field, file.metadata.num_rows) for field in present}
        if present:
            for batch in file.iter_batches(batch_size=READ_BATCH_ROWS, columns=list(columns)):
                for name, column in columns.items():
                    column.add(batch.column(name))
    except (pa.ArrowInvalid, OSError) as error:
        raise InputError(f"{path}: not a readable Parquet file ({error})") from None
    arrays = []
    for field in schema:
        if field.name in columns:
            arrays.append(columns[field.name].array(path))
        elif field.name in optional:
            arrays.append(pa.nulls(file.metadata.num_rows, field.type))
        else:
            raise InputError(f"{path}: column '{field.name}' is missing (expected {field.type})")
    return pa.Table.from_arrays(arrays, schema=schema)


class _NumericColumn:
    """One column of `read_numeric_parquet`, filled batch by batch, with what its checks found."""

    def __init__(self, field: pa.Field, rows: int) -> None:
        if not (pa.types.is_integer(field.type) or pa.types.is_floating(field.type)):
            raise TypeError(f"read_numeric_parquet reads integer and float columns, not {field}")
        self.field = field
        self.values = np.empty(rows, dtype=field.type.to_pandas_dtype())
        self.valid = np.ones(rows, dtype=bool) if field.nullable else None
        self.filled = self.nulls = self.nan = 0
        self.first_nan: int | None = None
        self.wrong_type: pa.DataType | None = None
        self.cast_error = ""  # why it cannot be read (`converted`), naming the value that does not fit

    def add(self, column: pa.Array) -> None:
        """The column's next batch."""
        start, self.filled = self.filled, self.filled + len(column)
        if self.wrong_type is not None:
            return
        try:
            column = converted(column, self.field, start)
        except ColumnTypeError as error:
            self.wrong_type, self.cast_error = column.type, str(error)
            return
        self.nulls += column.null_count
        values = column.fill_null(0).to_numpy(zero_copy_only=False) if column.null_count else column.to_numpy()
        self.values[start:self.filled] = values
        if self.valid is not None and column.null_count:
            self.valid[start:self.filled] = column.is_valid().to_numpy(zero_copy_only=False)
        if pa.types.is_floating(self.field.type) and not self.field.nullable:
            nan = np.isnan(values)
            if nan.any():
                self.first_nan = start + int(np.argmax(nan)) if self.first_nan is None else self.first_nan
                self.nan += int(nan.sum())

    def array(self, path: Path) -> pa.Array:
        """The column as one Arrow array, or the error `read_parquet` gives for it."""
        name, kind = self.field.name, self.field.type
        if self.wrong_type is not None:
            raise InputError(f"{path}: column '{name}' has type {self.wrong_type}, expected {kind} "
                             f"({self.cast_error})")
        if not self.field.nullable and self.nulls:
            raise InputError(f"{path}: column '{name}' has {self.nulls} missing values")
        if self.nan:
            raise InputError(f"{path}: column '{name}' is NaN in {self.nan} rows (first at row {self.first_nan})")
        mask = None if self.valid is None or self.valid.all() else ~self.valid
        return pa.array(self.values, type=kind, mask=mask)

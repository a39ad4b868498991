"""Files in and out: atomic writes, and Parquet reads that name what is wrong.

Every output is written to a temporary file beside its destination and renamed into
place, so an interrupted stage never leaves a half file that the next stage (or DVC)
would take for a result. A writer killed outright (SIGKILL, the OOM killer) cannot remove
its temporary; the next write of the same destination does, so leftovers never pile up.
"""

from __future__ import annotations

import json
import os
import re
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


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


def _remove_stale_temporaries(destination: Path) -> None:
    """Remove the temporaries of `destination` whose writer is dead, named
    `.<name>.<pid>.<random>.tmp`; a live writer's (another process still writing) is left alone."""
    pattern = re.compile(rf"\.{re.escape(destination.name)}\.(\d+)\.[^.]+\.tmp")
    for candidate in destination.parent.iterdir():
        match = pattern.fullmatch(candidate.name)
        if match and not process_alive(int(match.group(1))):
            candidate.unlink(missing_ok=True)


@contextmanager
def atomic_path(destination: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write to; it replaces `destination` only if the block succeeds.

    The temporary's name carries the writer's pid, so that the next write of `destination`
    can tell a killed writer's leftover from a live one's and remove it. The new file gets the
    mode a plain `open` would give it (0666 less the umask), or the mode of the file it
    replaces: mkstemp's private 0600 would otherwise hide outputs from a team's other accounts."""
    destination = Path(destination)
    destination.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_temporaries(destination)
    handle, temporary = tempfile.mkstemp(prefix=f".{destination.name}.{os.getpid()}.", suffix=".tmp",
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
        if not column.type.equals(field.type):
            try:
                column = column.cast(field.type)
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as error:
                raise InputError(f"{path}: column '{field.name}' has type {column.type}, expected {field.type} "
                                 f"({_first_line(error)})") from None
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
        self.cast_error = ""  # Arrow's reason, naming the value that does not fit (an int64 id past int32)

    def add(self, column: pa.Array) -> None:
        """The column's next batch."""
        start, self.filled = self.filled, self.filled + len(column)
        if self.wrong_type is not None:
            return
        if not column.type.equals(self.field.type):
            try:
                column = column.cast(self.field.type)
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as error:
                self.wrong_type, self.cast_error = column.type, _first_line(error)
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

"""An external merge sort of Arrow tables: its memory follows a run, not the data (issue 16, item 4).

`track` sorts a recording that is out of time order this way (`pipeline.recordings.streamed_recording`):
the plots arrive a batch at a time; `sorted_runs` sorts RUN_ROWS rows at a time by the key
columns and writes each as a Parquet file (a run) in a folder; `merged` reads the runs back
MERGE_BATCH_ROWS rows at a time and gives all their rows in key order, a table at a time.

The merge is the k-way merge of sorted runs (Knuth, The Art of Computer Programming vol. 3,
sec. 5.4.1), taken a batch at a time so that numpy does the per-row work: each run's next rows
are held; every held row not after the smallest of the runs' last held keys (the bound) can go
out, since the rows a run has not yet given come after its last held row; the run that set the
bound is used up and refilled, so each step frees at least one run's batch. The rows going out
are sorted together (a stable numpy lexsort). At most MERGE_FAN_IN runs are merged at once
(open files, and MERGE_FAN_IN x MERGE_BATCH_ROWS rows held); more runs are first merged in
groups into longer runs (a multipass merge, sec. 5.4), each group's runs removed as its merged
run is written.

Rows with equal keys come out sorted but in no set order between runs: a stable sort needs a last
key that tells every row apart (the caller's row number). Key columns hold no nulls.

pyarrow and numpy do it: no new dependency. DuckDB would sort out of core too, but the checks
that must see the plots in file order (`input_checks`) and the twins that must be seen in sorted
order (`plot_table.first_of_twins`) would still need these passes, and its row order among equal
keys would have to be forced the same way.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import io

RUN_ROWS = io.READ_BATCH_ROWS  # rows sorted in memory at a time (about 250 B each while sorted and written)
MERGE_BATCH_ROWS = io.READ_BATCH_ROWS // 16  # rows read from a run at a time: a run's row group, and the sorted
                                             # copy's (larger groups, held while written, cost more than they save)
MERGE_FAN_IN = 16  # runs merged at once: 16 x 4096 rows held (one READ_BATCH_ROWS), 16 files open; each open
                   # run costs about 1.4 MiB more (measured), so a wider merge saves a pass but not memory
COMPRESSION = {"compression": "zstd", "compression_level": 1}  # temporary files: fast, still about half size


def sorted_runs(tables: Iterable[pa.Table], keys: Sequence[str], folder: Path) -> list[Path]:
    """`tables` (one schema) cut into runs of RUN_ROWS rows in arrival order, each sorted by `keys`
    (stable) and written to `folder` (created): the runs' paths, in arrival order."""
    folder.mkdir(parents=True, exist_ok=True)
    return [_sorted_run(table, keys, folder / f"run-{number}.parquet")
            for number, table in enumerate(_rebatched(tables, RUN_ROWS))]


def _rebatched(tables: Iterable[pa.Table], rows: int) -> Iterator[pa.Table]:
    """The rows of `tables` (one schema), in order, as tables of `rows` rows (the last may have fewer)."""
    held: list[pa.Table] = []
    count = 0
    for table in tables:
        while table.num_rows:
            taken = min(rows - count, table.num_rows)
            held.append(table.slice(0, taken))
            count, table = count + taken, table.slice(taken)
            if count == rows:
                yield pa.concat_tables(held)
                held, count = [], 0
    if count:
        yield pa.concat_tables(held)


def _sorted_run(table: pa.Table, keys: Sequence[str], path: Path) -> Path:
    return written([table.take(_order(table, keys))], table.schema, path)


def _order(table: pa.Table, keys: Sequence[str]) -> np.ndarray:
    """The rows of `table` in `keys` order, stable."""
    return np.lexsort([table.column(key).to_numpy() for key in reversed(keys)])


def written(tables: Iterable[pa.Table], schema: pa.Schema, path: Path) -> Path:
    """`tables` (in `schema`) written one after the other to `path`, in row groups of
    MERGE_BATCH_ROWS rows (what a merge reads of a run at a time)."""
    with pq.ParquetWriter(path, schema, **COMPRESSION) as writer:
        for table in _rebatched(tables, MERGE_BATCH_ROWS):
            writer.write_table(table, row_group_size=MERGE_BATCH_ROWS)
    return path


def merged(runs: list[Path], keys: Sequence[str]) -> Iterator[pa.Table]:
    """The rows of `runs` (each sorted by `keys`) in `keys` order, a table at a time; runs beyond
    MERGE_FAN_IN first merged in groups into longer runs beside them (the merged runs removed)."""
    level = 0
    while len(runs) > MERGE_FAN_IN:
        groups = [runs[start:start + MERGE_FAN_IN] for start in range(0, len(runs), MERGE_FAN_IN)]
        runs = [_merged_run(group, keys, group[0].with_name(f"merge-{level}-{number}.parquet"))
                for number, group in enumerate(groups)]
        level += 1
    yield from _merge(runs, keys)


def _merged_run(runs: list[Path], keys: Sequence[str], path: Path) -> Path:
    written(_merge(runs, keys), pq.read_schema(runs[0]), path)
    for run in runs:
        run.unlink()
    return path


def _merge(runs: list[Path], keys: Sequence[str]) -> Iterator[pa.Table]:
    """One k-way merge of `runs` (module docstring)."""
    with contextlib.ExitStack() as stack:
        readers = [io.parquet_batches(stack.enter_context(io.parquet_file(run)), batch_rows=MERGE_BATCH_ROWS)
                   for run in runs]
        held = [_next(reader) for reader in readers]
        while any(table is not None for table in held):
            columns = [None if table is None else [table.column(key).to_numpy() for key in keys] for table in held]
            bound = min(tuple(column[-1] for column in run) for run in columns if run is not None)
            parts = []
            for number, run in enumerate(columns):
                if run is None:
                    continue
                rows = _at_most(run, bound)
                parts.append(held[number].slice(0, rows))
                held[number] = held[number].slice(rows) if rows < held[number].num_rows else _next(readers[number])
            table = pa.concat_tables(parts)
            yield table.take(_order(table, keys))


def _next(reader: Iterator[pa.RecordBatch]) -> pa.Table | None:
    """A run's next batch with rows, or None when the run is used up."""
    for batch in reader:
        if batch.num_rows:
            return pa.Table.from_batches([batch])
    return None


def _at_most(columns: list[np.ndarray], bound: tuple) -> int:
    """How many of the first rows of a run (its key `columns`, sorted) are not after `bound`: a
    binary search a key at a time, within the rows equal to `bound` on the keys before."""
    low, high = 0, len(columns[0])
    for column, value in zip(columns, bound):
        part = column[low:high]
        low, high = low + int(np.searchsorted(part, value, "left")), low + int(np.searchsorted(part, value, "right"))
    return high

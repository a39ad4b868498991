"""A user's Parquet recording read a part at a time when it is already in order (issue 16, item 4).

`plot_table.read_parquet_recording` holds the input's columns whole (about 60 bytes a plot):
a recording may be out of time order (files merged, a radar's plots interleaved around
midnight) and the tracker needs it sorted by scenario, then time. Most recordings need no sort:
`simulate` and a recorder write their plots in that order. For those, `read_recording` makes two
passes over the file, `io.READ_BATCH_ROWS` rows at a time: the first finds that the file is in
order and valid and counts what the summary and the placing need (plots by radar, twins,
whether any plot has a target id); the second (`StreamedRecording.scenarios`) drops the twins,
places the plots and hands them on `compute.chunk_plots` at a time. Memory then follows a batch
and a chunk, not the recording's length (the file is read without pyarrow's pre-buffering, which
would keep every row group read: `io.parquet_file`).

Streamed, a recording gives the plots, chunks, counts, warnings and errors of the whole read:
- in order: each scenario's plots in non-decreasing time, scenarios in increasing id (a null id
  counting as `plot_table.NO_SCENARIO`), so the whole read's stable sort would leave every plot
  where it is and its out-of-order and day-error checks (`input_checks`) find nothing;
- plot ids unique: seen in the first pass to increase (the usual case), else read alone and
  sorted (16 bytes a plot for that moment, a quarter of the whole read);
- twins (`plot_table.first_of_twins`) share a scenario and a time, so in order they lie within
  one run of equal (scenario, time): each run is judged whole, held back across a batch's end.
Anything else (out of order, a repeated plot id, a value or column the checks refuse, a plot of a
radar the description lacks) falls back to the whole read, which sorts the plots or names
the error as it always did.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import input_checks, io, plot_table
from pipeline.params import Radar
from pipeline.plot_table import NO_SCENARIO, OPTIONAL_PLOT_COLUMNS, PLOT_INPUT_SCHEMA, Plots


class RecordingParts(Protocol):
    """A recording `track` places a part at a time: `plot_table.Recording` or `StreamedRecording`."""

    radars: Mapping[int, Radar]
    skipped: Mapping[str, int]
    plot_counts: Mapping[int, int]

    def __len__(self) -> int: ...

    def scenarios(self, chunk_plots: int) -> Iterator[tuple[int, Iterator[Plots]]]: ...


class _NotStreamable(io.InputError):
    """The file is not in order, or not valid: the whole read sorts it or names the error. Met in
    the second pass (the file changed between the two), it stops the command as any input error."""


@dataclass(frozen=True)
class StreamedRecording:
    """A recording in order (module docstring) left in its file at `path`: `plots` the plots
    without twins; the rest as in `plot_table.Recording`."""

    path: Path
    plots: int
    radars: Mapping[int, Radar]
    has_truth: bool
    skipped: Mapping[str, int]
    plot_counts: Mapping[int, int]

    def __len__(self) -> int:
        return self.plots

    def scenarios(self, chunk_plots: int) -> Iterator[tuple[int, Iterator[Plots]]]:
        """Each scenario (in scenario id order) with its plots in time order, `chunk_plots` at a
        time: the chunks of `plot_table.Recording.scenarios`, read from the file as they are asked for."""
        chunks = ((scenario_id, plot_table.placed(table, self.radars, self.plot_counts, self.has_truth, self.skipped))
                  for scenario_id, table in _chunks(_twin_free(_batches(self.path), self.radars), chunk_plots))
        for scenario_id, group in itertools.groupby(chunks, key=lambda chunk: chunk[0]):
            yield scenario_id, (plots for _, plots in group)


def read_recording(plots_path: Path, radar_path: Path, radar: Radar) -> RecordingParts:
    """The recording of `plot_table.read_parquet_recording`, streamed when the file is in order
    (module docstring), else read whole. Raises what `read_parquet_recording` raises."""
    radars = io.read_parquet(radar_path, plot_table.RADAR_FILE_SCHEMA, optional=plot_table.OPTIONAL_RADAR_COLUMNS)
    input_checks.check_radars(radars, radar_path)
    sensors = plot_table.sensors(radars, radar)
    try:
        plots, radar_counts, twins, has_truth = _scan(plots_path, sensors)
    except _NotStreamable:
        return plot_table.read_parquet_recording(plots_path, radar_path, radar)
    skipped: dict[str, int] = {}
    if twins:
        plot_table.note_twins(skipped, twins, str(plots_path))
    return StreamedRecording(plots_path, plots, sensors, has_truth, skipped,
                             {radar_id: 0 for radar_id in sensors} | dict(sorted(radar_counts.items())))


def _scan(path: Path, radars: Mapping[int, Radar]) -> tuple[int, dict[int, int], int, bool]:
    """The first pass: the plots without twins, their count by radar id, the twins, and whether
    any plot has a target id. Raises _NotStreamable, also for a repeated plot id or a plot of a
    radar `radars` lacks (the whole read names it)."""
    read, increasing, last_id = 0, True, None

    def counted() -> Iterator[pa.Table]:
        nonlocal read, increasing, last_id
        for batch in _batches(path):
            if not np.isin(batch.column("radar_id").to_numpy(), list(radars)).all():
                raise _NotStreamable
            ids = batch.column("plot_id").to_numpy()
            if len(ids):
                increasing = increasing and bool((np.diff(ids) > 0).all()) and (last_id is None or ids[0] > last_id)
                read, last_id = read + len(ids), ids[-1]
            yield batch

    plots, counts, has_truth = 0, {}, False
    for table in _twin_free(counted(), radars):
        plots += table.num_rows
        has_truth = has_truth or table.column("target_id").null_count < table.num_rows
        ids, radar_counts = np.unique(table.column("radar_id").to_numpy(), return_counts=True)
        for radar_id, count in zip(ids.tolist(), radar_counts.tolist()):
            counts[radar_id] = counts.get(radar_id, 0) + count
    if not increasing and input_checks.repeats(pq.read_table(path, columns=["plot_id"]).column("plot_id").to_numpy()):
        raise _NotStreamable
    return plots, counts, read - plots, has_truth


def _batches(path: Path) -> Iterator[pa.Table]:
    """The file's plots, io.READ_BATCH_ROWS at a time, in PLOT_INPUT_SCHEMA (a missing optional
    column null); raises _NotStreamable at the first batch that is not valid or not in order."""
    try:
        file = io.parquet_file(path)
        names = file.schema_arrow.names
        if any(field.name not in names and field.name not in OPTIONAL_PLOT_COLUMNS for field in PLOT_INPUT_SCHEMA):
            raise _NotStreamable
        present = [field.name for field in PLOT_INPUT_SCHEMA if field.name in names]
        last: tuple[int, float] | None = None  # the previous batch's last scenario and time
        for batch in file.iter_batches(batch_size=io.READ_BATCH_ROWS, columns=present):
            table = _checked(batch)
            last = _in_order(table, last)
            yield table
    except (_NotStreamable, pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError):
        raise _NotStreamable(f"{path}: no longer in scenario and time order, or no longer valid, when read "
                             f"again (changed while being tracked?)") from None


def _checked(batch: pa.RecordBatch) -> pa.Table:
    """A batch in PLOT_INPUT_SCHEMA if every value is one the whole read accepts (types, nulls,
    NaN, `input_checks.PLOT_CHECKS`); raises _NotStreamable (or pa.ArrowInvalid) otherwise."""
    columns = []
    for field in PLOT_INPUT_SCHEMA:
        if field.name not in batch.schema.names:
            columns.append(pa.nulls(batch.num_rows, field.type))
            continue
        column = batch.column(field.name).cast(field.type)
        if column.null_count and not field.nullable:
            raise _NotStreamable
        columns.append(column)
    table = pa.Table.from_arrays(columns, schema=PLOT_INPUT_SCHEMA)
    for name, _, valid in input_checks.PLOT_CHECKS:
        if not valid(table.column(name).to_numpy()).all():
            raise _NotStreamable
    return table


def _in_order(table: pa.Table, last: tuple[int, float] | None) -> tuple[int, float] | None:
    """Whether `table`, after the batch that ended with `last` (scenario, time), keeps the file in
    order; the table's own last. Raises _NotStreamable."""
    if not table.num_rows:
        return last
    scenario = table.column("scenario_id").fill_null(NO_SCENARIO).to_numpy()
    time = table.column("time_unix_s").to_numpy()
    if last is not None:
        scenario, time = np.r_[last[0], scenario], np.r_[last[1], time]
    later_scenario = scenario[1:] > scenario[:-1]
    in_order = later_scenario | ((scenario[1:] == scenario[:-1]) & (time[1:] >= time[:-1]))
    if not in_order.all():
        raise _NotStreamable
    return int(scenario[-1]), float(time[-1])


def _twin_free(tables: Iterable[pa.Table], radars: Mapping[int, Radar]) -> Iterator[pa.Table]:
    """The plots of `tables` (in order) without twins, `plot_table.first_of_twins` applied to whole
    runs of equal (scenario, time): each table's last run is held back and joined to the next."""
    held = None
    for table in tables:
        table = table if held is None else pa.concat_tables([held, table]).combine_chunks()
        scenario = table.column("scenario_id").fill_null(NO_SCENARIO).to_numpy()
        time = table.column("time_unix_s").to_numpy()
        in_last_run = (scenario == scenario[-1]) & (time == time[-1]) if table.num_rows else np.zeros(0, bool)
        start = len(in_last_run) - int(np.argmin(in_last_run[::-1])) if not in_last_run.all() else 0
        done, held = table.slice(0, start), table.slice(start)
        if done.num_rows:
            yield done.take(plot_table.first_of_twins(done, radars))
    if held is not None and held.num_rows:
        yield held.take(plot_table.first_of_twins(held, radars))


def _chunks(tables: Iterable[pa.Table], chunk_plots: int) -> Iterator[tuple[int, pa.Table]]:
    """The plots of `tables` (in order) as (scenario id, chunk): each scenario's plots `chunk_plots`
    at a time from its first, as `plot_table.Recording.scenarios` cuts them."""
    pending: list[pa.Table] = []
    rows, current = 0, None
    for table in tables:
        scenario = table.column("scenario_id").fill_null(NO_SCENARIO).to_numpy()
        cuts = [0, *(np.flatnonzero(scenario[1:] != scenario[:-1]) + 1).tolist(), table.num_rows]
        for start, stop in itertools.pairwise(cuts):
            if int(scenario[start]) != current and pending:
                yield current, pa.concat_tables(pending).combine_chunks()
                pending, rows = [], 0
            current, piece = int(scenario[start]), table.slice(start, stop - start)
            while piece.num_rows:
                taken = min(chunk_plots - rows, piece.num_rows)
                pending.append(piece.slice(0, taken))
                rows, piece = rows + taken, piece.slice(taken)
                if rows == chunk_plots:
                    yield current, pa.concat_tables(pending).combine_chunks()
                    pending, rows = [], 0
    if pending:
        yield current, pa.concat_tables(pending).combine_chunks()

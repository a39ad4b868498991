"""A user's Parquet recording read a part at a time, in order or not (issue 16, item 4).

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

A recording out of order is sorted out of core first (`pipeline.recordings.external_sort`), in a temporary
folder that `read_recording` removes when its block ends, however it ends: one pass in file
order checks each batch as the whole read would, numbers its rows and writes sorted runs keyed
by (scenario, time, file row), so that the merge is the whole read's stable sort; the merge
drops the twins, counts the plots and writes them, sorted, to one file, which is then streamed
as an in-order recording is (the placing and the summary need the counts before the first chunk:
one merge and a read of its output, rather than merging twice). Disk: at most about three times the recording file (measured: 35 MiB
for a 13 MiB file of 0.84 M plots), while the sort runs.

Streamed, a recording gives the plots, chunks, counts, warnings and errors of the whole read:
- in order: each scenario's plots in non-decreasing time, scenarios in increasing id (a null id
  counting as `plot_table.NO_SCENARIO`), so the whole read's stable sort would leave every plot
  where it is and its out-of-order and day-error checks (`input_checks`) find nothing;
- out of order: the day-error check (`input_checks.radar_lags`) and the out-of-order warning's
  lags (`input_checks.time_lags`) are taken in file order, each batch continuing from the
  latest time of each group in the batches before it: the same maxima, so the same lags. A
  twin's lag is left out of the warning as the whole read drops twins before taking lags (a
  twin's time is that of its kept plot, earlier in the file, so the other plots' lags are the
  same with or without it);
- plot ids unique: seen in the first pass to increase (the usual case), else their column sorted
  out of core and looked through for a repeat;
- twins (`plot_table.first_of_twins`) share a scenario and a time, so in order they lie within
  one run of equal (scenario, time), in file order: each run is judged whole, held back across a
  batch's end.
Anything else (a repeated plot id, a day error, a value or column the checks refuse, a plot of a
radar the description lacks) falls back to the whole read, which names the error as it always
did: a bad file is read whole, once, to say what is wrong with it.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.params import Radar
from pipeline.recordings import external_sort, input_checks, plot_table
from pipeline.recordings.plot_table import NO_SCENARIO, OPTIONAL_PLOT_COLUMNS, PLOT_INPUT_SCHEMA, Plots


class RecordingParts(Protocol):
    """A recording `track` places a part at a time: `plot_table.Recording` or `StreamedRecording`."""

    radars: Mapping[int, Radar]
    skipped: Mapping[str, int]
    plot_counts: Mapping[int, int]

    def __len__(self) -> int: ...

    def scenarios(self, chunk_plots: int) -> Iterator[tuple[int, Iterator[Plots]]]: ...


class _NotStreamable(io.InputError):
    """The file is not valid: the whole read names the error. Met in
    the second pass (the file changed between the two), it stops the command as any input error."""


class _OutOfOrder(_NotStreamable):
    """The file is valid as far as read, but not in order: it is sorted out of core."""


@dataclass(frozen=True)
class StreamedRecording:
    """A recording in order (module docstring) left in its file at `path` (the user's, or the
    sorted copy of one out of order): `plots` the plots without twins; the rest as in
    `plot_table.Recording`."""

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
        twin_free = (table for table, _ in _twin_free(_batches(self.path), self.radars))
        chunks = ((scenario_id, plot_table.placed(table, self.radars, self.plot_counts, self.has_truth, self.skipped))
                  for scenario_id, table in _chunks(twin_free, chunk_plots))
        for scenario_id, group in itertools.groupby(chunks, key=lambda chunk: chunk[0]):
            yield scenario_id, (plots for _, plots in group)


@contextmanager
def read_recording(plots_path: Path, radar_path: Path, radar: Radar, scratch: Path | None = None
                   ) -> Iterator[RecordingParts]:
    """The recording of `plot_table.read_parquet_recording`, streamed (module docstring) within
    the block; a recording out of order sorted in a temporary folder in `scratch` (the system's
    temporary folder if None; best on disk, not in memory), `.track-sort.<pid>.<host>.<random>.tmp`,
    removed when the block ends however it ends; one a process killed outright left is removed by
    the next `track` to sort there (`io.temporary_folder`). Raises what `read_parquet_recording` raises."""
    radars = io.read_parquet(radar_path, plot_table.RADAR_FILE_SCHEMA, optional=plot_table.OPTIONAL_RADAR_COLUMNS)
    input_checks.check_radars(radars, radar_path)
    sensors = plot_table.sensors(radars, radar)
    with io.temporary_folder(SORT_FOLDER, scratch) as folder:
        yield _opened(plots_path, radar_path, radar, sensors, folder)


SORT_FOLDER = ".track-sort"  # the prefix of `read_recording`'s temporary folder


def _opened(plots_path: Path, radar_path: Path, radar: Radar, sensors: Mapping[int, Radar], folder: Path
            ) -> RecordingParts:
    """The recording, streamed from its file when in order, from a sorted copy in `folder` when
    not, read whole when not valid (module docstring)."""
    path, lags, counts = plots_path, _Lags(), None
    try:
        counts = _scan(plots_path, sensors, folder)
    except _OutOfOrder:
        pass  # sorted below, once the exception (and the batches its frames hold) is let go
    except _NotStreamable:
        return plot_table.read_parquet_recording(plots_path, radar_path, radar)
    if counts is None:
        try:
            path, counts, lags = _sort(plots_path, sensors, folder)
        except _NotStreamable:
            return plot_table.read_parquet_recording(plots_path, radar_path, radar)
    skipped: dict[str, int] = {}
    if counts.twins:
        plot_table.note_twins(skipped, counts.twins, str(plots_path))
    plot_table.note_out_of_order(lags.moved, lags.largest, str(plots_path))
    return StreamedRecording(path, counts.plots, sensors, counts.has_truth, skipped,
                             {radar_id: 0 for radar_id in sensors} | dict(sorted(counts.by_radar.items())))


@dataclass
class _Counts:
    """What the summary and the placing need of a recording, counted a table at a time: its plots
    without twins, the twins, the plots by radar id, whether any plot has a target id."""

    plots: int = 0
    twins: int = 0
    by_radar: dict[int, int] = dataclasses.field(default_factory=dict)
    has_truth: bool = False

    def add(self, table: pa.Table, twins: int) -> None:
        """Count `table` (plots without twins) and the `twins` dropped from it."""
        self.plots, self.twins = self.plots + table.num_rows, self.twins + twins
        self.has_truth = self.has_truth or table.column("target_id").null_count < table.num_rows
        ids, radar_counts = np.unique(table.column("radar_id").to_numpy(), return_counts=True)
        for radar_id, count in zip(ids.tolist(), radar_counts.tolist()):
            self.by_radar[radar_id] = self.by_radar.get(radar_id, 0) + count


@dataclass
class _Lags:
    """The out-of-order warning's numbers (`plot_table.note_out_of_order`), gathered a table at a time."""

    moved: int = 0
    largest: float = 0.0

    def add(self, lags: np.ndarray) -> None:
        self.moved += int((lags > 0).sum())
        self.largest = max(self.largest, float(lags.max(initial=0.0)))


class _PlotIds:
    """Whether the plot ids seen so far increase, batch after batch."""

    def __init__(self) -> None:
        self.increasing, self.last = True, None

    def add(self, table: pa.Table) -> None:
        ids = table.column("plot_id").to_numpy()
        if len(ids):
            self.increasing = (self.increasing and bool((np.diff(ids) > 0).all())
                               and (self.last is None or ids[0] > self.last))
            self.last = ids[-1]


def _scan(path: Path, radars: Mapping[int, Radar], folder: Path) -> _Counts:
    """The first pass over a file in order: its counts. Raises _OutOfOrder, or _NotStreamable for
    a repeated plot id or a plot of a radar `radars` lacks (the whole read names it)."""
    ids = _PlotIds()

    def counted() -> Iterator[pa.Table]:
        for batch in _batches(path):
            _check_radars(batch, radars)
            ids.add(batch)
            yield batch

    counts = _Counts()
    for table, twins in _twin_free(counted(), radars):
        counts.add(table, twins)
    if not ids.increasing and _repeats(path, folder / "ids"):
        raise _NotStreamable
    return counts


def _sort(path: Path, radars: Mapping[int, Radar], folder: Path) -> tuple[Path, _Counts, _Lags]:
    """The file's plots, checked in file order, sorted (scenario, time, file row) and written
    without twins to a file in `folder` (PLOT_INPUT_SCHEMA): its path, the counts and the
    out-of-order warning's numbers. Raises _NotStreamable (module docstring)."""
    ids, by_radar, by_scenario = _PlotIds(), {}, {}
    rows = 0

    def keyed() -> Iterator[pa.Table]:
        nonlocal rows
        for table in _batches(path, ordered=False):
            _check_radars(table, radars)
            if (input_checks.radar_lags(table, by_radar) > input_checks.MAX_BACKWARD_JUMP_S).any():
                raise _NotStreamable
            ids.add(table)
            scenario = table.column("scenario_id").fill_null(NO_SCENARIO)
            lags = input_checks.time_lags(table.column("time_unix_s").to_numpy(), scenario.to_numpy(),
                                          latest=by_scenario)
            keys = {"scenario_key": scenario, "row": pa.array(np.arange(rows, rows + table.num_rows)),
                    "lag": pa.array(lags)}
            rows += table.num_rows
            for name, column in keys.items():
                table = table.append_column(name, column)
            yield table

    runs = external_sort.sorted_runs(keyed(), _SORT_KEYS, folder / "runs")
    if not ids.increasing and _repeats(path, folder / "ids"):
        raise _NotStreamable
    counts, lags = _Counts(), _Lags()

    def counted() -> Iterator[pa.Table]:
        for table, twins in _twin_free(external_sort.merged(runs, _SORT_KEYS), radars):
            counts.add(table, twins)
            lags.add(table.column("lag").to_numpy())
            yield pa.Table.from_arrays(table.select(PLOT_INPUT_SCHEMA.names).columns, schema=PLOT_INPUT_SCHEMA)

    sorted_path = external_sort.written(counted(), PLOT_INPUT_SCHEMA, folder / "sorted.parquet")
    for run in (folder / "runs").iterdir():
        run.unlink()
    pa.default_memory_pool().release_unused()  # the sort's freed pages, which Arrow's allocator keeps, handed
    return sorted_path, counts, lags            # back: the tracking's peak 12 MiB lower at 4 hours (measured)


_SORT_KEYS = ("scenario_key", "time_unix_s", "row")  # the whole read's stable sort: scenario, time, file order


def _check_radars(table: pa.Table, radars: Mapping[int, Radar]) -> None:
    """Raises _NotStreamable for a plot of a radar `radars` lacks (the whole read names it)."""
    if not np.isin(table.column("radar_id").to_numpy(), list(radars)).all():
        raise _NotStreamable


def _repeats(path: Path, folder: Path) -> bool:
    """Whether a plot id of the file at `path` occurs twice: the column sorted out of core in `folder`."""
    with io.parquet_file(path) as file:
        runs = external_sort.sorted_runs((pa.table({"plot_id": batch.column("plot_id").cast(pa.int64())})
                                          for batch in io.parquet_batches(file, ["plot_id"])), ["plot_id"], folder)
    last = None
    for table in external_sort.merged(runs, ["plot_id"]):
        ids = table.column("plot_id").to_numpy()
        if (ids[1:] == ids[:-1]).any() or ids[0] == last:
            return True
        last = ids[-1]
    return False


def _batches(path: Path, ordered: bool = True) -> Iterator[pa.Table]:
    """The file's plots, io.READ_BATCH_ROWS at a time, in PLOT_INPUT_SCHEMA (a missing optional
    column null); raises _NotStreamable at the first batch that is not valid, _OutOfOrder at the
    first that is not in order if `ordered`."""
    try:
        file = io.parquet_file(path)
        names = file.schema_arrow.names
        if any(field.name not in names and field.name not in OPTIONAL_PLOT_COLUMNS for field in PLOT_INPUT_SCHEMA):
            raise _NotStreamable
        present = [field.name for field in PLOT_INPUT_SCHEMA if field.name in names]
        last: tuple[int, float] | None = None  # the previous batch's last scenario and time
        for batch in io.parquet_batches(file, present):
            table = _checked(batch)
            last = _in_order(table, last) if ordered else last
            yield table
    except (_NotStreamable, pa.ArrowInvalid, pa.ArrowNotImplementedError, OSError) as error:
        raise (_OutOfOrder if isinstance(error, _OutOfOrder) else _NotStreamable)(
            f"{path}: no longer in scenario and time order, or no longer valid, when read again (changed while "
            f"being tracked?)") from None


def _checked(batch: pa.RecordBatch) -> pa.Table:
    """A batch in PLOT_INPUT_SCHEMA if every value is one the whole read accepts (types, as
    `io.converted` reads them, nulls, NaN, `input_checks.PLOT_CHECKS`); raises _NotStreamable otherwise."""
    columns = []
    for field in PLOT_INPUT_SCHEMA:
        if field.name not in batch.schema.names:
            columns.append(pa.nulls(batch.num_rows, field.type))
            continue
        try:
            column = io.converted(batch.column(field.name), field)
        except io.ColumnTypeError:
            raise _NotStreamable from None
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
    order; the table's own last. Raises _OutOfOrder."""
    if not table.num_rows:
        return last
    scenario = table.column("scenario_id").fill_null(NO_SCENARIO).to_numpy()
    time = table.column("time_unix_s").to_numpy()
    if last is not None:
        scenario, time = np.r_[last[0], scenario], np.r_[last[1], time]
    later_scenario = scenario[1:] > scenario[:-1]
    in_order = later_scenario | ((scenario[1:] == scenario[:-1]) & (time[1:] >= time[:-1]))
    if not in_order.all():
        raise _OutOfOrder
    return int(scenario[-1]), float(time[-1])


def _twin_free(tables: Iterable[pa.Table], radars: Mapping[int, Radar]) -> Iterator[tuple[pa.Table, int]]:
    """The plots of `tables` (in order) without twins, each with the count of twins dropped from
    it: `plot_table.first_of_twins` applied to whole runs of equal (scenario, time), each table's
    last run held back and joined to the next."""
    held = None
    for table in tables:
        table = table if held is None else pa.concat_tables([held, table]).combine_chunks()
        scenario = table.column("scenario_id").fill_null(NO_SCENARIO).to_numpy()
        time = table.column("time_unix_s").to_numpy()
        in_last_run = (scenario == scenario[-1]) & (time == time[-1]) if table.num_rows else np.zeros(0, bool)
        start = len(in_last_run) - int(np.argmin(in_last_run[::-1])) if not in_last_run.all() else 0
        done, held = table.slice(0, start), table.slice(start)
        if done.num_rows:
            yield _first_of_twins(done, radars)
    if held is not None and held.num_rows:
        yield _first_of_twins(held, radars)


def _first_of_twins(table: pa.Table, radars: Mapping[int, Radar]) -> tuple[pa.Table, int]:
    first = plot_table.first_of_twins(table, radars)
    return table.take(first), table.num_rows - len(first)


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

"""One plot table for every recording: simulated Parquet, a user's Parquet, or ASTERIX.

Every plot carries its sensor. A recording is plots (`radar_id`, time, slant range, azimuth,
altitude; optionally `scenario_id` and, from the simulator, `target_id`) and a radar
description (one row per radar: `radar_id`, site latitude, longitude and height, optionally its
`scan_period_s` and its own error figures `sigma_range_m`, `sigma_azimuth_deg`,
`sigma_altitude_m`). Each plot is placed in ECEF from its own measurements and its own radar's site
(thesis eqs 4.1-4.6, `geodesy.plot_to_ecef`), and gets its converted-measurement covariance from
its own radar's errors (`geodesy.measurement_covariance`), so plots of several radars can be
tracked together. Every property of a radar comes from its own row where the row gives it; params'
`radar` section fills in what it leaves out (null or no column): the error figures, and the
rotation where there is no scan period.

A user's Parquet recording is checked value by value first (`input_checks`: physical ranges,
unique plot and radar ids, no day errors in the times). Plots of a radar the description lacks
stop the reading with an error naming the radar id. A plot identical to an earlier one of the same
radar (or a radar at the same site) and scenario (same time, range, azimuth and altitude, whatever its
plot id) is dropped and
counted (`Plots.skipped["duplicate plot"]`, and a warning): recordings off redundant networks hold
every packet twice, and a twin associated with its own plot at distance 0 would confirm clutter in
half the scans. Plots out of time order within a scenario are sorted (stable) with a warning
giving how many plots moved and the largest backward step: a recording merged from several files
is often slightly out of order, and the tracker needs time order.

`recording` does all of that but the placing, and keeps the checked input columns (a
`Recording`); the plots are placed from it a part at a time (`Recording.plots`,
`Recording.scenarios`, `placed`), so that `track` holds a long recording in a fraction of the
memory of its plot table. `plot_table` places every plot at once. A Parquet recording need not be
held at all: `pipeline.recordings.streamed_recording` reads it from its file as it goes, sorted out of core
first when it is out of order.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from datetime import date
from functools import cached_property
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.geometry import geodesy
from pipeline.params import Radar
from pipeline.recordings import asterix_io, input_checks

log = logging.getLogger("pipeline")

PLOT_INPUT_SCHEMA = io.schema(
    ("plot_id", pa.int64()),
    ("radar_id", pa.int32()),
    ("time_unix_s", pa.float64()),
    ("range_m", pa.float64()),
    ("azimuth_deg", pa.float64()),
    ("altitude_m", pa.float64()),
    ("scenario_id", pa.int32(), True),
    ("target_id", pa.int32(), True),
)
OPTIONAL_PLOT_COLUMNS = ("scenario_id", "target_id")
RADAR_INPUT_SCHEMA = io.schema(
    ("radar_id", pa.int32()),
    ("latitude_deg", pa.float64()),
    ("longitude_deg", pa.float64()),
    ("height_m", pa.float64()),
    ("scan_period_s", pa.float64(), True),
)
RADAR_ERROR_COLUMNS = ("sigma_range_m", "sigma_azimuth_deg", "sigma_altitude_m")  # named as in params' `radar`
RADAR_FILE_SCHEMA = pa.schema([*RADAR_INPUT_SCHEMA, *(pa.field(name, pa.float64()) for name in RADAR_ERROR_COLUMNS)])
OPTIONAL_RADAR_COLUMNS = ("scan_period_s", *RADAR_ERROR_COLUMNS)
DUPLICATE_PLOT = "duplicate plot"  # the `Plots.skipped` reason of a dropped twin
NO_SCENARIO = -1  # scenario id of plots that have none (ASTERIX, or a Parquet file without the column)
NO_TARGET = -1    # target id of a false plot, or of every plot when the truth is unknown


@dataclass(frozen=True)
class Plots:
    """N plots of one recording (or one scenario of it), each with its sensor.

    Arrays are indexed by plot (the plot's row): `plot_id` (N,) int64, `radar_id` (N,) int32,
    `scenario_id` (N,) int32 (NO_SCENARIO where unknown), `time` (N,) Unix seconds, `position`
    (N, 3) ECEF metres, `range_m` (N,) the measured slant range to the plot's radar, `covariance`
    (N, 3, 3) m^2 the converted-measurement covariance of the position, `target_id` (N,) int32 the
    true target (NO_TARGET for false plots, or when the truth is unknown: `has_truth` False).
    `radars` maps each radar id to its description. `skipped` counts, by reason, the records or
    plots that reading the recording left out (`track` reports them in its summary); every part
    of a recording (`take`, `scenarios`) carries the recording's counts."""

    plot_id: np.ndarray
    radar_id: np.ndarray
    scenario_id: np.ndarray
    time: np.ndarray
    position: np.ndarray
    range_m: np.ndarray
    covariance: np.ndarray
    target_id: np.ndarray
    has_truth: bool
    radars: Mapping[int, Radar]
    skipped: Mapping[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.time)

    @cached_property
    def features(self) -> np.ndarray:
        """Rows [t, x, y, z, r] (N, 5) as the networks read plots: time, ECEF position, measured range."""
        return np.column_stack([self.time, self.position, self.range_m])

    @cached_property
    def radar_position(self) -> np.ndarray:
        """ECEF (N, 3) metres of each plot's radar: the networks' radial window frame needs it."""
        ids = np.array(sorted(self.radars), dtype=np.int64)
        sites = np.array([geodesy.radar_site_ecef(self.radars[int(i)]) for i in ids]).reshape(-1, 3)
        return sites[np.searchsorted(ids, self.radar_id)]

    def take(self, rows: np.ndarray) -> "Plots":
        """The plots at `rows` (indices or a boolean mask), in that order."""
        return Plots(self.plot_id[rows], self.radar_id[rows], self.scenario_id[rows], self.time[rows],
                     self.position[rows], self.range_m[rows], self.covariance[rows], self.target_id[rows],
                     self.has_truth, self.radars, self.skipped)

    def scenarios(self) -> Iterator[tuple[int, "Plots"]]:
        """Each scenario's plots (in scenario id order), each tracked on its own."""
        for scenario_id in np.unique(self.scenario_id):
            yield int(scenario_id), self.take(np.flatnonzero(self.scenario_id == scenario_id))


def joined(parts: list[Plots]) -> Plots:
    """The plots of `parts` (parts of one recording) one after the other; truth known if known in
    every part; the first part's `skipped` (each part carries the recording's)."""
    columns = ("plot_id", "radar_id", "scenario_id", "time", "position", "range_m", "covariance", "target_id")
    return Plots(*(np.concatenate([getattr(part, name) for part in parts]) for name in columns),
                 all(part.has_truth for part in parts), {k: v for part in parts for k, v in part.radars.items()},
                 parts[0].skipped)


def sensors(radar_table: pa.Table, radar: Radar) -> dict[int, Radar]:
    """Each described radar (RADAR_INPUT_SCHEMA rows, optionally with RADAR_ERROR_COLUMNS) as
    params' `radar` at that site, with the row's scan period and error figures where it gives them."""
    out = {}
    for row in radar_table.to_pylist():
        period = row.get("scan_period_s")
        errors = {name: row[name] for name in RADAR_ERROR_COLUMNS if row.get(name) is not None}
        out[int(row["radar_id"])] = dataclasses.replace(
            radar, latitude_deg=row["latitude_deg"], longitude_deg=row["longitude_deg"], height_m=row["height_m"],
            rotation_rpm=60.0 / period if period else radar.rotation_rpm, **errors)
    return out


@dataclass(frozen=True)
class Recording:
    """A checked recording before its plots are placed: `table` the plots (PLOT_INPUT_SCHEMA) in
    file order, twins dropped; `order` (N,) the rows in scenario, then time order (stable);
    `radars` by id; `has_truth` whether any plot has a target id; `skipped` as in `Plots`;
    `plot_counts` the plots by radar id, every described radar listed.

    It keeps the compact input columns (about 60 bytes a plot with `order`) and places plots in
    ECEF, with their covariances (96 bytes a plot more), a part at a time (`plots`, `scenarios`):
    `track` reads a 24-hour dense recording this way in a fraction of the plot table's memory."""

    table: pa.Table
    order: np.ndarray
    radars: Mapping[int, Radar]
    has_truth: bool
    skipped: Mapping[str, int]
    plot_counts: Mapping[int, int]

    def __len__(self) -> int:
        return len(self.order)

    def plots(self, rows: np.ndarray | slice = slice(None)) -> Plots:
        """The plot table of the plots at `rows` of the sorted order (all by default)."""
        return placed(self.table.take(self.order[rows]), self.radars, self.plot_counts, self.has_truth, self.skipped)

    def scenarios(self, chunk_plots: int) -> Iterator[tuple[int, Iterator[Plots]]]:
        """Each scenario (in scenario id order) with its plots in time order, `chunk_plots` at a time."""
        scenario_ids = self.table.column("scenario_id").fill_null(NO_SCENARIO).to_numpy()[self.order]
        starts = np.flatnonzero(np.r_[True, scenario_ids[1:] != scenario_ids[:-1]]) if len(self) else []
        for start, stop in zip(starts, [*starts[1:], len(self)]):
            yield int(scenario_ids[start]), (self.plots(slice(first, min(first + chunk_plots, stop)))
                                             for first in range(start, stop, chunk_plots))


def placed(table: pa.Table, radars: Mapping[int, Radar], plot_counts: Mapping[int, int], has_truth: bool,
           skipped: Mapping[str, int]) -> Plots:
    """The plot table of `table` (PLOT_INPUT_SCHEMA rows of a recording, in the order given): each
    plot placed in ECEF from its own radar's site, with its covariance (module docstring).
    `plot_counts` (the recording's plots by radar id), `has_truth` and `skipped` are the recording's."""
    radar_ids, range_m = table.column("radar_id").to_numpy(), table.column("range_m").to_numpy()
    azimuth, altitude = table.column("azimuth_deg").to_numpy(), table.column("altitude_m").to_numpy()
    position, covariance = np.empty((len(table), 3)), np.empty((len(table), 3, 3))
    for radar_id in np.unique(radar_ids):
        chosen = np.flatnonzero(radar_ids == radar_id)
        # a lone plot of a radar with more is placed twice over: numpy's matmul and einsum take
        # another path for one row, whose last bit can differ from the whole recording's
        at = np.r_[chosen, chosen] if len(chosen) == 1 and plot_counts[int(radar_id)] > 1 else chosen
        radar = radars[int(radar_id)]
        ecef = geodesy.plot_to_ecef(range_m[at], azimuth[at], altitude[at], radar)
        position[chosen] = ecef[:len(chosen)]
        covariance[chosen] = geodesy.measurement_covariance(ecef, radar)[:len(chosen)]
    return Plots(table.column("plot_id").to_numpy(), radar_ids,
                 table.column("scenario_id").fill_null(NO_SCENARIO).to_numpy(),
                 table.column("time_unix_s").to_numpy(), position, range_m, covariance,
                 table.column("target_id").fill_null(NO_TARGET).to_numpy(), has_truth, dict(radars), skipped)


def plot_table(plots: pa.Table, radars: Mapping[int, Radar], source: str,
               skipped: Mapping[str, int] | None = None) -> Plots:
    """The plot table of a recording (`recording`'s arguments), all its plots placed."""
    return recording(plots, radars, source, skipped).plots()


def recording(plots: pa.Table, radars: Mapping[int, Radar], source: str,
              skipped: Mapping[str, int] | None = None) -> Recording:
    """A recording: `plots` in PLOT_INPUT_SCHEMA, `radars` by id. Twins of earlier plots are
    dropped; `skipped` (what the reader already left out, by reason) plus those twins become the
    result's `skipped`; plots out of time order within their scenario are sorted, with a warning.

    Raises io.InputError naming `source` and the radar id when a plot's radar is not described."""
    radar_ids = plots.column("radar_id").to_numpy()
    unknown = sorted(set(np.unique(radar_ids).tolist()) - set(radars))
    if unknown:
        raise io.InputError(f"{source}: plots from radar id {unknown[0]} ({len(unknown)} unknown in all), which "
                            f"the radar description does not list (it has {sorted(radars)})")
    skipped = dict(skipped or {})
    first = first_of_twins(plots, radars)
    if len(first) < plots.num_rows:
        note_twins(skipped, plots.num_rows - len(first), source)
        plots = plots.take(first)
    scenario_ids = plots.column("scenario_id").fill_null(NO_SCENARIO).to_numpy()
    times = plots.column("time_unix_s").to_numpy()
    _warn_out_of_order(times, scenario_ids, source)
    target = plots.column("target_id")
    ids, counts = np.unique(plots.column("radar_id").to_numpy(), return_counts=True)
    return Recording(plots, np.lexsort((times, scenario_ids)), dict(radars), target.null_count < len(target), skipped,
                     {radar_id: 0 for radar_id in radars} | dict(zip(ids.tolist(), counts.tolist())))


def note_twins(skipped: dict[str, int], twins: int, source: str) -> None:
    """Count `twins` dropped twins in `skipped` (DUPLICATE_PLOT) and warn of them."""
    skipped[DUPLICATE_PLOT] = skipped.get(DUPLICATE_PLOT, 0) + twins
    log.warning("%s: %d duplicate plots (the same radar or radar site, scenario, time, range, azimuth and "
                "altitude as an earlier plot) dropped", source, twins)


def first_of_twins(plots: pa.Table, radars: Mapping[int, Radar]) -> np.ndarray:
    """Rows (ascending) of the plots that are not twins of an earlier row: the same radar site,
    scenario, time, range, azimuth and altitude (the plot id may differ, as when each of two redundant
    feeds' copies got its own). The site, not the radar id: two radars at one site cannot measure one
    detection to the bit at the same instant, so such a pair is one feed delivered under two ids, and
    tracked together (as a recording's radars are) each twin would confirm clutter in half the scans."""
    ids = np.array(sorted(radars), dtype=np.int64)
    sites: dict[tuple[float, float, float], int] = {}
    site_of = np.array([sites.setdefault((radars[r].latitude_deg, radars[r].longitude_deg, radars[r].height_m),
                                         len(sites)) for r in ids.tolist()], dtype=np.int64)
    keys = [plots.column("scenario_id").fill_null(NO_SCENARIO).to_numpy(),
            site_of[np.searchsorted(ids, plots.column("radar_id").to_numpy())],
            *(plots.column(name).to_numpy() for name in ("time_unix_s", "range_m", "azimuth_deg", "altitude_m"))]
    order = np.lexsort(keys[::-1])  # stable: of equal rows, the earliest comes first
    first = np.r_[True, input_checks.changes(order, keys)][:len(order)]  # no row of an empty recording
    return np.sort(order[first])


def _warn_out_of_order(times: np.ndarray, scenario_ids: np.ndarray, source: str) -> None:
    """Warn of plots earlier than a plot before them in their scenario: how many will move when
    sorted, and the largest backward step (a day error shows as about 86400 s)."""
    lags = input_checks.time_lags(times, scenario_ids)
    note_out_of_order(int((lags > 0).sum()), float(lags.max(initial=0.0)), source)


def note_out_of_order(moved: int, largest: float, source: str) -> None:
    """Warn, if `moved` > 0, of `moved` plots out of time order, the largest `largest` s earlier
    than a plot before them in their scenario (`input_checks.time_lags`). The warning says what
    such steps are taken for (parts merged out of order) and where a day error begins, which the
    day-error check refuses, so that the one is not read for the other."""
    if moved:
        log.warning("%s: %d plots out of time order (up to %.1f s earlier than a plot before them); sorted by time "
                    "as parts merged out of order (a step back of more than %.0f s within a radar would be refused "
                    "as a day error)", source, moved, largest, input_checks.MAX_BACKWARD_JUMP_S)


def read_parquet_plots(plots_path: Path, radar_path: Path, radar: Radar) -> Plots:
    """The plot table of `read_parquet_recording`, all its plots placed."""
    return read_parquet_recording(plots_path, radar_path, radar).plots()


def read_parquet_recording(plots_path: Path, radar_path: Path, radar: Radar) -> Recording:
    """A recording from Parquet (the schema `simulate` writes, or a user's with PLOT_INPUT_SCHEMA's
    columns) and their radar description (RADAR_FILE_SCHEMA), each checked (`input_checks`). Errors
    name the file and column."""
    plots = io.read_numeric_parquet(plots_path, PLOT_INPUT_SCHEMA, optional=OPTIONAL_PLOT_COLUMNS)
    input_checks.check_plots(plots, plots_path)
    radars = io.read_parquet(radar_path, RADAR_FILE_SCHEMA, optional=OPTIONAL_RADAR_COLUMNS)
    input_checks.check_radars(radars, radar_path)
    return recording(plots, sensors(radars, radar), str(plots_path))


def read_asterix_plots(paths: list[Path], first_date: date, radar: Radar, radar_path: Path | None = None) -> Plots:
    """The plot table of `read_asterix_recording`, all its plots placed."""
    return read_asterix_recording(paths, first_date, radar, radar_path).plots()


def read_asterix_recording(paths: list[Path], first_date: date, radar: Radar, radar_path: Path | None = None
                           ) -> Recording:
    """The recording of ASTERIX CAT048 files given in time order; `first_date` is the UTC date of the first
    record. The radars' sites come from the description at `radar_path` (RADAR_FILE_SCHEMA, checked
    as for Parquet input) where it lists the radar, else from CAT034 I034/120
    (`asterix_io.with_radar_description`); a described radar's own error figures apply to its plots.
    What the decoder left out is counted in `Plots.skipped`."""
    source = ", ".join(str(p) for p in paths)
    description = None
    if radar_path is not None:
        description = io.read_parquet(radar_path, RADAR_FILE_SCHEMA, optional=OPTIONAL_RADAR_COLUMNS)
        input_checks.check_radars(description, radar_path)
    decoded = asterix_io.with_radar_description(asterix_io.decode(paths, first_date), description, source)
    plots = decoded.plots
    for name in OPTIONAL_PLOT_COLUMNS:
        plots = plots.append_column(name, pa.nulls(plots.num_rows, pa.int32()))
    radars = sensors(decoded.radars.select(RADAR_INPUT_SCHEMA.names).cast(RADAR_INPUT_SCHEMA), radar)
    if description is not None:
        described = sensors(description, radar)
        radars = {radar_id: dataclasses.replace(site, **{name: getattr(described[radar_id], name)
                                                         for name in RADAR_ERROR_COLUMNS})
                  if radar_id in described else site for radar_id, site in radars.items()}
    return recording(plots.select(PLOT_INPUT_SCHEMA.names).cast(PLOT_INPUT_SCHEMA), radars, source, decoded.skipped)

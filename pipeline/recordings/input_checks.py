"""The numbers and ids of a user's Parquet recording, checked before anything is computed from them.

`io.read_parquet` checks that the columns are there, of the right type, without nulls or NaN.
These check what the values mean: a slant range of 0 or infinity, an azimuth of 400 degrees or a
site at latitude 95 would otherwise be placed somewhere (or nowhere: NaN) and tracked without a
word. Each check refuses the file with an `io.InputError` naming the file, the column, the first
bad row and its value, and how many rows are bad; the command then exits 2 and writes nothing.

The bounds, and where they come from:
- `time_unix_s`: from 1970 (Unix time 0; a recording before it is a unit or epoch error) to
  2200-01-01 (TIME_MAX_UNIX_S: far past any recording, well short of milliseconds read as seconds).
- `range_m`: above 0 (a slant range is a distance; a negative one would mirror the plot through the
  radar) and at most RANGE_MAX_M.
- `azimuth_deg`: [0, 360), degrees clockwise from north, as ASTERIX I048/040 and `simulate` give it.
- `altitude_m`: ALTITUDE_MIN_M to ALTITUDE_MAX_M.
- the radar description: latitude [-90, 90], longitude [-180, 180], height SITE_HEIGHT_MIN_M to
  SITE_HEIGHT_MAX_M, `scan_period_s` and the error figures `sigma_*` above 0 and finite where given.
- `plot_id` unique in the file (the output's only link from a track update to its plot), and
  `radar_id` unique in the radar description (one row per radar; identical rows too, since which
  row was meant cannot be told from the file).
- time order: a plot more than MAX_BACKWARD_JUMP_S earlier than an earlier plot of its radar and
  scenario (in file order) is a day error, not a merge of slightly out-of-order files.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import io

TIME_MAX_UNIX_S = 7258118400.0  # 2200-01-01 00:00 UTC
ALTITUDE_MIN_M = -1000.0   # below the lowest land (Dead Sea shore, -430 m) and a low-pressure day's Mode C
ALTITUDE_MAX_M = 100000.0  # the Karman line: nothing a surveillance radar tracks flies higher
SITE_HEIGHT_MIN_M = -1000.0  # as ALTITUDE_MIN_M
SITE_HEIGHT_MAX_M = 20000.0  # above any ground site (Everest 8849 m) and airborne radar (AWACS, about 9 km)
RANGE_MAX_M = 2000000.0  # line of sight from a site at SITE_HEIGHT_MAX_M to a plot at ALTITUDE_MAX_M
                         # ends within 1,650 km over the Earth's curvature
MAX_BACKWARD_JUMP_S = 3600.0  # slightly out-of-order files are seconds apart; a day error is 86400 s


Check = tuple[str, str, Callable[[np.ndarray], np.ndarray]]  # column, what a value must be, which values are


def _positive(values: np.ndarray) -> np.ndarray:
    return (values > 0) & np.isfinite(values)


def _within(low: float, high: float, low_open: bool = False, high_open: bool = False
            ) -> Callable[[np.ndarray], np.ndarray]:
    """Which values lie between `low` and `high` (each bound included unless open); infinities do not."""
    return lambda values: (((values > low) if low_open else (values >= low))
                           & ((values < high) if high_open else (values <= high)))


PLOT_CHECKS: tuple[Check, ...] = (
    ("time_unix_s", f"in [0, {TIME_MAX_UNIX_S:.0f}) (1970 to 2200)", _within(0.0, TIME_MAX_UNIX_S, high_open=True)),
    ("range_m", f"in (0, {RANGE_MAX_M:.0f}]", _within(0.0, RANGE_MAX_M, low_open=True)),
    ("azimuth_deg", "in [0, 360)", _within(0.0, 360.0, high_open=True)),
    ("altitude_m", f"in [{ALTITUDE_MIN_M:.0f}, {ALTITUDE_MAX_M:.0f}]", _within(ALTITUDE_MIN_M, ALTITUDE_MAX_M)),
)
RADAR_CHECKS: tuple[Check, ...] = (
    ("latitude_deg", "in [-90, 90]", _within(-90.0, 90.0)),
    ("longitude_deg", "in [-180, 180]", _within(-180.0, 180.0)),
    ("height_m", f"in [{SITE_HEIGHT_MIN_M:.0f}, {SITE_HEIGHT_MAX_M:.0f}]", _within(SITE_HEIGHT_MIN_M, SITE_HEIGHT_MAX_M)),
    ("scan_period_s", "> 0 and finite", _positive),
    ("sigma_range_m", "> 0 and finite", _positive),
    ("sigma_azimuth_deg", "> 0 and finite", _positive),
    ("sigma_altitude_m", "> 0 and finite", _positive),
)


def check_plots(plots: pa.Table, path: Path) -> None:
    """Refuse a plots table (PLOT_INPUT_SCHEMA, in file order) with an impossible value, a repeated
    plot id or a day error in its times."""
    _check_bounds(plots, path, PLOT_CHECKS)
    _check_unique(plots, path, "plot_id", "the output links each track update to its plot by it")
    _check_time_jumps(plots, path)


def check_radars(radars: pa.Table, path: Path) -> None:
    """Refuse a radar description with an impossible value or two rows for one radar."""
    _check_bounds(radars, path, RADAR_CHECKS)
    _check_unique(radars, path, "radar_id", "one row per radar")


def _check_bounds(table: pa.Table, path: Path, checks: tuple[Check, ...]) -> None:
    """Each checked column the table has: every value valid (nulls of optional columns aside: they
    mean "not given")."""
    for column, rule, valid in checks:
        if column not in table.column_names:
            continue
        data = table.column(column)
        values = data.to_numpy(zero_copy_only=False).astype(float, copy=False)
        bad = ~(valid(values) | data.is_null().to_numpy(zero_copy_only=False))
        if bad.any():
            row = int(np.argmax(bad))
            raise io.InputError(f"{path}: column '{column}' must be {rule}: row {row} is {float(values[row])!r} "
                                f"({int(bad.sum())} of {len(values)} rows bad)")


def _check_unique(table: pa.Table, path: Path, column: str, why: str) -> None:
    """No value of `column` twice: name the first repeated value and its rows."""
    values = table.column(column).to_numpy()
    if not repeats(values):  # the usual case, in a fraction of np.unique's memory
        return
    _, first, counts = np.unique(values, return_index=True, return_counts=True)
    repeated = counts > 1
    if repeated.any():
        value = values[first[repeated].min()]
        rows = np.flatnonzero(values == value)
        listed = ", ".join(str(r) for r in rows[:5]) + (", ..." if len(rows) > 5 else "")
        raise io.InputError(f"{path}: {column} {value} is listed {len(rows)} times (rows {listed}); "
                            f"{int((counts[repeated] - 1).sum())} rows repeat an earlier {column} "
                            f"(column '{column}' must be unique: {why})")


def repeats(values: np.ndarray) -> bool:
    """Whether any value of `values` (N,) occurs twice: sorted, so 8 bytes a value held twice."""
    ordered = np.sort(values)
    return bool((ordered[1:] == ordered[:-1]).any())


def changes(order: np.ndarray, keys: tuple[np.ndarray, ...] | list[np.ndarray]) -> np.ndarray:
    """Whether each row of `order` (N,) after the first differs from the row before it in any of
    the `keys` (each (N,)): (N - 1,) booleans, one key at a time (no (N, K) copy of the keys)."""
    differs = np.zeros(max(len(order) - 1, 0), dtype=bool)
    for key in keys:
        ordered = key[order]
        differs |= ordered[1:] != ordered[:-1]
    return differs


def time_lags(times: np.ndarray, *groups: np.ndarray, latest: dict[tuple, float] | None = None) -> np.ndarray:
    """How far (s) each plot is earlier than the latest plot before it (in the given order) of its
    group (rows with equal `groups` values); 0 for a plot in time order. `latest`, when given, holds
    each group's latest time (keyed by its `groups` values) in the plots before these, and is
    updated to include these: a file read a batch at a time gives the lags of the file read whole
    (a maximum is exact, so the same differences are taken)."""
    order = np.lexsort((np.arange(len(times)), *reversed(groups)))
    starts = np.flatnonzero(np.r_[True, changes(order, groups)])
    lags = np.zeros(len(times))
    for start, stop in zip(starts, [*starts[1:], len(times)]):
        rows = order[start:stop]
        running = np.maximum.accumulate(times[rows])
        if latest is not None and len(rows):
            key = tuple(group[rows[0]].item() for group in groups)
            running = np.maximum(running, latest.get(key, -np.inf))
            latest[key] = float(running[-1])
        lags[rows] = running - times[rows]
    return lags


def radar_lags(plots: pa.Table, latest: dict[tuple, float] | None = None) -> np.ndarray:
    """`time_lags` (with `latest`) of plots (PLOT_INPUT_SCHEMA, in file order) within their radar
    and scenario (no scenario id a group of its own): the backward steps the day-error check judges."""
    scenario = plots.column("scenario_id")
    return time_lags(plots.column("time_unix_s").to_numpy(), scenario.fill_null(0).to_numpy(),
                     scenario.is_null().to_numpy(zero_copy_only=False), plots.column("radar_id").to_numpy(),
                     latest=latest)


def _check_time_jumps(plots: pa.Table, path: Path) -> None:
    """Refuse a plot more than MAX_BACKWARD_JUMP_S earlier than an earlier plot of its radar and
    scenario: most likely a time of day added to a fixed date, so that the plots after midnight
    are a day early; sorting them would track them a day before the rest."""
    scenario = plots.column("scenario_id")
    times, radar_ids = plots.column("time_unix_s").to_numpy(), plots.column("radar_id").to_numpy()
    lags = radar_lags(plots)
    jumps = lags > MAX_BACKWARD_JUMP_S
    if jumps.any():
        row = int(np.argmax(jumps))
        scenario_id = scenario[row].as_py()
        within = f"radar {radar_ids[row]}" + ("" if scenario_id is None else f", scenario {scenario_id}")
        raise io.InputError(f"{path}: column 'time_unix_s' jumps back {lags[row]:.0f} s at row {row} "
                            f"({float(times[row])!r}) within the plots of {within} "
                            f"({int(jumps.sum())} of {len(times)} rows more than {MAX_BACKWARD_JUMP_S:.0f} s "
                            f"earlier than a plot before them): probably a day error (a time of day added to "
                            f"a fixed date?), not parts merged out of order, which are seconds to minutes apart "
                            f"and sorted; give each plot its own date")

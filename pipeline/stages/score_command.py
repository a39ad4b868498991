"""`python -m pipeline score`: the surveillance scorecard of any tracker's output against a truth table.

Tracks are either our update table (what `track` writes: `track_id`, `time_unix_s`, `x/y/z_ecef_m`,
`status`; optionally `scenario_id` and the velocity columns `vx/vy/vz_ecef_mps`) or ASTERIX CAT062 system
tracks (ours or another tracker's; `--date` gives the UTC date of the first record, `--reference` the
system reference point of its I062/185 velocities, which `track --cat062` logs: without it the velocity
indicators are left out). The truth is a Parquet table of `target_id`, `time_unix_s`, `x/y/z_ecef_m`,
optionally `scenario_id` and `in_coverage` (what `simulate` writes as `truth.parquet`).

Scenarios are scored together: each is moved to a time range of its own (`SCENARIO_TIME_S` apart) and its
track and target ids made its own, so no update of one is associated with a target of another and every
indicator pools them as one recording would. CAT062 tracks carry no scenario: their truth must hold one
scenario (`--scenario` picks it).

Writes the scorecard (`pipeline.surveillance.scorecard`) as JSON and, beside it, Markdown (`<stem>.md`): every
indicator, and every reference figure beside its value with whether it passes.
"""

from __future__ import annotations

import logging
from datetime import date
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline import io
from pipeline.geometry import geodesy
from pipeline.params import Params
from pipeline.surveillance import cat062, scorecard
from pipeline.surveillance.scorecard import Settings, TrackUpdates, Truth

log = logging.getLogger("pipeline")

SCENARIO_TIME_S = 1e8  # scenarios moved this far apart in time (three years: more than any recording)
TRACK_COLUMNS = io.schema(("track_id", pa.int64()), ("time_unix_s", pa.float64()), ("x_ecef_m", pa.float64()),
                          ("y_ecef_m", pa.float64()), ("z_ecef_m", pa.float64()), ("status", pa.string()),
                          ("scenario_id", pa.int32(), True), ("vx_ecef_mps", pa.float64(), True),
                          ("vy_ecef_mps", pa.float64(), True), ("vz_ecef_mps", pa.float64(), True))
TRACK_OPTIONAL = ("scenario_id", "vx_ecef_mps", "vy_ecef_mps", "vz_ecef_mps")
TRUTH_COLUMNS = io.schema(("target_id", pa.int32()), ("time_unix_s", pa.float64()), ("x_ecef_m", pa.float64()),
                          ("y_ecef_m", pa.float64()), ("z_ecef_m", pa.float64()), ("scenario_id", pa.int32(), True),
                          ("in_coverage", pa.bool_(), True))
TRUTH_OPTIONAL = ("scenario_id", "in_coverage")
NO_SCENARIO = -1


def markdown_path(out: Path) -> Path:
    """Where `score` writes the Markdown beside the JSON `out`: `<stem>.md`."""
    return out.with_name(f"{out.stem}.md")


def _column(table: pa.Table, name: str, fill: float | int | bool) -> np.ndarray:
    if name not in table.column_names:
        return np.full(table.num_rows, fill)
    return table.column(name).fill_null(fill).to_numpy(zero_copy_only=False)


def _positions(table: pa.Table, prefix: str = "", suffix: str = "_ecef_m") -> np.ndarray:
    return np.stack([_column(table, f"{prefix}{axis}{suffix}", np.nan).astype(float) for axis in "xyz"], axis=1)


def _finite(values: np.ndarray, path: Path, column: str) -> None:
    bad = np.flatnonzero(~np.isfinite(values).reshape(len(values), -1).all(axis=1))
    if len(bad):
        raise io.InputError(f"{path}: column {column}: {len(bad)} rows not finite, the first row {bad[0]}")


def read_table_tracks(path: Path) -> tuple[TrackUpdates, np.ndarray]:
    """Our update table's tracks, and each update's scenario id (NO_SCENARIO where none)."""
    table = io.read_parquet(path, TRACK_COLUMNS, optional=TRACK_OPTIONAL)
    time, position = table.column("time_unix_s").to_numpy(), _positions(table)
    _finite(time, path, "time_unix_s")
    _finite(position, path, "x/y/z_ecef_m")
    velocity = np.stack([_column(table, f"v{axis}_ecef_mps", np.nan).astype(float) for axis in "xyz"], axis=1)
    return (TrackUpdates(table.column("track_id").to_numpy(), time, position, velocity,
                         _column(table, "status", "") == "confirmed"),
            _column(table, "scenario_id", NO_SCENARIO).astype(np.int64))


def read_cat062_tracks(path: Path, first_date: date, reference: cat062.SystemReference | None
                       ) -> tuple[TrackUpdates, np.ndarray]:
    """A CAT062 file's tracks (`cat062.read_cat062`), placed in ECEF at their WGS-84 position and altitude; their
    velocities from I062/185 about `reference` (NaN without one, or where the record has none)."""
    table = cat062.read_cat062(path, first_date)
    read = {name: table.column(name).to_numpy() for name in table.column_names}
    altitude = np.where(np.isfinite(read["altitude_m"]), read["altitude_m"], 0.0)
    position = geodesy.geodetic_to_ecef(read["latitude_deg"], read["longitude_deg"], altitude).reshape(-1, 3)
    velocity = np.full((len(position), 3), np.nan)
    if reference is not None and len(position):
        known = np.isfinite(read["vx_plane_mps"])
        if known.any():
            velocity[known] = cat062.plane_velocity_to_ecef(reference, position[known], read["vx_plane_mps"][known],
                                                            read["vy_plane_mps"][known])
    return (TrackUpdates(read["track_id"], read["time_unix_s"], position, velocity, read["confirmed"]),
            np.full(len(position), NO_SCENARIO))


def read_truth(path: Path) -> tuple[Truth, np.ndarray]:
    """The truth table (module docstring) and each row's scenario id (NO_SCENARIO where none)."""
    table = io.read_parquet(path, TRUTH_COLUMNS, optional=TRUTH_OPTIONAL)
    time, position = table.column("time_unix_s").to_numpy(), _positions(table)
    _finite(time, path, "time_unix_s")
    _finite(position, path, "x/y/z_ecef_m")
    return (Truth(table.column("target_id").to_numpy().astype(np.int64), time, position,
                  _column(table, "in_coverage", True).astype(bool)),
            _column(table, "scenario_id", NO_SCENARIO).astype(np.int64))


def _chosen(scenario: int | None, track_scenarios: np.ndarray, truth_scenarios: np.ndarray, truth_path: Path
            ) -> tuple[np.ndarray, np.ndarray]:
    """The rows of the tracks and of the truth that are scored: all, or those of `scenario`."""
    if scenario is None:
        return np.ones(len(track_scenarios), bool), np.ones(len(truth_scenarios), bool)
    tracks, truth = track_scenarios == scenario, truth_scenarios == scenario
    if not truth.any():
        raise io.InputError(f"{truth_path}: no truth of scenario {scenario} (--scenario; it holds "
                            f"{sorted(set(truth_scenarios.tolist()))[:10]})")
    if (track_scenarios == NO_SCENARIO).all():
        tracks[:] = True
    return tracks, truth


def _separated(updates: TrackUpdates, track_scenarios: np.ndarray, truth: Truth, truth_scenarios: np.ndarray,
               tracks_path: Path, truth_path: Path) -> tuple[TrackUpdates, Truth]:
    """Each scenario in a time range and id space of its own (module docstring)."""
    scenarios = np.unique(truth_scenarios)
    if scenarios.tolist() == [NO_SCENARIO]:  # a truth of one recording: the tracks must be of one too
        kinds = sorted(set(track_scenarios.tolist()) - {NO_SCENARIO})
        if len(kinds) > 1:
            raise io.InputError(f"{tracks_path}: tracks of {len(kinds)} scenarios ({kinds[:5]}), and {truth_path} has "
                                "no scenario_id: give a truth with scenario_id, or --scenario")
        return updates, truth
    lacking = sorted(set(np.unique(track_scenarios).tolist()) - set(scenarios.tolist()) - {NO_SCENARIO})
    if lacking:
        raise io.InputError(f"{tracks_path}: tracks of scenario {lacking[0]}, which {truth_path} has no truth of")
    if (track_scenarios == NO_SCENARIO).any() and len(scenarios) > 1:
        raise io.InputError(f"{tracks_path}: tracks without a scenario, and {truth_path} holds {len(scenarios)} "
                            "scenarios: give --scenario")
    if len(scenarios) == 1:
        return updates, truth
    place = {int(s): k for k, s in enumerate(scenarios.tolist())}
    track_place = np.array([place[int(s)] for s in track_scenarios.tolist()], dtype=np.int64)
    truth_place = np.array([place[int(s)] for s in truth_scenarios.tolist()], dtype=np.int64)
    return (TrackUpdates(track_place * 2 ** 32 + updates.track_id, updates.time_s + track_place * SCENARIO_TIME_S,
                         updates.position, updates.velocity, updates.confirmed),
            Truth(truth_place * 2 ** 32 + truth.target_id, truth.time_s + truth_place * SCENARIO_TIME_S,
                  truth.position, truth.in_coverage))


def _check_overlap(updates: TrackUpdates, truth: Truth, tracks_path: Path, truth_path: Path) -> None:
    """InputError when no confirmed update falls within the truth's time: the wrong day or recording."""
    confirmed = updates.time_s[updates.confirmed]
    if len(confirmed) and not ((confirmed >= truth.time_s.min()) & (confirmed <= truth.time_s.max())).any():
        raise io.InputError(f"{tracks_path}: no confirmed update within the time of {truth_path} "
                            f"({confirmed.min():.0f}-{confirmed.max():.0f} s against {truth.time_s.min():.0f}-"
                            f"{truth.time_s.max():.0f} s, Unix): another day (--date) or another recording")


def run_score(params: Params, tracks_path: Path | None, cat062_path: Path | None, first_date: date | None,
              reference: tuple[float, float] | None, truth_path: Path, scenario: int | None,
              update_interval_s: float | None, out: Path) -> dict:
    """Score the tracks (our table at `tracks_path`, or CAT062 at `cat062_path`) against the truth; write the
    scorecard to `out` (JSON) and `markdown_path(out)`; the update interval is the radar's scan period
    (params' `radar.rotation_rpm`) unless given. Nothing is written on an error."""
    inputs = {"--tracks": [tracks_path] if tracks_path else [], "--cat062": [cat062_path] if cat062_path else [],
              "--truth": [truth_path]}
    io.check_outputs(inputs, {"--out": out, "--out's Markdown": markdown_path(out)})
    if (tracks_path is None) == (cat062_path is None):
        raise io.InputError("give --tracks (our update table, Parquet) or --cat062 (ASTERIX CAT062), one of them")
    if cat062_path is not None and first_date is None:
        raise io.InputError("CAT062 carries only the time of day: give --date (UTC date of the first record)")
    interval = update_interval_s if update_interval_s is not None else 60.0 / params.radar.rotation_rpm
    settings = Settings.from_params(interval, params.scorecard)
    if tracks_path is not None:
        updates, track_scenarios = read_table_tracks(tracks_path)
    else:
        updates, track_scenarios = read_cat062_tracks(
            cat062_path, first_date, cat062.SystemReference(*reference) if reference else None)
        if reference is None:
            log.warning("score: no --reference for %s: its velocities (I062/185) are not scored", cat062_path)
    tracks_file = tracks_path or cat062_path
    truth, truth_scenarios = read_truth(truth_path)
    track_rows, truth_rows = _chosen(scenario, track_scenarios, truth_scenarios, truth_path)
    updates = TrackUpdates(*(getattr(updates, name)[track_rows] for name in
                             ("track_id", "time_s", "position", "velocity", "confirmed")))
    truth = Truth(*(getattr(truth, name)[truth_rows] for name in ("target_id", "time_s", "position", "in_coverage")))
    _check_overlap(updates, truth, tracks_file, truth_path)
    updates, truth = _separated(updates, track_scenarios[track_rows], truth, truth_scenarios[truth_rows],
                                tracks_file, truth_path)
    try:
        card = scorecard.scorecard(updates, truth, settings)
    except ValueError as error:
        raise io.InputError(f"{truth_path}: {error}") from None
    report = {"tracks": str(tracks_file), "truth": str(truth_path), "scenario": scenario,
              "settings": {"update_interval_s": settings.update_interval_s, "association_m": settings.association_m,
                           "miss_tolerance_scans": settings.miss_tolerance_scans,
                           "long_gap_scans": settings.long_gap_scans, "manoeuvre_mps2": settings.manoeuvre_mps2},
              "scorecard": card, "references": scorecard.judged(card)}
    text = markdown(report)
    io.write_json(report, out)
    io.write_text(text, markdown_path(out))
    log.info("score: %d confirmed updates of %d tracks against %d targets: position RMS %.1f m, probability of "
             "update %.4f, ratio of long gaps %.4f -> %s, %s", card["confirmed_updates"], card["confirmed_tracks"],
             card["targets"], card["position_rms_m"], card["probability_of_update"], card["ratio_of_long_gaps"],
             out, markdown_path(out))
    return report


def markdown(report: dict) -> str:
    """The scorecard as Markdown: the indicators, then the reference figures with pass or fail."""
    card = report["scorecard"]
    lines = [f"# Scorecard of {report['tracks']}", "", f"Against {report['truth']}; update interval "
             f"{report['settings']['update_interval_s']:g} s (`python -m pipeline score`, definitions in "
             "pipeline/surveillance/scorecard.py).", "", "| indicator | value |", "|---|---|"]
    lines += [f"| {name} | {_shown(value)} |" for name, value in card.items()]
    lines += ["", "| figures | indicator | value | reference | passes | source |", "|---|---|---|---|---|---|"]
    for row in report["references"]:
        bound = "<=" if row["at_most"] else ">="
        verdict = {True: "pass", False: "**fail**", None: "n/a"}[row["passes"]]
        lines.append(f"| {row['figures']} | {row['indicator']} | {_shown(row['value'])} | {bound} "
                     f"{_shown(row['reference'])} | {verdict} | {row['source']} |")
    return "\n".join(lines) + "\n"


def _shown(value: float) -> str:
    if isinstance(value, (int, np.integer)):
        return str(value)
    return "n/a" if not np.isfinite(value) else f"{value:.4g}"

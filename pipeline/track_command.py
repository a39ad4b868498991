"""`python -m pipeline track`: a tracker on a user's recording.

Input is either Parquet plots in the schema `simulate` writes (truth columns optional) with
a radar description, or ASTERIX CAT048 plots with CAT034 north markers; either becomes one plot
table (`pipeline.plot_table`), each plot with its radar's position and measurement covariance,
so a recording may hold plots of several radars, anywhere on Earth. The networks' default
`radial` window frame (`pipeline.scaling`) sees a flight relative to its radar, the same at any
site; networks trained with `windows.frame: ecef` (the thesis's) do not carry to a radar far from
the training site. The method loads only what it needs
(`pipeline.tracker.loading`): a classical one only the tuned filters.

Each scenario of the recording (all of it when the plots have no scenario id) is tracked on its
own, the plots of all its radars together.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from datetime import date
from pathlib import Path
from typing import Iterable, Iterator, Mapping

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import asterix_io, geodesy, io, plot_table, streamed_recording
from pipeline.params import Params, Radar
from pipeline.plot_table import NO_SCENARIO, Plots
from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.management import TrackManagement
from pipeline.tracker.refusals import RefusalCounts, warn_refusals
from pipeline.tracker.run import track_chunks
from pipeline.tracker.updates import positions

log = logging.getLogger("pipeline")

POSITION_COLUMNS = tuple((name, pa.float64()) for name in ("x_ecef_m", "y_ecef_m", "z_ecef_m", "latitude_deg",
                                                             "longitude_deg", "altitude_m"))  # a track's position
TRACK_SCHEMA = io.schema(
    ("radar_id", pa.int32()),
    ("scenario_id", pa.int32(), True),
    ("track_id", pa.int64()),
    ("time_unix_s", pa.float64()),
    ("plot_id", pa.int64()),
    *POSITION_COLUMNS,
    ("range_m", pa.float64()),
    ("weight", pa.float64()),
    ("status", pa.string()),
    ("association", pa.string()),
    ("association_error", pa.float64(), True),
    *((name, pa.float64(), True) for name in ("covariance_xx_m2", "covariance_xy_m2", "covariance_xz_m2",
                                              "covariance_yy_m2", "covariance_yz_m2", "covariance_zz_m2")),
)
TRACK_ROW_GROUP_ROWS = 65536  # rows per row group of `track`'s output: what the writer holds (about 200 B a row)
COVARIANCE_COLUMNS = TRACK_SCHEMA.names[-6:]  # the position's ECEF covariance, upper triangle; null when the
COVARIANCE_ENTRIES = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # estimator gives none (the networks)
SCAN_SLACK = 1.5  # scans a new track must outlive (`warn_short_silences`): half a revolution of slack for the
                  # plot's place in the scan, as M-of-N's miss (`pipeline.tracker.m_of_n`)


def covariance_columns(covariances: np.ndarray) -> dict[str, pa.Array]:
    """COVARIANCE_COLUMNS of (U, 3, 3) ECEF position covariances, m^2; null where NaN (an estimator giving none)."""
    return {name: pa.array(covariances[:, i, j], mask=np.isnan(covariances[:, i, j]))
            for name, (i, j) in zip(COVARIANCE_COLUMNS, COVARIANCE_ENTRIES)}


def warn_short_silences(management: TrackManagement, rule: str, radars: Mapping[int, Radar]) -> list[int]:
    """Warn for each radar of `radars` whose new tracks the management rule `management` (named
    `rule`) lowers before SCAN_SLACK of the radar's scans: a radar sees an aircraft once a
    revolution, a little more than a scan apart for one moving clockwise in azimuth (12.07 s at
    12 s, case 25), so such a radar's tracks could not live to their second plot. Returns those
    radars' ids (sorted)."""
    short = []
    for radar_id, radar in sorted(radars.items()):
        silence = management.silence(management.start, radar.scan_period_s)
        if silence < SCAN_SLACK * radar.scan_period_s:
            short.append(radar_id)
            log.warning("track: radar %d turns every %.6g s, but track management %r lowers a new track after "
                        "%.6g s of silence, less than %.6g of its scans: its tracks may never be confirmed (raise "
                        "tracker.silence_s or tracker.silence_scans)", radar_id, radar.scan_period_s, rule, silence,
                        SCAN_SLACK)
    return short


def track_recording(plots: Plots, method: str, window_m: float, params: Params, models_dir: Path) -> pa.Table:
    """Track every scenario of a recording with `method`; one row per track update (TRACK_SCHEMA),
    `range_m` the range from the plot's radar to the track's position. Warns as `track` does when the
    method's learned gate keeps refusing plots (`refusals.warn_refusals`)."""
    refusals = RefusalCounts()
    parts = [part for _, part, _ in tracked_parts(((scenario_id, iter([scenario]))
                                                   for scenario_id, scenario in plots.scenarios()),
                                                  plots.radars, method, window_m, params, models_dir, refusals)]
    warn_refusals(method, window_m, refusals, params.tracker.refusal_warning_share)
    return pa.concat_tables(parts) if parts else TRACK_SCHEMA.empty_table()


def tracked_parts(scenarios: Iterable[tuple[int, Iterable[Plots]]], radars: Mapping[int, Radar], method: str,
                  window_m: float, params: Params, models_dir: Path, refusals: RefusalCounts
                  ) -> Iterator[tuple[int, pa.Table, bool]]:
    """Track each scenario, given as its plots in time-ordered chunks, with `method`: the track
    updates (TRACK_SCHEMA) of each chunk in turn, with its scenario id and whether it is the
    scenario's first. `radars`: every radar of the recording; a radar too slow for the management
    rule's silence is warned of first (`warn_short_silences`). Each scenario's counts of plots its
    learned gate refused (`pipeline.tracker.refusals`; none for a method without one) are added to
    `refusals` once the scenario is tracked."""
    models = load_models(models_dir, params, [method])
    management = registry.management(params.tracker.management, params.tracker)
    warn_short_silences(management, params.tracker.management, radars)
    sites = {radar_id: geodesy.radar_site_ecef(radar) for radar_id, radar in radars.items()}
    for scenario_id, chunks in scenarios:
        seed = [params.tracker.seed, scenario_id] if scenario_id != NO_SCENARIO else [params.tracker.seed]
        tracker = registry.compose(method, models, params.tracker, window_m, seed)
        for number, updates in enumerate(track_chunks(chunks, tracker)):
            yield scenario_id, _track_table(updates, scenario_id, sites, management), number == 0
        if tracker.refusals is not None:
            refusals.add(tracker.refusals.counts)


def _track_table(updates: dict[str, np.ndarray], scenario_id: int, sites: Mapping[int, np.ndarray],
                 management: TrackManagement) -> pa.Table:
    """Track updates (`pipeline.tracker.updates`) of one scenario as TRACK_SCHEMA rows."""
    states = positions(updates)
    site = np.array([sites[r] for r in updates["radar_id"].tolist()]).reshape(-1, 3)
    lat, lon, alt = geodesy.ecef_to_geodetic(states)
    count = len(updates["track_id"])
    return pa.Table.from_pydict({
        "radar_id": updates["radar_id"].astype(np.int32),
        "scenario_id": pa.array(np.full(count, scenario_id, np.int32), mask=np.full(count, scenario_id < 0)),
        "track_id": updates["track_id"], "time_unix_s": updates["time_unix_s"], "plot_id": updates["plot_id"],
        "x_ecef_m": states[:, 0], "y_ecef_m": states[:, 1], "z_ecef_m": states[:, 2],
        "latitude_deg": lat, "longitude_deg": lon, "altitude_m": alt,
        "range_m": np.linalg.norm(states - site, axis=1), "weight": updates["weight"],
        "status": [management.status(w) for w in updates["weight"]],
        "association": updates["association"].astype(str), "association_error": updates["association_error"],
        **covariance_columns(updates["position_covariance"]),
    }, schema=TRACK_SCHEMA)


def summary_path(out: Path) -> Path:
    """Where `track` writes the summary of a run with output `out`: beside it, `<stem>.summary.json`."""
    return out.with_name(f"{out.stem}.summary.json")


class RunSummary:
    """What a user checks first after `track`, gathered as the track updates are written: the plots
    tracked, the records or plots left out by reason (`Plots.skipped`), the confirmed tracks, and
    per radar its plots and the confirmed tracks it fed, and the plots a learned gate refused that the
    window would have taken (`refusals`, `pipeline.tracker.refusals`). A track is one (scenario, track id): each
    scenario's radars are tracked together, so a track may hold plots of several radars; it counts
    once in the total and once for each radar whose plots updated it while confirmed. Holds the
    confirmed tracks' keys, not the updates."""

    def __init__(self, plots: int, plot_counts: Mapping[int, int], skipped: Mapping[str, int]) -> None:
        self.plots, self.plot_counts, self.skipped = plots, plot_counts, skipped
        self.updates = 0
        self.refusals = RefusalCounts()
        self.confirmed: dict[int, set[tuple[int, int]]] = {radar_id: set() for radar_id in plot_counts}

    def add(self, tracks: pa.Table) -> None:
        """Count a part of the track updates (TRACK_SCHEMA)."""
        self.updates += tracks.num_rows
        confirmed = np.asarray(tracks.column("status")) == "confirmed"
        radar_ids = np.asarray(tracks.column("radar_id"))[confirmed].tolist()
        scenario_ids = np.asarray(tracks.column("scenario_id").fill_null(NO_SCENARIO))[confirmed].tolist()
        track_ids = np.asarray(tracks.column("track_id"))[confirmed].tolist()
        for radar_id, key in zip(radar_ids, zip(scenario_ids, track_ids)):
            self.confirmed[radar_id].add(key)

    def report(self) -> dict:
        radars = {str(r): {"plots": self.plot_counts[r], "confirmed_tracks": len(self.confirmed[r])}
                  for r in sorted(self.plot_counts)}
        return {"plots_tracked": self.plots, "skipped": dict(sorted(self.skipped.items())),
                "plots_skipped": int(sum(self.skipped.values())), "track_updates": self.updates,
                "confirmed_tracks": len(set().union(*self.confirmed.values())), "radars": radars,
                "learned_gate": {"plots_in_window": self.refusals.in_window, "plots_refused": self.refusals.refused}}


def run_track(params: Params, plots_path: Path | None, radar_path: Path | None, asterix_paths: list[Path],
              first_date: date | None, method: str, window_m: float, models_dir: Path, out: Path,
              management: str | None = None) -> None:
    """Track a recording into `out` (TRACK_SCHEMA, row groups of TRACK_ROW_GROUP_ROWS updates) and its
    summary beside it (`summary_path`), under the track management rule `management` (one of
    `registry.MANAGEMENT`; None: params' `tracker.management`). The recording is placed, tracked and written
    `compute.chunk_plots` plots at a time: a Parquet recording is read from its file as it goes
    (`streamed_recording`), one out of time order sorted first into a temporary folder beside `out`
    (in its nearest existing folder), removed at the end; an ASTERIX recording is decoded whole
    first. Nothing is written on an error, nor when `out` or its summary would replace an input
    (`io.check_outputs`)."""
    inputs = {"--plots": [plots_path] if plots_path else [], "--radar": [radar_path] if radar_path else [],
              "--asterix": asterix_paths}
    io.check_outputs(inputs, {"--out": out, "--out's summary": summary_path(out)})
    if management is not None:
        params = dataclasses.replace(params, tracker=dataclasses.replace(params.tracker, management=management))
    if asterix_paths:
        if first_date is None:
            raise io.InputError("ASTERIX input carries only the time of day: give --date (UTC date of the first record)")
        if plots_path is not None:
            raise io.InputError("give --plots (Parquet) or --asterix files, not both")
        opened = contextlib.nullcontext(plot_table.read_asterix_recording(asterix_paths, first_date, params.radar,
                                                                          radar_path))
    else:
        if plots_path is None or radar_path is None:
            raise io.InputError("give --plots and --radar (Parquet), or --asterix files")
        scratch = next(folder for folder in out.absolute().parents if folder.exists())
        opened = streamed_recording.read_recording(plots_path, radar_path, params.radar, scratch)
    with opened as recording:
        _write_tracks(recording, method, window_m, params, models_dir, out,
                      plots_path or ", ".join(map(str, asterix_paths)))


def _write_tracks(recording: streamed_recording.RecordingParts, method: str, window_m: float, params: Params,
                  models_dir: Path, out: Path, source: Path | str) -> None:
    """`run_track`'s work once the recording (read from `source`) is open."""
    summary = RunSummary(len(recording), recording.plot_counts, recording.skipped)
    if not len(recording):
        log.warning("track: no plots to track in %s: the output will hold no track update", source)
    with io.parquet_chunks(out, TRACK_SCHEMA, TRACK_ROW_GROUP_ROWS) as written:
        for _, part, first in tracked_parts(recording.scenarios(params.chunk_plots), recording.radars, method,
                                             window_m, params, models_dir, summary.refusals):
            written.add(part, new_chunk=first)
            summary.add(part)
        report = summary.report()
        io.write_json(report, summary_path(out))
    warn_refusals(method, window_m, summary.refusals, params.tracker.refusal_warning_share)
    skipped = ", ".join(f"{count} {reason}" for reason, count in report["skipped"].items())
    log.info("track: %d plots (%s), %d track updates, %d confirmed tracks on %d radars -> %s, summary %s",
             len(recording), f"skipped {skipped}" if skipped else "none skipped", report["track_updates"],
             report["confirmed_tracks"], len(recording.radars), out, summary_path(out))


EXPORT_PLOT_SCHEMA = io.schema(  # the columns of `simulate.PLOT_SCHEMA` that `export_asterix` writes
    ("scenario_id", pa.int32()), ("scan", pa.int64()), ("time_unix_s", pa.float64()), ("range_m", pa.float64()),
    ("azimuth_deg", pa.float64()), ("flight_level", pa.float64()),
)


def export_asterix(plots_path: Path, radar_path: Path, scenario_id: int, out: Path) -> None:
    """Write one simulated scenario as a CAT034 + CAT048 recording; `out` must not be an input."""
    io.check_outputs({"--plots": [plots_path], "--radar": [radar_path]}, {"--out": out})
    plots = io.read_parquet(plots_path, EXPORT_PLOT_SCHEMA)
    plots = plots.filter(pa.compute.equal(plots.column("scenario_id"), scenario_id))
    if plots.num_rows == 0:
        raise io.InputError(f"{plots_path}: no plots of scenario {scenario_id}")
    radar = io.read_parquet(radar_path, pq.read_schema(radar_path)).to_pylist()[0]
    scans = np.unique(plots.column("scan").to_numpy()) * radar["scan_period_s"]
    data = asterix_io.encode(plots, radar, scans)
    with io.atomic_path(out) as temporary:
        temporary.write_bytes(data)
    log.info("asterix: scenario %d, %d plots, %d north markers -> %s", scenario_id, plots.num_rows, len(scans), out)

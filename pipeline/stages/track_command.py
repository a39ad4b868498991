"""`python -m pipeline track`: a tracker on a user's recording.

Input is either Parquet plots in the schema `simulate` writes (truth columns optional) with
a radar description, or ASTERIX CAT048 plots with CAT034 north markers; either becomes one plot
table (`pipeline.recordings.plot_table`), each plot with its radar's position and measurement covariance,
so a recording may hold plots of several radars, anywhere on Earth. The networks' default
`radial` window frame (`pipeline.learning.scaling`) sees a flight relative to its radar, the same at any
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
from typing import Mapping

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import io
from pipeline.learning.experiment_tracking import data_hash
from pipeline.params import Params
from pipeline.progress import progress_logger
from pipeline.recordings import asterix_io, plot_table, streamed_recording
from pipeline.recordings.plot_table import NO_SCENARIO
from pipeline.surveillance import cat062
from pipeline.tracker.loading import model_paths
from pipeline.tracker.recording import TRACK_SCHEMA, tracked_parts
from pipeline.tracker.refusals import RefusalCounts, warn_refusals
from pipeline.tracker.updates import START

log = logging.getLogger("pipeline")

STATUSES = ("tentative", "candidate", "confirmed")  # a track update's status (`TrackManagement.status`)
TRACK_ROW_GROUP_ROWS = 65536  # rows per row group of `track`'s output: what the writer holds (about 200 B a row)


def summary_path(out: Path) -> Path:
    """Where `track` writes the summary of a run with output `out`: beside it, `<stem>.summary.json`."""
    return out.with_name(f"{out.stem}.summary.json")


class RunSummary:
    """What a user checks first after `track`, gathered as the track updates are written: how the tracks
    were made (`made`: method, window, management rule, the model files with their digests), the plots
    tracked, the records or plots left out by reason (`Plots.skipped`), the tracks started, the updates by
    status, the confirmed tracks, and per radar its plots and the confirmed tracks it fed, and the plots a
    learned gate refused that the window would have taken (`refusals`, `pipeline.tracker.refusals`). A
    track is one (scenario, track id): each scenario's radars are tracked together, so a track may hold
    plots of several radars; it counts once in the total and once for each radar whose plots updated it
    while confirmed. Holds the confirmed tracks' keys, not the updates."""

    def __init__(self, made: dict, plots: int, plot_counts: Mapping[int, int], skipped: Mapping[str, int]) -> None:
        self.made, self.plots, self.plot_counts, self.skipped = made, plots, plot_counts, skipped
        self.updates, self.tracks, self.written = 0, 0, 0
        self.by_status = {status: 0 for status in STATUSES}
        self.refusals = RefusalCounts()
        self.confirmed: dict[int, set[tuple[int, int]]] = {radar_id: set() for radar_id in plot_counts}

    def add(self, tracks: pa.Table) -> None:
        """Count a part of the track updates (TRACK_SCHEMA)."""
        self.updates += tracks.num_rows
        self.tracks += int(np.count_nonzero(np.asarray(tracks.column("association")) == START))
        status = np.asarray(tracks.column("status"))
        for name in STATUSES:
            self.by_status[name] += int(np.count_nonzero(status == name))
        confirmed = status == "confirmed"
        radar_ids = np.asarray(tracks.column("radar_id"))[confirmed].tolist()
        scenario_ids = np.asarray(tracks.column("scenario_id").fill_null(NO_SCENARIO))[confirmed].tolist()
        track_ids = np.asarray(tracks.column("track_id"))[confirmed].tolist()
        for radar_id, key in zip(radar_ids, zip(scenario_ids, track_ids)):
            self.confirmed[radar_id].add(key)

    def report(self) -> dict:
        radars = {str(r): {"plots": self.plot_counts[r], "confirmed_tracks": len(self.confirmed[r])}
                  for r in sorted(self.plot_counts)}
        return {**self.made, "plots_tracked": self.plots, "skipped": dict(sorted(self.skipped.items())),
                "plots_skipped": int(sum(self.skipped.values())), "track_updates": self.updates,
                "track_updates_by_status": self.by_status, "rows_written": self.written, "tracks": self.tracks,
                "confirmed_tracks": len(set().union(*self.confirmed.values())), "radars": radars,
                "learned_gate": {"plots_in_window": self.refusals.in_window, "plots_refused": self.refusals.refused}}


def how_made(method: str, window_m: float, params: Params, models_dir: Path, confirmed_only: bool) -> dict:
    """What made a `track` run's output, for its summary: the method, window, track management rule, whether
    only confirmed updates were written, and each model file the method read with its digest
    (`experiment_tracking.data_hash`: the tag a registered MLflow model version carries, so the summary
    names the version that made the tracks)."""
    paths = model_paths(models_dir, [method])
    return {"method": method, "window_m": window_m, "management": params.tracker.management.rule,
            "confirmed_only": confirmed_only,
            "models": {str(path): data_hash(path) for _, path in sorted(paths.items())}}


@dataclasses.dataclass(frozen=True)
class SystemTrackOutput:
    """Where `track` also writes its updates as ASTERIX CAT062 system tracks, and the SAC/SIC (I062/010) of the
    tracker that sends them (`pipeline.surveillance.cat062`)."""

    path: Path
    sac: int = 0
    sic: int = 1


def run_track(params: Params, plots_path: Path | None, radar_path: Path | None, asterix_paths: list[Path],
              first_date: date | None, method: str, window_m: float, models_dir: Path, out: Path,
              management: str | None = None, confirmed_only: bool = False,
              system_tracks: SystemTrackOutput | None = None) -> None:
    """Track a recording into `out` (TRACK_SCHEMA, row groups of TRACK_ROW_GROUP_ROWS updates; with
    `confirmed_only` only the updates of confirmed tracks) and its summary beside it (`summary_path`), under
    the track management rule `management` (one of `registry.MANAGEMENT`; None: params'
    `tracker.management.rule`), with a progress line at most every `compute.progress_every_s`. The recording is placed, tracked and written
    `compute.chunk_plots` plots at a time: a Parquet recording is read from its file as it goes
    (`streamed_recording`), one out of time order sorted first into a temporary folder beside `out`
    (in its nearest existing folder), removed at the end; an ASTERIX recording is decoded whole
    first. With `system_tracks`, the written updates go also to a CAT062 file, about the site of the
    recording's first radar (the lowest id) as system reference point; it is made from the updates held in
    memory at the end. Nothing is written on an error, nor when an output would replace an input
    (`io.check_outputs`)."""
    inputs = {"--plots": [plots_path] if plots_path else [], "--radar": [radar_path] if radar_path else [],
              "--asterix": asterix_paths}
    outputs = {"--out": out, "--out's summary": summary_path(out)}
    if system_tracks is not None:
        outputs["--cat062"] = system_tracks.path
        for name, value in (("--sac", system_tracks.sac), ("--sic", system_tracks.sic)):
            if not 0 <= value <= 255:
                raise io.InputError(f"{name} {value} is not a byte (0 to 255)")
    io.check_outputs(inputs, outputs)
    if management is not None:
        rules = dataclasses.replace(params.tracker.management, rule=management)
        params = dataclasses.replace(params, tracker=dataclasses.replace(params.tracker, management=rules))
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
        made = how_made(method, window_m, params, models_dir, confirmed_only)
        log.info("track: method %s, window %g m, track management %s, models %s", method, window_m,
                 made["management"], ", ".join(made["models"]) or "none but params")
        _write_tracks(recording, made, params, models_dir, out, plots_path or ", ".join(map(str, asterix_paths)),
                      system_tracks)


def _write_tracks(recording: streamed_recording.RecordingParts, made: dict, params: Params, models_dir: Path,
                  out: Path, source: Path | str, system_tracks: SystemTrackOutput | None) -> None:
    """`run_track`'s work once the recording (read from `source`) is open, made as `made` says (`how_made`)."""
    method, window_m = made["method"], made["window_m"]
    summary = RunSummary(made, len(recording), recording.plot_counts, recording.skipped)
    if not len(recording):
        log.warning("track: no plots to track in %s: the output will hold no track update", source)
    progress = progress_logger("track: plots tracked", params.progress_every_s)
    held = []  # the written updates, for CAT062
    with io.parquet_chunks(out, TRACK_SCHEMA, TRACK_ROW_GROUP_ROWS) as written:
        for _, part, first in tracked_parts(recording.scenarios(params.chunk_plots), recording.radars, method,
                                             window_m, params, models_dir, summary.refusals):
            summary.add(part)
            if made["confirmed_only"]:
                part = part.filter(pa.compute.equal(part.column("status"), "confirmed"))
            written.add(part, new_chunk=first)
            summary.written += part.num_rows
            if system_tracks is not None:
                held.append(part)
            progress(summary.updates, len(recording))
        report = summary.report()
        if system_tracks is not None:
            _write_system_tracks(pa.concat_tables(held) if held else TRACK_SCHEMA.empty_table(), recording.radars,
                                 system_tracks)
        io.write_json(report, summary_path(out))
    warn_refusals(method, window_m, summary.refusals, params.tracker.refusal_warning_share,
                  params.tracker.lstm_update.young_window_fallback)
    skipped = ", ".join(f"{count} {reason}" for reason, count in report["skipped"].items())
    seen = sum(1 for count in recording.plot_counts.values() if count)  # a radar whose every plot was skipped: none
    unseen = [str(radar_id) for radar_id, count in sorted(recording.plot_counts.items()) if not count]
    confirmed = report["track_updates_by_status"]["confirmed"]
    log.info("track: %d plots (%s), %s of %s, %d of them (%.1f %%) of %s, on the plots of %s%s -> %s (%s), "
             "summary %s", len(recording), f"skipped {skipped}" if skipped else "none skipped",
             _counted(report["track_updates"], "track update"), _counted(report["tracks"], "track"), confirmed,
             100.0 * confirmed / max(report["track_updates"], 1), _counted(report["confirmed_tracks"], "confirmed track"),
             _counted(seen, "radar"), f" (no plot tracked of radar {', '.join(unseen)})" if unseen else "", out,
             "confirmed updates only" if made["confirmed_only"] else "every update", summary_path(out))


def _write_system_tracks(tracks: pa.Table, radars: Mapping, output: SystemTrackOutput) -> None:
    """`tracks` as CAT062 to `output.path`, about the site of the lowest radar id (module `cat062`)."""
    site = radars[min(radars)] if radars else None
    reference = cat062.SystemReference(site.latitude_deg if site else 0.0, site.longitude_deg if site else 0.0)
    cat062.write_cat062(tracks, output.path, output.sac, output.sic, reference)
    log.info("track: %s CAT062 system track records (SAC %d, SIC %d; I062/100 about %.6f N, %.6f E, the site of "
             "radar %s) -> %s", tracks.num_rows, output.sac, output.sic, reference.latitude_deg,
             reference.longitude_deg, min(radars) if radars else "none", output.path)


def _counted(count: int, noun: str) -> str:
    """"1 track", "2 tracks"."""
    return f"{count} {noun}{'' if count == 1 else 's'}"


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

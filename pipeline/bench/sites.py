"""The evaluated routes at other radar sites: does a tracker work wherever its radar stands?

Routes are planned on the radar's tangent plane (`pipeline.simulation.routes`) from seeds that do not
involve the site, so generating the evaluated split with the radar moved gives the same
manoeuvres, the same east-north tracks, the same times, flown past a radar at the new site;
the simulation's streams do not involve the site either, so the radar draws the same noise,
detections and clutter. What changes is only where the earth puts them: the ECEF coordinates,
the ellipsoid's curvature under the coverage, and the longitudes (which wrap at 180°).

Each site's split is written to a temporary folder as the routes and simulate stages write
theirs, and scored by `pipeline.bench.evaluation` exactly as the `evaluate` stage scores the
training site, every run and reference over every scenario. The metrics leave out the speeds
(timings), so the report is the same byte for byte whatever the number of workers.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from pipeline import io
from pipeline.bench import evaluation
from pipeline.bench.runs import by_name
from pipeline.params import Params, Site
from pipeline.progress import progress_logger
from pipeline.simulation import routes, simulate

log = logging.getLogger("pipeline")

SITE_FOLDER = "pipeline-site"  # the prefix of a site's temporary split in the system's temporary folder


def at_site(params: Params, site: Site) -> Params:
    """Params with the radar at `site` and only the runs scored at sites (`evaluate.site_runs`);
    everything else, seeds included, unchanged."""
    return dataclasses.replace(
        params, radar=dataclasses.replace(params.radar, latitude_deg=site.latitude_deg,
                                          longitude_deg=site.longitude_deg, height_m=site.height_m),
        evaluate=dataclasses.replace(params.evaluate, runs=params.evaluate.runs_at_sites()))


def place_split(params: Params, folder: Path, label: str) -> None:
    """The evaluated split's routes and simulated plots for params' radar, in `folder` laid out as
    the stages lay theirs out: `routes/<split>.parquet`, `simulated/<split>/{plots,truth,radar}.parquet`."""
    split = params.routes.split(params.evaluate.split)
    route_table = routes.generate_split(params, split, progress_logger(f"{label} routes"))
    plots, truth = simulate.simulate_split(params, split, route_table, progress_logger(f"{label} simulate"))
    io.write_parquet(route_table, folder / "routes" / f"{split.name}.parquet")
    simulate.write_split(plots, truth, simulate.radar_description(params), folder / "simulated" / split.name)


def without_speeds(runs: dict[str, dict]) -> dict[str, dict]:
    """Each run's metrics but its speed, a timing that differs from run to run."""
    return {name: {k: v for k, v in values.items() if k != evaluation.SPEED} for name, values in runs.items()}


def site_entry(name: str, latitude_deg: float, longitude_deg: float, height_m: float, runs: dict[str, dict],
               bounds: dict[str, float]) -> dict:
    """One site's part of the report: where it is, its plot counts, every run's metrics (as
    `reports/tracker_metrics.json` has them, without the speeds) and the PCRB's horizontal RMS there by model
    (`evaluation.split_bounds`)."""
    first = next(iter(runs.values()))
    return {"name": name, "latitude_deg": latitude_deg, "longitude_deg": longitude_deg, "height_m": height_m,
            "plots": {"target": first["target_plots"], "false": first["false_plots"]}, "runs": without_speeds(runs),
            "pcrb_horizontal_rms_m": bounds}


def evaluate_site(params: Params, site: Site, models_dir: Path) -> dict:
    """Every run and reference of params over the evaluated split placed at `site`, in
    `params.workers` processes: the site's report entry."""
    label = f"site {site.name}"
    moved = at_site(params, site)
    with io.temporary_folder(SITE_FOLDER) as folder:
        place_split(moved, folder, label)
        prepared = evaluation.prepare(moved, folder / "simulated", folder / "routes", models_dir)
        runs, *_ = evaluation.evaluate_all(prepared, params.workers, label)
        bounds = evaluation.split_bounds(moved, folder / "simulated", models_dir)
    return site_entry(site.name, site.latitude_deg, site.longitude_deg, site.height_m, by_name(runs), bounds)


def site_metrics(params: Params, training_runs: dict[str, dict], training_bounds: dict[str, float],
                 models_dir: Path) -> dict:
    """The report: the training site's runs and bounds (the `evaluate` stage's, `training_runs` and
    `training_bounds`) and each of `evaluate.sites` in params order."""
    radar = params.radar
    return {"split": params.evaluate.split,
            "training": site_entry("training", radar.latitude_deg, radar.longitude_deg, radar.height_m, training_runs,
                                   training_bounds),
            "sites": [evaluate_site(params, site, models_dir) for site in params.evaluate.sites]}

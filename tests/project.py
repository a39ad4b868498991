"""Helpers for tests that run the pipeline as a user does: tiny params, a copy of the repository."""

from __future__ import annotations

import copy
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml

from pipeline.params import STRATEGIES, load_params_tree

REPOSITORY = Path(__file__).resolve().parent.parent


def default_params_tree() -> dict[str, Any]:
    return load_params_tree(REPOSITORY / "params.yaml")


def tiny_params_tree(routes_per_strategy: int = 2) -> dict[str, Any]:
    """The default params with a handful of routes per split and two training epochs (no early
    stopping, so a run's length is its `epochs`): the whole pipeline in about a minute."""
    tree = copy.deepcopy(default_params_tree())
    for split in tree["routes"]["splits"].values():
        split.update(dict.fromkeys(STRATEGIES, routes_per_strategy))
    tree["report"]["example_routes"] = 1
    tree["scenes"].update(count=1, aircraft=6, duration_s=180.0, formation_size=[2, 2])  # the situations, no others
    tree["windows"]["holdout_fraction"] = 0.25  # a handful of segments: 5 % would hold out none
    for network in ("filter", "predictor", "autoencoder"):
        tree["training"][network]["epochs"] = 2
        tree["training"][network]["early_stopping_patience"] = 0  # runs of a fixed length, as tests expect
        tree["training"][network]["lr_decay_patience"] = 1
    tree["kalman_net"].update(epochs=1, baseline_epochs=1, segment_plots=16, truncation_steps=8)  # seconds
    tree["association"].update(epochs=1, scenes_per_epoch=16, eval_scenes=4, eval_bias_m=[0.0, 200.0])  # seconds
    tree["confirmation"].update(epochs=3, validation_every=3)  # seconds; every third training scenario held out
    tree["fusion"].update(sweep_scenes=1, sweep_bias_m=[0.0, 200.0])  # the bias sweep in seconds
    tree["lstm_update"].update(epochs=1, segment_plots=16, truncation_steps=8, mc_samples=4, validation_fraction=0.2,
                                calibration_ages=4)
    tree["evaluate"]["site_runs"] = tree["evaluate"]["scene_runs"] = []  # every run of the few below
    tree["evaluate"]["runs"] = [{"method": "via", "window_m": 4000.0}, {"method": "ae", "window_m": 5000.0},
                                {"method": "kalman_cv", "window_m": 4000.0}]
    tree["evaluate"]["example_scenarios"] = 1
    tree["evaluate"]["example_run"] = "via_4000"
    tree["evaluate"].update(seeds=2, bootstrap_replicates=200)  # a second draw of every scenario, in seconds
    tree["peers"].update(scenarios_per_strategy=1, window_s=60.0, scenes=1, scene_window_s=60.0,  # Stone Soup on a
                         runs=[])                                                                 # few hundred plots
    # evaluate_sites: the training site again (must give evaluate's metrics) and one across the world
    radar = tree["radar"]
    tree["evaluate"]["sites"] = [
        {"name": "home", "latitude_deg": radar["latitude_deg"], "longitude_deg": radar["longitude_deg"],
         "height_m": radar["height_m"]},
        {"name": "south_dateline", "latitude_deg": -60.0, "longitude_deg": 179.9, "height_m": radar["height_m"]}]
    return tree


def write_params(tree: dict[str, Any], path: Path) -> Path:
    path.write_text(yaml.safe_dump(tree, sort_keys=False))
    return path


def environment() -> dict[str, str]:
    """The test's environment, with this interpreter's folder first on PATH so DVC's `python` is ours."""
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    return env


def run_pipeline(*arguments: str, cwd: Path = REPOSITORY) -> subprocess.CompletedProcess:
    """`python -m pipeline ...` in a fresh process, output captured."""
    return subprocess.run([sys.executable, "-m", "pipeline", *arguments], cwd=cwd, env=environment(),
                          capture_output=True, text=True)


def copy_repository(destination: Path) -> Path:
    """The files git would give a fresh clone (tracked or not ignored), in a new git repository."""
    listing = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
                             cwd=REPOSITORY, capture_output=True, text=True, check=True).stdout
    for name in filter(None, listing.split("\0")):
        source = REPOSITORY / name
        if source.is_file():
            target = destination / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    git = ["git", "-c", "user.name=test", "-c", "user.email=test@example.invalid"]
    subprocess.run(["git", "init", "-q"], cwd=destination, check=True)
    subprocess.run([*git, "add", "-A"], cwd=destination, check=True)
    subprocess.run([*git, "commit", "-q", "-m", "copy"], cwd=destination, check=True)
    return destination

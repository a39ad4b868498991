"""Small two-radar track sets for the association tests: straight aircraft seen by both radars."""

from __future__ import annotations

import numpy as np

from pipeline.association.association_scenes import SceneSetting, make_tracks

SETTING = SceneSetting(targets=(16, 32), area_m=10000.0, scan_period_s=4.0, track_points=5, noise_m=(50.0, 70.0),
                       detection_probability=0.9, speed_mps=(100.0, 300.0), acceleration_std_mps2=1.0,
                       bias_m=(0.0, 200.0), tracks="kalman")


def straight_aircraft(starts_m: np.ndarray, velocities_mps: np.ndarray, bias_m: np.ndarray, seed: int = 0,
                      time_offset_s: float = 0.0):
    """Both radars' track histories (L, N, 4) and covariances of aircraft flying straight from `starts_m` (N, 2)
    at `velocities_mps` (N, 2); radar 2's plots shifted by `bias_m` (2,) and stamped `time_offset_s` late (each
    aircraft's that far back along its velocity). Same track order in both radars."""
    rng = np.random.default_rng(seed)
    times = np.arange(SETTING.track_points) * SETTING.scan_period_s
    truth = starts_m[None] + times[:, None, None] * velocities_mps[None]
    tracks = []
    for radar, sigma in enumerate(SETTING.noise_m):
        late = (bias_m - time_offset_s * velocities_mps[None]) if radar == 1 else 0.0
        plots = truth + rng.normal(0.0, sigma, truth.shape) + late
        tracks.append(make_tracks(plots, SETTING, sigma))
    return tracks[0][0], tracks[0][1], tracks[1][0], tracks[1][1]

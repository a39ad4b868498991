"""The network-scaled filter, the gradient-tuned and the Nelder-Mead tuned filters on the hold-out windows.

The same windows as the table "Networks against the tuned filters on the hold-out windows"
(`compare_stage.holdout_comparison`): every `windows.filter_length`-plot window of the windows
stage's hold-out segments (5 % of the train split's segments, `windows.holdout_segments`), each
filter started afresh at the window's first plot with the plots' converted-measurement covariance,
and scored at the window's last plot against the truth: mean distance, RMSE, 95th percentile (m)
and the mean position NEES e' P^-1 e (3 for a filter whose covariance tells the truth).

Against the noise level: the hold-out plots measured again from their truth with the radar's
model (`radar.add_measurement_noise`, `radar.measure`: range, azimuth and altitude errors, CAT048
quantisation) with every sigma multiplied by a factor, while every filter keeps the nominal R (it
does not know the factor). Factor 1 is a fresh draw of the radar's own noise.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np
import torch
from scipy.stats import chi2

from pipeline.filters.torch_filters import Filtered, SequenceBatch
from pipeline.geometry import geodesy
from pipeline.learning import windows
from pipeline.params import Radar
from pipeline.simulation import radar as radar_model

FilterRun = Callable[[SequenceBatch], Filtered]  # a filter over a batch (no truncation)


def window_batch(plots: windows.TargetPlots, radar: Radar, length: int) -> SequenceBatch:
    """The hold-out windows (B, length) as a batch: restart at the first plot, only the last scored."""
    starts = windows.window_starts(plots.segment_id, length)
    raw = windows.gather(plots.plot_features(), starts, length)
    truth = windows.gather(plots.true_features(), starts, length)[..., 1:4]
    positions = raw[..., 1:4]
    covariances = geodesy.measurement_covariance(positions.reshape(-1, 3), radar).reshape(*positions.shape[:2], 3, 3)
    shape = positions.shape[:2]
    restart, scored = np.zeros(shape, bool), np.zeros(shape, bool)
    restart[:, 0], scored[:, -1] = True, True
    as_tensor = lambda values: torch.as_tensor(np.ascontiguousarray(values))  # noqa: E731
    return SequenceBatch(as_tensor(raw[..., 0]), as_tensor(positions), as_tensor(covariances), as_tensor(truth),
                         torch.ones(shape, dtype=torch.bool), as_tensor(restart), as_tensor(scored))


def renoised(plots: windows.TargetPlots, radar: Radar, factor: float, rng: np.random.Generator) -> windows.TargetPlots:
    """The plots measured again from their truth by `radar` with its sigmas times `factor` (module docstring)."""
    noisy = replace(radar, sigma_range_m=radar.sigma_range_m * factor,
                    sigma_azimuth_deg=radar.sigma_azimuth_deg * factor, sigma_altitude_m=radar.sigma_altitude_m * factor)
    measured = radar_model.measure(plots.time, *radar_model.add_measurement_noise(
        rng, *geodesy.true_measurement(plots.true_position, radar), noisy), radar=radar, reference_unix_s=plots.time)
    return replace(plots, position=measured.ecef, range_m=measured.range_m)


def scores(batch: SequenceBatch, filtered: Filtered) -> dict[str, float]:
    """Error of the scored (last) plots' estimates: mean, RMSE and 95th percentile (m), ANEES."""
    error = (filtered.position[batch.scored] - batch.truth[batch.scored]).detach()
    distance = error.norm(dim=-1).numpy()
    covariance = filtered.covariance[batch.scored].detach()
    nees = (error[:, None, :] @ torch.linalg.solve(covariance, error[:, :, None]))[:, 0, 0].numpy()
    return {"mean_error_m": float(distance.mean()), "rmse_m": float(np.sqrt((distance ** 2).mean())),
            "p95_error_m": float(np.percentile(distance, 95)), "anees": float(nees.mean())}


def detailed_scores(plots: windows.TargetPlots, length: int, batch: SequenceBatch, filtered: Filtered,
                    turn_share: float, range_shares: tuple[float, ...]) -> dict:
    """`scores` on the `window_batch` windows, and beside them:
    - the mean error (m) in turns, the `turn_share` of windows of lowest truth linearity
      (`windows.linearity`, thesis eq. 4.7), and on the straight rest;
    - the ANEES's chi-square 95 % bounds: with n windows and 3 degrees of freedom each, n ANEES is
      chi-square with 3n degrees of freedom if the covariances tell the truth (Bar-Shalom, Li and
      Kirubarajan 2001, section 5.4.2), so chi2.ppf([0.025, 0.975], 3n) / n, and whether it is inside;
    - the seed's accuracy measure (`shared/spec/related-work.md` section A, "5 % accuracy"): for each
      of `range_shares`, the share of windows whose error is within it times the target's true range
      at the scored plot."""
    starts = windows.window_starts(plots.segment_id, length)
    straightness = windows.linearity(windows.gather(plots.true_position, starts, length))
    turning = straightness <= np.quantile(straightness, turn_share)
    distance = (filtered.position[batch.scored] - batch.truth[batch.scored]).detach().norm(dim=-1).numpy()
    true_range = plots.true_range_m[starts + length - 1]
    result = scores(batch, filtered)
    n = len(distance)
    low, high = chi2.ppf([0.025, 0.975], 3 * n) / n
    return {**result, "turn_mean_error_m": float(distance[turning].mean()),
            "straight_mean_error_m": float(distance[~turning].mean()), "turn_windows": int(turning.sum()),
            "anees_bounds": [float(low), float(high)], "anees_inside": bool(low <= result["anees"] <= high),
            "within_range_share": {f"{share:g}": float((distance <= share * true_range).mean())
                                   for share in range_shares}}


def compare(plots: windows.TargetPlots, radar: Radar, length: int, filters: dict[str, FilterRun],
            factors: tuple[float, ...], seed: int) -> dict:
    """Each filter's `scores` on the hold-out windows, and its mean error with the plots re-noised at
    each noise factor (one draw per factor, the same for every filter)."""
    batch = window_batch(plots, radar, length)
    with torch.no_grad():
        result = {"windows": int(len(batch.times)), "filters": {name: scores(batch, run(batch))
                                                                for name, run in filters.items()},
                  "noise_factors": list(factors), "mean_error_by_noise_m": {name: [] for name in filters}}
        rng = np.random.default_rng(seed)
        for factor in factors:
            noisy = window_batch(renoised(plots, radar, factor, rng), radar, length)
            for name, run in filters.items():
                result["mean_error_by_noise_m"][name].append(scores(noisy, run(noisy))["mean_error_m"])
    return result


def compare_detailed(plots: windows.TargetPlots, radar: Radar, length: int, filters: dict[str, FilterRun],
                     turn_share: float, range_shares: tuple[float, ...]) -> dict:
    """Each filter's `detailed_scores` on the hold-out windows, and how many windows."""
    batch = window_batch(plots, radar, length)
    with torch.no_grad():
        return {"windows": int(len(batch.times)),
                "filters": {name: detailed_scores(plots, length, batch, run(batch), turn_share, range_shares)
                            for name, run in filters.items()}}

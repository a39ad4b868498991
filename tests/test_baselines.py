"""The classical references the networks are measured against: the radar's measurement
covariance, a constant-velocity Kalman filter and linear extrapolation.

Tracks are built on the radar's tangent plane (east, north, up) and moved to ECEF with
geodesy.enu_rotation, so the expected errors can be read off in the radar's own axes.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.filters import baselines
from pipeline.geometry import geodesy
from pipeline.params import Radar

T0 = 1.78e9  # an instant in 2026, in Unix seconds
SCAN_S = 6.0
ACCELERATION_STD = 10.0  # params.yaml: training.kalman_acceleration_std_mps2
MAX_SPEED = 400.0


@pytest.fixture(scope="module")
def radar(make_params) -> Radar:
    return make_params(1).radar


def to_ecef(local: np.ndarray, radar: Radar) -> np.ndarray:
    """Points given as (east, north, up) offsets from the radar, in ECEF."""
    rotation = geodesy.enu_rotation(radar.latitude_deg, radar.longitude_deg)
    return local @ rotation + geodesy.radar_site_ecef(radar)


def straight_tracks(radar: Radar, count: int, steps: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`count` constant-velocity tracks seen every scan: times (N x L), ECEF positions (N x L x 3),
    and the function time -> true position, for checking predictions."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0.0, 2 * np.pi, count)
    speed = rng.uniform(100.0, 300.0, count)
    start = np.column_stack([rng.uniform(-150e3, 150e3, count), rng.uniform(-150e3, 150e3, count),
                             rng.uniform(2e3, 10e3, count)])
    velocity = np.column_stack([speed * np.sin(heading), speed * np.cos(heading), np.zeros(count)])
    times = T0 + SCAN_S * np.tile(np.arange(steps, dtype=float), (count, 1))

    def truth(at: np.ndarray) -> np.ndarray:
        return to_ecef(start[:, None, :] + velocity[:, None, :] * (at - T0)[..., None], radar)

    return times, truth(times), truth


def covariances(positions: np.ndarray, radar: Radar) -> np.ndarray:
    """Measurement covariance of every plot of (N x L x 3) positions: (N x L x 3 x 3)."""
    return geodesy.measurement_covariance(positions.reshape(-1, 3), radar).reshape(*positions.shape, 3)


def test_measurement_covariance_is_range_across_azimuth_and_altitude_in_radar_axes(radar):
    """200 km due north: std (range * sigma_azimuth east, sigma_range north, sigma_altitude up), no correlation."""
    covariance = geodesy.measurement_covariance(to_ecef(np.array([[0.0, 200e3, 0.0]]), radar), radar)[0]
    rotation = geodesy.enu_rotation(radar.latitude_deg, radar.longitude_deg)
    enu = rotation @ covariance @ rotation.T
    expected_std = [200e3 * np.radians(radar.sigma_azimuth_deg), radar.sigma_range_m, radar.sigma_altitude_m]
    np.testing.assert_allclose(np.sqrt(np.diag(enu)), expected_std, rtol=1e-9)
    np.testing.assert_allclose(enu - np.diag(np.diag(enu)), 0.0, atol=1e-6)


@pytest.mark.parametrize("local", [(0.0, 200e3, 0.0), (-150e3, 80e3, 9e3), (0.0, 0.0, 8e3)],
                         ids=["north", "north-west", "overhead"])
def test_measurement_covariance_is_symmetric_positive_definite(radar, local):
    """Anywhere in coverage, even straight above the radar, the covariance is a valid one."""
    covariance = geodesy.measurement_covariance(to_ecef(np.array([local]), radar), radar)[0]
    np.testing.assert_allclose(covariance, covariance.T, rtol=0.0, atol=1e-9 * np.abs(covariance).max())
    assert np.linalg.eigvalsh(covariance).min() > 0.0


def test_kalman_filter_follows_a_noiseless_straight_track(radar):
    """Exact plots of constant-velocity tracks: the filtered last position is the truth within 1 m."""
    times, positions, _ = straight_tracks(radar, count=20, steps=10, seed=1)
    estimate = baselines.kalman_filtered_last(times, positions, covariances(positions, radar), ACCELERATION_STD,
                                              MAX_SPEED)
    assert estimate.shape == (20, 3)
    np.testing.assert_allclose(estimate, positions[:, -1], rtol=0.0, atol=1.0)


def test_kalman_filter_is_closer_to_the_truth_than_noisy_plots(radar):
    """Plots with the radar's noise: on average over 300 windows the filtered last position beats the raw plot."""
    times, truth, _ = straight_tracks(radar, count=300, steps=10, seed=2)
    covariance = covariances(truth, radar)
    noise = np.einsum("nlij,nlj->nli", np.linalg.cholesky(covariance),
                      np.random.default_rng(3).standard_normal(truth.shape))
    plots = truth + noise
    estimate = baselines.kalman_filtered_last(times, plots, covariance, ACCELERATION_STD, MAX_SPEED)
    kalman_error = np.linalg.norm(estimate - truth[:, -1], axis=1).mean()
    raw_error = np.linalg.norm(plots[:, -1] - truth[:, -1], axis=1).mean()
    assert kalman_error < raw_error


def test_kalman_prediction_of_a_constant_velocity_track(radar):
    """Filtering 10 exact plots, then predicting 1.5 scans ahead, lands on the true future position within 1 m."""
    times, positions, truth = straight_tracks(radar, count=20, steps=10, seed=4)
    target_times = times[:, -1] + 1.5 * SCAN_S
    predicted = baselines.kalman_predicted(times, positions, covariances(positions, radar), target_times,
                                           ACCELERATION_STD, MAX_SPEED)
    np.testing.assert_allclose(predicted, truth(target_times[:, None])[:, 0], rtol=0.0, atol=1.0)


def test_linear_extrapolation_is_exact_for_constant_velocity(radar):
    """The last two plots, even after a missed scan, extrapolate a straight track exactly."""
    times, positions, truth = straight_tracks(radar, count=20, steps=4, seed=5)
    times[:, -1] += SCAN_S  # a missed scan before the last plot
    positions = truth(times)
    target_times = times[:, -1] + np.linspace(1.0, 30.0, 20)
    np.testing.assert_allclose(baselines.linear_extrapolation(times, positions, target_times),
                               truth(target_times[:, None])[:, 0], rtol=0.0, atol=1e-6)

"""The posterior Cramér-Rao bound (`pipeline.surveillance.pcrb`) against Stone Soup's `PCRBMetric`, and the
bound's behaviour where its answer is known."""

from __future__ import annotations

from datetime import datetime, timedelta

import numpy as np
import pytest

from pipeline.filters import motion_models
from pipeline.surveillance import pcrb

SCAN_S = 6.0
PLOT_COVARIANCE = np.array([[200.0 ** 2, 3e3, 0.0], [3e3, 120.0 ** 2, 0.0], [0.0, 0.0, 40.0 ** 2]])


def stone_soup_bound(times: np.ndarray, noise_std: float, velocity_std: float, detection: float) -> np.ndarray:
    """Stone Soup's PCRB position RMSE of a CV target with our CV model's F and Q (discrete white-noise
    acceleration, `motion_models`), the plot covariance above, and the information reduction factor `detection`."""
    from stonesoup.metricgenerator.pcrbmetric import PCRBMetric
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import LinearGaussianTimeInvariantTransitionModel
    from stonesoup.types.array import StateVector, StateVectors
    from stonesoup.types.groundtruth import GroundTruthPath, GroundTruthState
    from stonesoup.types.state import GaussianState

    transition = LinearGaussianTimeInvariantTransitionModel(
        transition_matrix=motion_models.transition("cv", SCAN_S),
        covariance_matrix=motion_models.process_noise("cv", SCAN_S, noise_std))
    measurement = LinearGaussian(ndim_state=6, mapping=(0, 2, 4), noise_covar=PLOT_COVARIANCE)
    _, start = motion_models.initial_state("cv", np.zeros(3), PLOT_COVARIANCE, velocity_std, 0.0)
    epoch = datetime(2026, 6, 1)
    truth = GroundTruthPath([GroundTruthState(StateVector([200.0 * t, 200.0, 0.0, 0.0, 9000.0, 0.0]),
                                              timestamp=epoch + timedelta(seconds=float(t))) for t in times])
    metric = PCRBMetric(prior=GaussianState(StateVector(np.zeros(6)), start, timestamp=epoch),
                        transition_model=transition, measurement_model=measurement,
                        sensor_locations=StateVectors(np.zeros((3, 1))), irf=detection)
    return metric._compute_pcrb_single(metric.prior, transition, measurement, truth, metric.sensor_locations,
                                       detection, [0, 2, 4], None)["position_RMSE"]


@pytest.mark.parametrize("detection", [1.0, 0.7])
def test_the_bound_is_stone_soups_on_the_same_model_and_plots(detection: float) -> None:
    times = SCAN_S * np.arange(40)
    count = len(times)
    bounds = pcrb.information_recursion(times, np.broadcast_to(PLOT_COVARIANCE, (count, 3, 3)),
                                        np.full(count, detection), "cv", 3.0, 150.0, 0.0)
    np.testing.assert_allclose(pcrb.position_bounds(bounds, "cv"), stone_soup_bound(times, 3.0, 150.0, detection),
                               rtol=1e-9)


def test_the_bound_falls_from_the_plot_error_and_settles_higher_with_fewer_detections() -> None:
    times = SCAN_S * np.arange(60)
    count = len(times)
    covariance = np.broadcast_to(PLOT_COVARIANCE, (count, 3, 3))
    always = pcrb.position_bounds(pcrb.information_recursion(times, covariance, np.ones(count), "ca", 1.0, 150.0, 10.0),
                                  "ca")
    half = pcrb.position_bounds(pcrb.information_recursion(times, covariance, np.full(count, 0.5), "ca", 1.0, 150.0,
                                                           10.0), "ca")
    assert always[0] == pytest.approx(np.sqrt(np.trace(PLOT_COVARIANCE)))  # the first plot alone
    assert always[-1] < 0.9 * always[0] and np.all(np.diff(always[5:]) <= 1e-9)  # to its steady state from above
    assert np.all(half[1:] > always[1:])
    horizontal = pcrb.position_bounds(pcrb.information_recursion(times, covariance, np.ones(count), "cv", 1.0, 150.0,
                                                                 0.0), "cv", np.broadcast_to(np.eye(3), (count, 3, 3)))
    assert horizontal[0] == pytest.approx(np.sqrt(200.0 ** 2 + 120.0 ** 2))  # east and north: x and y here


def test_times_not_increasing_and_factors_outside_0_1_are_refused() -> None:
    covariance = np.broadcast_to(PLOT_COVARIANCE, (3, 3, 3))
    with pytest.raises(ValueError, match="must increase"):
        pcrb.information_recursion(np.array([0.0, 6.0, 6.0]), covariance, np.ones(3), "cv", 1.0, 100.0, 0.0)
    with pytest.raises(ValueError, match="outside"):
        pcrb.information_recursion(np.array([0.0, 6.0, 12.0]), covariance, np.array([1.0, 1.2, 1.0]), "cv", 1.0,
                                   100.0, 0.0)


def test_the_benchs_bound_pools_every_in_coverage_scan_of_every_target_and_item() -> None:
    """`horizontal_rms`, the figure beside a scorecard's position RMS: the RMS of `route_bounds` over the
    in-coverage scans of each target of each material item; a target never in coverage adds nothing, and a
    material without one gives NaN."""
    from pipeline.filters.classical_filters import FilterSettings
    from pipeline.geometry import geodesy
    from pipeline.surveillance.scorecard import Truth
    from tests import tracker_fixtures as tf

    params = tf.make_params()
    settings = FilterSettings("cv", (3.0,), 150.0, 0.0, 0.0, 1.0)
    site = geodesy.radar_site_ecef(params.radar)
    times = SCAN_S * np.arange(12)
    first = site + np.array([30e3, 0.0, 0.0]) + np.outer(times, [0.0, 150.0, 0.0])
    second = site + np.array([0.0, 50e3, 0.0]) + np.outer(times, [150.0, 0.0, 0.0])
    truth = Truth(np.repeat([1, 2, 3], 12), np.tile(times, 3), np.concatenate([first, second, second]),
                  np.concatenate([np.ones(24, bool), np.zeros(12, bool)]))
    detection = np.full(36, 0.9)
    alone = [pcrb.route_bounds(times, path, detection[:12], params.radar, settings)[1] for path in (first, second)]
    expected = np.sqrt(np.mean(np.concatenate(alone) ** 2))
    assert pcrb.horizontal_rms([(truth, detection, params.radar)], settings) == pytest.approx(expected, rel=1e-12)
    assert pcrb.horizontal_rms([(truth, detection, params.radar)] * 2, settings) == pytest.approx(expected, rel=1e-12)
    nowhere = Truth(truth.target_id, truth.time_s, truth.position, np.zeros(36, bool))
    assert np.isnan(pcrb.horizontal_rms([(nowhere, detection, params.radar)], settings))

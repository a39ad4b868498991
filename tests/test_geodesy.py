"""Coordinates: the thesis's plot-to-ECEF conversion (eqs 4.1-4.6) against pymap3d's exact ones."""

from __future__ import annotations

import dataclasses

import numpy as np
import pymap3d
import pymap3d.rcurve
import pytest

from pipeline.geometry import geodesy

WGS84 = pymap3d.Ellipsoid.from_name("wgs84")

# Radars in both hemispheres and on both sides of Greenwich, plus the equator/meridian and near the pole.
SITES = [(60.3, 24.9), (-33.9, 151.2), (40.6, -73.8), (-22.9, -43.2), (0.0, 0.0), (89.0, 179.0)]


@pytest.fixture(scope="module")
def default_radar(make_params):
    return make_params().radar


def radar_at(radar, latitude_deg, longitude_deg):
    return dataclasses.replace(radar, latitude_deg=latitude_deg, longitude_deg=longitude_deg)


@pytest.mark.parametrize("height_m", [0.0, 60.0, 2500.0])
@pytest.mark.parametrize("latitude_deg, longitude_deg", SITES)
def test_site_ecef_matches_pymap3d(latitude_deg, longitude_deg, height_m):
    """Eq 4.4 puts the radar where pymap3d.geodetic2ecef does, to a micrometre."""
    expected = pymap3d.geodetic2ecef(latitude_deg, longitude_deg, height_m, ell=WGS84)
    np.testing.assert_allclose(geodesy.site_ecef(latitude_deg, longitude_deg, height_m), expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize("latitude_deg", [-89.0, -60.0, -33.9, 0.0, 22.5, 60.3, 90.0])
def test_meridian_radius_is_the_ellipsoid_meridional_curvature(latitude_deg):
    """Eq 4.1 gives the WGS-84 meridian radius of curvature (pymap3d.rcurve.meridian)."""
    assert geodesy.meridian_radius(latitude_deg) == pytest.approx(pymap3d.rcurve.meridian(latitude_deg, WGS84),
                                                                  rel=1e-12)


@pytest.mark.parametrize("latitude_deg, longitude_deg", SITES)
def test_enu_rotation_rows_are_east_north_up(latitude_deg, longitude_deg):
    """Eq 4.6: local ENU @ S + T is pymap3d.enu2ecef, and S is orthonormal."""
    height_m = 60.0
    local = np.array([[1000.0, 0.0, 0.0], [0.0, 1000.0, 0.0], [0.0, 0.0, 1000.0],
                      [-250e3, 310e3, 12e3], [399e3, -2e3, -5e3]])
    rotation = geodesy.enu_rotation(latitude_deg, longitude_deg)
    ecef = local @ rotation + geodesy.site_ecef(latitude_deg, longitude_deg, height_m)
    expected = np.stack(pymap3d.enu2ecef(local[:, 0], local[:, 1], local[:, 2], latitude_deg, longitude_deg,
                                         height_m, ell=WGS84), axis=-1)
    np.testing.assert_allclose(ecef, expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)


def _ground_grid(max_distance_m: float):
    """Targets every 15 deg of azimuth, at 1, 6 and 12 km altitude, out to `max_distance_m` on the tangent plane."""
    azimuth, altitude, distance = np.meshgrid(np.radians(np.arange(0.0, 360.0, 15.0)), [1000.0, 6000.0, 12000.0],
                                              np.arange(5000.0, max_distance_m + 1.0, 5000.0), indexing="ij")
    return (distance * np.sin(azimuth)).ravel(), (distance * np.cos(azimuth)).ravel(), altitude.ravel()


def _conversion_error(radar, max_distance_m):
    """Slant range and distance between the true position and plot_to_ecef of its exact measurement."""
    east, north, altitude = _ground_grid(max_distance_m)
    truth = geodesy.geodetic_to_ecef(*geodesy.local_to_geodetic(east, north, altitude, radar))
    slant_range, azimuth, measured_altitude = geodesy.true_measurement(truth, radar)
    converted = geodesy.plot_to_ecef(slant_range, azimuth, measured_altitude, radar)
    return slant_range, np.linalg.norm(converted - truth, axis=1)


@pytest.mark.parametrize("latitude_deg, longitude_deg", SITES + [(-35.0, 20.0), (-60.0, -70.0)])
def test_plot_to_ecef_error_is_bounded_by_range_squared(default_radar, latitude_deg, longitude_deg):
    """Eqs 4.1-4.6 on an exact measurement miss the truth by at most 6e-4 m/km^2 * range^2 + 0.5 m (eq 4.2)."""
    slant_range, error = _conversion_error(radar_at(default_radar, latitude_deg, longitude_deg), 400e3)
    assert slant_range.max() > 395e3  # the grid reaches the edge of coverage
    bound = 6e-4 * (slant_range / 1000.0) ** 2 + 0.5
    worst = np.argmax(error / bound)
    assert np.all(error <= bound), f"{error[worst]:.2f} m at {slant_range[worst] / 1000:.0f} km"


@pytest.mark.parametrize("latitude_deg, longitude_deg", SITES)
def test_plot_to_ecef_is_accurate_at_short_range(default_radar, latitude_deg, longitude_deg):
    """Within 50 km the thesis's conversion recovers the true position to under 1.5 m."""
    slant_range, error = _conversion_error(radar_at(default_radar, latitude_deg, longitude_deg), 45e3)
    assert error[slant_range <= 50e3].max() < 1.5


def test_plot_at_azimuth_zero_lies_due_north(default_radar):
    """A plot at azimuth 0 lies on the radar's north axis: east component zero, north positive."""
    ecef = geodesy.plot_to_ecef(np.array([100e3]), np.array([0.0]), np.array([9000.0]), default_radar)
    local = (ecef - geodesy.radar_site_ecef(default_radar)) @ geodesy.enu_rotation(
        default_radar.latitude_deg, default_radar.longitude_deg).T
    assert abs(local[0, 0]) < 1e-6
    assert 99e3 < local[0, 1] < 100e3
    np.testing.assert_allclose(np.linalg.norm(local[0]), 100e3, rtol=1e-12)


def test_below_horizon_on_a_four_thirds_earth(default_radar):
    """At 300 km a target at 10 km altitude is above the horizon, one at 100 m is below it."""
    assert default_radar.height_m == 60.0 and default_radar.effective_earth_radius_factor == pytest.approx(4 / 3)
    hidden = geodesy.below_horizon(np.array([300e3, 300e3]), np.array([10000.0, 100.0]), default_radar)
    assert hidden.tolist() == [False, True]


@pytest.mark.parametrize("target_altitude_m", [100.0, 1000.0, 10000.0])
def test_horizon_distance_is_the_four_thirds_earth_rule(default_radar, target_altitude_m):
    """The radar horizon is the textbook 4/3-earth distance 4.12 km * (sqrt(h_radar) + sqrt(h_target)), to 1 %."""
    horizon_m = 4121.0 * (np.sqrt(default_radar.height_m) + np.sqrt(target_altitude_m))
    hidden = geodesy.below_horizon(np.array([0.99, 1.01]) * horizon_m, np.full(2, target_altitude_m), default_radar)
    assert hidden.tolist() == [False, True]

"""Coordinates: the thesis's plot-to-ECEF conversion (eqs 4.1-4.6) and the exact ones.

The thesis converts a plot (slant range, azimuth, measured altitude) to ECEF with a
spherical-earth elevation (eq. 4.2) that uses the meridian radius at the radar for the
whole coverage. That is kept exactly as written, because the networks are meant to learn
its residual error; the exact conversions of pymap3d are used for the truth (routes and
true measurements) so that the approximation's error is visible and bounded
(see tests/test_geodesy.py and docs/data.md).

Every function here computes with `pipeline.geometry.strict_math` (fdlibm's sin, cos, atan, atan2, asin in
IEEE arithmetic) instead of NumPy's or pymap3d's, so that the data stages write the same bytes on
any processor (issue 27): NumPy's transcendental kernels and glibc's differ in the last bit by
processor, and a route's truth passes through these conversions. The exact conversions are
pymap3d's formulas (geodetic2ecef, ecef2geodetic after You (2000), enu2ecef, ecef2enu, enu2aer),
written out with those functions; they agree with pymap3d to a few ulps.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pymap3d

from pipeline.geometry import strict_math as sm
from pipeline.params import Radar

WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3  # first eccentricity squared
WGS84_ELLIPSOID = pymap3d.Ellipsoid.from_name("wgs84")  # the exact conversions' ellipsoid (and the figures')
SEMIMAJOR_M, SEMIMINOR_M = WGS84_ELLIPSOID.semimajor_axis, WGS84_ELLIPSOID.semiminor_axis
LINEAR_ECCENTRICITY_M = float(np.sqrt(SEMIMAJOR_M * SEMIMAJOR_M - SEMIMINOR_M * SEMIMINOR_M))


def meridian_radius(latitude_deg: float) -> float:
    """Eq. 4.1: earth radius (meridional curvature) at the radar's latitude."""
    s = float(sm.sin(np.radians(latitude_deg)))
    q = 1.0 - WGS84_E2 * s * s
    return WGS84_A * (1.0 - WGS84_E2) / (q * np.sqrt(q))


def site_ecef(latitude_deg: float, longitude_deg: float, height_m: float) -> np.ndarray:
    """Eq. 4.4: ECEF position of a site given geodetically (the radar, T)."""
    (sin_lat, cos_lat), (sin_lon, cos_lon) = sm.sin_cos(np.radians(latitude_deg)), sm.sin_cos(np.radians(longitude_deg))
    mu = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
    return np.array([
        (mu + height_m) * cos_lat * cos_lon,
        (mu + height_m) * cos_lat * sin_lon,
        (mu * (1.0 - WGS84_E2) + height_m) * sin_lat,
    ])


def enu_rotation(latitude_deg: float, longitude_deg: float) -> np.ndarray:
    """Eq. 4.6: S1, whose rows are the east, north and up unit vectors in ECEF."""
    return enu_rotations(np.array([latitude_deg]), np.array([longitude_deg]))[0]


def enu_rotations(latitude_deg: np.ndarray, longitude_deg: np.ndarray) -> np.ndarray:
    """S1 of eq. 4.6 for many sites at once (N x 3 x 3): ECEF offsets -> east, north, up."""
    lat = np.radians(np.asarray(latitude_deg, dtype=float))
    (sin_lat, cos_lat), (sin_lon, cos_lon) = sm.sin_cos(lat), sm.sin_cos(np.radians(longitude_deg))
    return np.stack([
        np.stack([-sin_lon, cos_lon, np.zeros_like(lat)], axis=-1),
        np.stack([-sin_lat * cos_lon, -sin_lat * sin_lon, cos_lat], axis=-1),
        np.stack([cos_lat * cos_lon, cos_lat * sin_lon, sin_lat], axis=-1),
    ], axis=-2)


def radial_rotations(points_ecef: np.ndarray, radar_ecef: np.ndarray) -> np.ndarray:
    """Per point (N x 3 x 3): ECEF offsets -> (cross-range, down-range, up) axes at the point.

    Up is the normal of the ellipsoid through the point, (x / a^2, y / a^2, z / b^2) normalised
    (the ellipsoid's gradient there; within 1e-5 rad of the geodetic vertical below 15 km, and
    in closed form: the tracker computes it for every network window); down-range the horizontal
    part of the line of sight from the radar (`radar_ecef`, (3,) or (N, 3)); cross-range =
    down-range x up, so with down-range north it is east, as in ENU. Unlike ENU, the axes depend
    only on where the point is relative to the radar, not on where north is: the same
    radar-relative geometry gives the same axes at any site, whereas ENU turns with the meridian
    convergence (north 200 km east of a radar at 60 degrees latitude is 3 degrees from the
    radar's). Directly above the radar, where down-range is undefined, it is north.
    """
    points = np.asarray(points_ecef, dtype=float)
    up = points / np.array([1.0, 1.0, 1.0 - WGS84_E2])
    up /= sm.norm(up, axis=1, keepdims=True)
    line = points - np.asarray(radar_ecef, dtype=float)
    horizontal = line - (line * up).sum(axis=1, keepdims=True) * up
    length = sm.norm(horizontal, axis=1, keepdims=True)
    overhead = length[:, 0] <= 1.0
    if overhead.any():
        east = np.column_stack([-up[overhead, 1], up[overhead, 0], np.zeros(overhead.sum())])
        east /= sm.norm(east, axis=1, keepdims=True)
        horizontal[overhead], length[overhead] = _cross(up[overhead], east), 1.0
    down = horizontal / length
    return np.stack([_cross(down, up), down, up], axis=1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays, written out: np.cross costs more than the arithmetic here."""
    return np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])


def thesis_elevation(slant_range_m: np.ndarray, altitude_m: np.ndarray, radar_height_m: float,
                     earth_radius_m: float) -> np.ndarray:
    """Eq. 4.2: elevation angle (rad), assuming the radar's earth radius also at the target."""
    sin_psi = (2.0 * earth_radius_m * (altitude_m - radar_height_m) + altitude_m ** 2
               - radar_height_m * radar_height_m - slant_range_m ** 2) / (
        2.0 * slant_range_m * (earth_radius_m + radar_height_m))
    return sm.asin(np.clip(sin_psi, -1.0, 1.0))


def plot_to_ecef(slant_range_m: np.ndarray, azimuth_deg: np.ndarray, altitude_m: np.ndarray,
                 radar: Radar) -> np.ndarray:
    """Eqs. 4.1-4.6: a radar plot to ECEF (N x 3), exactly as the thesis does it."""
    slant_range_m = np.asarray(slant_range_m, dtype=float)
    psi = thesis_elevation(slant_range_m, np.asarray(altitude_m, dtype=float), radar.height_m,
                           meridian_radius(radar.latitude_deg))
    (sin_psi, cos_psi), (sin_theta, cos_theta) = sm.sin_cos(psi), sm.sin_cos(np.radians(azimuth_deg))
    east, north, up = slant_range_m * cos_psi * sin_theta, slant_range_m * cos_psi * cos_theta, slant_range_m * sin_psi
    rotation = enu_rotation(radar.latitude_deg, radar.longitude_deg)
    # local @ rotation written out: BLAS's kernel, and so its rounding, depends on the processor
    ecef = east[..., None] * rotation[0] + north[..., None] * rotation[1] + up[..., None] * rotation[2]
    return ecef + radar_site_ecef(radar)


def radar_site_ecef(radar: Radar) -> np.ndarray:
    return site_ecef(radar.latitude_deg, radar.longitude_deg, radar.height_m)


def local_to_geodetic(east_m: np.ndarray, north_m: np.ndarray, altitude_m: np.ndarray,
                      radar: Radar) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map route coordinates (east, north on the radar's tangent plane; altitude) to the earth.

    Routes are planned on the tangent plane so that the coverage box and turns are
    simple; each planar point is dropped along the ellipsoid normal to its geodetic
    latitude/longitude and then flown at the planned altitude above the ellipsoid. The
    mapping is smooth and distorts horizontal distances by under 0.3 % inside 400 km.
    """
    east_m, north_m = np.asarray(east_m, dtype=float), np.asarray(north_m, dtype=float)
    sin_lat, cos_lat, sin_lon, cos_lon, site = _site_frame(radar.latitude_deg, radar.longitude_deg, radar.height_m)
    # pymap3d.enu2uvw with up = 0, then enu2ecef: the plane point in ECEF
    t, w = -sin_lat * north_m, cos_lat * north_m
    offset = np.stack([cos_lon * t - sin_lon * east_m, sin_lon * t + cos_lon * east_m, w], axis=-1)
    lat, lon, _ = ecef_to_geodetic(offset + site)
    return lat, lon, np.asarray(altitude_m, dtype=float)


@lru_cache(maxsize=64)
def _site_frame(latitude_deg: float, longitude_deg: float, height_m: float
                ) -> tuple[float, float, float, float, np.ndarray]:
    """sin and cos of a site's latitude and longitude, and its ECEF position (3,) m by the exact
    conversion (`geodetic_to_ecef`): computed once per site, not at every call."""
    (sin_lat, cos_lat), (sin_lon, cos_lon) = sm.sin_cos(np.radians(latitude_deg)), sm.sin_cos(np.radians(longitude_deg))
    site = geodetic_to_ecef(np.array([latitude_deg]), np.array([longitude_deg]), np.array([height_m]))[0]
    site.flags.writeable = False
    return float(sin_lat), float(cos_lat), float(sin_lon), float(cos_lon), site


def geodetic_to_ecef(latitude_deg: np.ndarray, longitude_deg: np.ndarray, altitude_m: np.ndarray) -> np.ndarray:
    """ECEF (..., 3) m of geodetic points (deg, deg, m above WGS-84); pymap3d.geodetic2ecef's formula."""
    (sin_lat, cos_lat), (sin_lon, cos_lon) = (sm.sin_cos(np.radians(np.asarray(latitude_deg, dtype=float))),
                                              sm.sin_cos(np.radians(np.asarray(longitude_deg, dtype=float))))
    altitude_m = np.asarray(altitude_m, dtype=float)
    prime_vertical = SEMIMAJOR_M * SEMIMAJOR_M / sm.hypot(SEMIMAJOR_M * cos_lat, SEMIMINOR_M * sin_lat)
    ratio = SEMIMINOR_M / SEMIMAJOR_M
    return np.stack([(prime_vertical + altitude_m) * cos_lat * cos_lon,
                     (prime_vertical + altitude_m) * cos_lat * sin_lon,
                     (prime_vertical * (ratio * ratio) + altitude_m) * sin_lat], axis=-1)


def ecef_to_geodetic(ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latitude, longitude (deg) and height (m above WGS-84) of ECEF points (..., 3), without
    iterations: You, R.-J. (2000), Transformation of Cartesian to geodetic coordinates without
    iterations, J. Surveying Engineering 126(1), eqs 4a-4c, 7 and 13, as pymap3d.ecef2geodetic
    writes them (on the polar axis the reduced latitude is +-90 deg, and 0 at the centre)."""
    x, y, z = (np.asarray(ecef[..., axis], dtype=float) for axis in range(3))
    a, b, e = SEMIMAJOR_M, SEMIMINOR_M, LINEAR_ECCENTRICITY_M
    r2 = x * x + y * y + z * z
    u = np.sqrt(0.5 * (r2 - e * e) + 0.5 * sm.hypot(r2 - e * e, 2.0 * e * z))  # eq. 4a
    horizontal = sm.hypot(x, y)
    hu_e = sm.hypot(u, e)
    axis = (np.abs(u) <= 1e-8) | (np.abs(horizontal) <= 1e-8)  # pymap3d's isclose(., 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        beta = sm.atan(np.where(axis, 0.0, hu_e / u * z / horizontal))  # eq. 4b
        sin_beta, cos_beta = sm.sin_cos(beta)
        beta = beta + (b * u - a * hu_e + e * e) * sin_beta / (a * hu_e / cos_beta - e * e * cos_beta)  # eq. 13
    beta = np.where(axis, np.where(np.abs(z) <= 1e-8, 0.0, np.copysign(np.pi / 2.0, z)), beta)
    sin_beta, cos_beta = sm.sin_cos(beta)
    pole = np.abs(beta) >= np.pi / 2.0 - np.finfo(float).eps
    with np.errstate(divide="ignore"):
        lat = np.where(pole, np.copysign(np.pi / 2.0, beta), sm.atan(a / b * (sin_beta / cos_beta)))  # eq. 4c
    cos_beta = np.where(pole, 0.0, cos_beta)
    height = sm.hypot(z - b * sin_beta, horizontal - a * cos_beta)  # eq. 7
    inside = x * x / (a * a) + y * y / (a * a) + z * z / (b * b) < 1.0
    return np.degrees(lat), np.degrees(sm.atan2(y, x)), np.where(inside, -height, height)[()]


def _aer(ecef: np.ndarray, radar: Radar) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuth from north (rad, [0, 2 pi)), elevation (rad) and slant range (m) of ECEF points
    (..., 3) from the radar: pymap3d.ecef2aer (ecef2enu, then enu2aer, which sets ENU components
    under 1 mm to 0 for stability overhead)."""
    sin_lat, cos_lat, sin_lon, cos_lon, site = _site_frame(radar.latitude_deg, radar.longitude_deg, radar.height_m)
    offset = np.asarray(ecef, dtype=float) - site
    u, v, w = offset[..., 0], offset[..., 1], offset[..., 2]
    t = cos_lon * u + sin_lon * v
    east, north, up = (np.where(np.abs(c) < 1e-3, 0.0, c) for c in
                       (-sin_lon * u + cos_lon * v, -sin_lat * t + cos_lat * w, cos_lat * t + sin_lat * w))
    ground = sm.hypot(east, north)
    return np.mod(sm.atan2(east, north), 2.0 * np.pi), sm.atan2(up, ground), sm.hypot(ground, up)


def true_measurement(ecef: np.ndarray, radar: Radar) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact slant range (m), azimuth from north (deg, [0, 360)) and altitude (m) of ECEF points."""
    azimuth, _, slant_range = _aer(ecef, radar)
    _, _, altitude = ecef_to_geodetic(ecef)
    return slant_range, np.mod(np.degrees(azimuth), 360.0), altitude


def azimuth_deg(ecef: np.ndarray, radar: Radar) -> np.ndarray:
    """Exact azimuth from north (deg, [0, 360)) of ECEF points: `true_measurement`'s, without the
    altitude's cost."""
    return np.mod(np.degrees(_aer(ecef, radar)[0]), 360.0)


def elevation_deg(ecef: np.ndarray, radar: Radar) -> np.ndarray:
    """Exact elevation of ECEF points above the radar's local horizontal plane."""
    return np.degrees(_aer(ecef, radar)[1])


def below_horizon(slant_range_m: np.ndarray, altitude_m: np.ndarray, radar: Radar) -> np.ndarray:
    """True where the line of sight is blocked by the earth (effective radius k*R for refraction).

    A target is visible while the slant range is at most the sum of the tangent lengths
    from radar and target to a sphere of the effective radius.
    """
    radius = radar.effective_earth_radius_factor * meridian_radius(radar.latitude_deg)
    radar_tangent = np.sqrt(max((radius + radar.height_m) * (radius + radar.height_m) - radius * radius, 0.0))
    target_tangent = np.sqrt(np.maximum((radius + np.asarray(altitude_m)) ** 2 - radius * radius, 0.0))
    return np.asarray(slant_range_m) > radar_tangent + target_tangent


def measurement_covariance(ecef: np.ndarray, radar: Radar) -> np.ndarray:
    """Converted-measurement covariance (N x 3 x 3, ECEF, m^2) of plots at the given ECEF positions (N x 3, m):
    the range error along the line of sight, the azimuth error across it (range * sigma_azimuth) and the
    altitude error vertically, in the radar's ENU axes rotated into ECEF (thesis section 4.2)."""
    rotation = enu_rotation(radar.latitude_deg, radar.longitude_deg)
    local = (ecef - radar_site_ecef(radar)) @ rotation.T
    horizontal = np.linalg.norm(local[:, :2], axis=1)
    radial = np.zeros_like(local)
    radial[:, 0] = np.divide(local[:, 0], horizontal, out=np.ones_like(horizontal), where=horizontal > 0)
    radial[:, 1] = np.divide(local[:, 1], horizontal, out=np.zeros_like(horizontal), where=horizontal > 0)
    cross = np.stack([-radial[:, 1], radial[:, 0], np.zeros(len(local))], axis=1)
    up = np.tile([0.0, 0.0, 1.0], (len(local), 1))
    axes = np.stack([radial, cross, up], axis=2)  # columns: radial, cross-range, up (ENU)
    slant = np.linalg.norm(local, axis=1)
    variances = np.stack([np.full(len(local), radar.sigma_range_m ** 2),
                          (slant * np.radians(radar.sigma_azimuth_deg)) ** 2,
                          np.full(len(local), radar.sigma_altitude_m ** 2)], axis=1)
    enu = np.einsum("nij,nj,nkj->nik", axes, variances, axes)
    return np.einsum("ji,njk,kl->nil", rotation, enu, rotation)

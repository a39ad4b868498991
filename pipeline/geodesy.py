"""Coordinates: the thesis's plot-to-ECEF conversion (eqs 4.1-4.6) and the exact ones.

The thesis converts a plot (slant range, azimuth, measured altitude) to ECEF with a
spherical-earth elevation (eq. 4.2) that uses the meridian radius at the radar for the
whole coverage. That is kept exactly as written, because the networks are meant to learn
its residual error; the exact conversions of pymap3d are used for the truth (routes and
true measurements) so that the approximation's error is visible and bounded
(see tests/test_geodesy.py and the README).
"""

from __future__ import annotations

import numpy as np
import pymap3d

from pipeline.params import Radar

WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3  # first eccentricity squared
WGS84_ELLIPSOID = pymap3d.Ellipsoid.from_name("wgs84")


def meridian_radius(latitude_deg: float) -> float:
    """Eq. 4.1: earth radius (meridional curvature) at the radar's latitude."""
    s = np.sin(np.radians(latitude_deg))
    return WGS84_A * (1.0 - WGS84_E2) / (1.0 - WGS84_E2 * s * s) ** 1.5


def site_ecef(latitude_deg: float, longitude_deg: float, height_m: float) -> np.ndarray:
    """Eq. 4.4: ECEF position of a site given geodetically (the radar, T)."""
    lat, lon = np.radians(latitude_deg), np.radians(longitude_deg)
    mu = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.array([
        (mu + height_m) * np.cos(lat) * np.cos(lon),
        (mu + height_m) * np.cos(lat) * np.sin(lon),
        (mu * (1.0 - WGS84_E2) + height_m) * np.sin(lat),
    ])


def enu_rotation(latitude_deg: float, longitude_deg: float) -> np.ndarray:
    """Eq. 4.6: S1, whose rows are the east, north and up unit vectors in ECEF."""
    return enu_rotations(np.array([latitude_deg]), np.array([longitude_deg]))[0]


def enu_rotations(latitude_deg: np.ndarray, longitude_deg: np.ndarray) -> np.ndarray:
    """S1 of eq. 4.6 for many sites at once (N x 3 x 3): ECEF offsets -> east, north, up."""
    lat, lon = np.radians(latitude_deg), np.radians(longitude_deg)
    sin_lat, cos_lat, sin_lon, cos_lon = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
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
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    line = points - np.asarray(radar_ecef, dtype=float)
    horizontal = line - (line * up).sum(axis=1, keepdims=True) * up
    length = np.linalg.norm(horizontal, axis=1, keepdims=True)
    overhead = length[:, 0] <= 1.0
    if overhead.any():
        east = np.column_stack([-up[overhead, 1], up[overhead, 0], np.zeros(overhead.sum())])
        east /= np.linalg.norm(east, axis=1, keepdims=True)
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
               - radar_height_m ** 2 - slant_range_m ** 2) / (2.0 * slant_range_m * (earth_radius_m + radar_height_m))
    return np.arcsin(np.clip(sin_psi, -1.0, 1.0))


def plot_to_ecef(slant_range_m: np.ndarray, azimuth_deg: np.ndarray, altitude_m: np.ndarray,
                 radar: Radar) -> np.ndarray:
    """Eqs. 4.1-4.6: a radar plot to ECEF (N x 3), exactly as the thesis does it."""
    slant_range_m = np.asarray(slant_range_m, dtype=float)
    psi = thesis_elevation(slant_range_m, np.asarray(altitude_m, dtype=float), radar.height_m,
                           meridian_radius(radar.latitude_deg))
    theta = np.radians(azimuth_deg)
    local = np.stack([
        slant_range_m * np.cos(psi) * np.sin(theta),
        slant_range_m * np.cos(psi) * np.cos(theta),
        slant_range_m * np.sin(psi),
    ], axis=-1)
    rotation = enu_rotation(radar.latitude_deg, radar.longitude_deg)
    return local @ rotation + radar_site_ecef(radar)


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
    lat, lon, _ = pymap3d.enu2geodetic(east_m, north_m, np.zeros_like(east_m), radar.latitude_deg,
                                       radar.longitude_deg, radar.height_m, ell=WGS84_ELLIPSOID)
    return np.asarray(lat), np.asarray(lon), np.asarray(altitude_m, dtype=float)


def geodetic_to_ecef(latitude_deg: np.ndarray, longitude_deg: np.ndarray, altitude_m: np.ndarray) -> np.ndarray:
    x, y, z = pymap3d.geodetic2ecef(latitude_deg, longitude_deg, altitude_m, ell=WGS84_ELLIPSOID)
    return np.stack([x, y, z], axis=-1)


def ecef_to_geodetic(ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lat, lon, alt = pymap3d.ecef2geodetic(ecef[..., 0], ecef[..., 1], ecef[..., 2], ell=WGS84_ELLIPSOID)
    return np.asarray(lat), np.asarray(lon), np.asarray(alt)


def true_measurement(ecef: np.ndarray, radar: Radar) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact slant range (m), azimuth from north (deg, [0, 360)) and altitude (m) of ECEF points."""
    azimuth, _, slant_range = pymap3d.ecef2aer(ecef[..., 0], ecef[..., 1], ecef[..., 2], radar.latitude_deg,
                                               radar.longitude_deg, radar.height_m, ell=WGS84_ELLIPSOID)
    _, _, altitude = ecef_to_geodetic(ecef)
    return np.asarray(slant_range), np.mod(np.asarray(azimuth), 360.0), altitude


def elevation_deg(ecef: np.ndarray, radar: Radar) -> np.ndarray:
    """Exact elevation of ECEF points above the radar's local horizontal plane."""
    _, elevation, _ = pymap3d.ecef2aer(ecef[..., 0], ecef[..., 1], ecef[..., 2], radar.latitude_deg,
                                       radar.longitude_deg, radar.height_m, ell=WGS84_ELLIPSOID)
    return np.asarray(elevation)


def below_horizon(slant_range_m: np.ndarray, altitude_m: np.ndarray, radar: Radar) -> np.ndarray:
    """True where the line of sight is blocked by the earth (effective radius k*R for refraction).

    A target is visible while the slant range is at most the sum of the tangent lengths
    from radar and target to a sphere of the effective radius.
    """
    radius = radar.effective_earth_radius_factor * meridian_radius(radar.latitude_deg)
    radar_tangent = np.sqrt(np.maximum((radius + radar.height_m) ** 2 - radius ** 2, 0.0))
    target_tangent = np.sqrt(np.maximum((radius + np.asarray(altitude_m)) ** 2 - radius ** 2, 0.0))
    return np.asarray(slant_range_m) > radar_tangent + target_tangent

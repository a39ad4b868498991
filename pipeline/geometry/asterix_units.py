"""ASTERIX CAT048 resolutions and the time-of-day clock.

A CAT048 plot carries slant range in 1/256 NM (I048/040), azimuth in 360/2^16 degrees
(I048/040), Mode C altitude in 1/4 flight level (I048/090) and time of day in 1/128 s
since midnight UTC (I048/140). Simulated plots are quantised to exactly these steps so
that what the tracker sees is what a real radar would send.

Only division, rounding to nearest even, multiplication and floor are used: IEEE 754 rounds each
correctly, so the quantised values are the same on every processor (issue 27; the elementary
functions upstream are `pipeline.geometry.strict_math`'s for the same reason).
"""

from __future__ import annotations

import numpy as np

NAUTICAL_MILE_M = 1852.0
FOOT_M = 0.3048
SECONDS_PER_DAY = 86400.0

RANGE_STEP_M = NAUTICAL_MILE_M / 256.0
AZIMUTH_STEP_DEG = 360.0 / 2 ** 16
FLIGHT_LEVEL_STEP = 0.25
TIME_OF_DAY_STEP_S = 1.0 / 128.0


def quantise(value: np.ndarray, step: float) -> np.ndarray:
    return np.round(np.asarray(value, dtype=float) / step) * step


def quantise_range(range_m: np.ndarray) -> np.ndarray:
    return quantise(range_m, RANGE_STEP_M)


def quantise_azimuth(azimuth_deg: np.ndarray) -> np.ndarray:
    return np.mod(quantise(np.mod(azimuth_deg, 360.0), AZIMUTH_STEP_DEG), 360.0)


def altitude_to_flight_level(altitude_m: np.ndarray) -> np.ndarray:
    """Quantised flight level (hundreds of feet). The simulated aircraft report their
    geometric altitude as if it were pressure altitude (standard atmosphere)."""
    return quantise(np.asarray(altitude_m) / FOOT_M / 100.0, FLIGHT_LEVEL_STEP)


def flight_level_to_altitude(flight_level: np.ndarray) -> np.ndarray:
    return np.asarray(flight_level) * 100.0 * FOOT_M


def time_of_day(unix_s: np.ndarray) -> np.ndarray:
    """Seconds since midnight UTC in 1/128 s, wrapped into [0, 86400)."""
    return np.mod(quantise(np.mod(unix_s, SECONDS_PER_DAY), TIME_OF_DAY_STEP_S), SECONDS_PER_DAY)


def unix_from_time_of_day(time_of_day_s: np.ndarray, reference_unix_s: np.ndarray) -> np.ndarray:
    """Unix time of a time of day, taking the day that puts it nearest to a reference clock.

    A receiver knows the date and roughly the time (its own clock, or the last north
    marker); any reference within 12 h of the plot gives the right day, so tracks run
    through midnight instead of jumping back by a day.
    """
    reference = np.asarray(reference_unix_s, dtype=float)
    candidate = np.floor(reference / SECONDS_PER_DAY) * SECONDS_PER_DAY + np.asarray(time_of_day_s, dtype=float)
    offset = np.round((reference - candidate) / SECONDS_PER_DAY) * SECONDS_PER_DAY
    return candidate + offset


def unwrap_time_of_day(time_of_day_s: np.ndarray) -> np.ndarray:
    """Seconds since the midnight before the first time of day, each on the day nearest the one
    before it.

    A radar sends its plots in azimuth order, so plots of one scan interleave around midnight
    (86399.9, 0.05, 86399.97, 0.2): a backward jump of more than 12 h is the next day, a forward
    jump of more than 12 h a return to the day before, and no plot moves by a day.
    """
    return np.unwrap(np.asarray(time_of_day_s, dtype=float), period=SECONDS_PER_DAY)

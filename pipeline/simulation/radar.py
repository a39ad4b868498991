"""A rotating surveillance radar: beam timing, detection, measurement errors, false plots.

- The antenna turns clockwise from north at `rotation_rpm`; it points north at every
  whole multiple of the scan period in Unix time (scan k starts at k * period). A target is seen when the beam crosses
  its azimuth, so plot intervals vary with the target's own azimuth motion.
- Detection (single pulse, square-law detector, Swerling 1): the mean SNR follows the
  radar equation, SNR = SNR_ref * (rcs / rcs_ref) * (R_ref / R)^4, with an
  aspect-dependent mean RCS (nose/tail to broadside). The RCS fluctuates from scan to
  scan (exponential), and the threshold is set by the false-alarm probability, which
  gives Pd = Pfa^(1 / (1 + SNR)). Low mean SNR at long range or nose-on means a target
  fades for several scans. Targets outside [range_min, range_max], above the coverage
  ceiling, in the cone of silence above `max_elevation_deg` or below the (4/3 earth)
  radar horizon are not detected.
- Measurements: slant range, azimuth from north and altitude with Gaussian errors, then
  quantised to ASTERIX CAT048 resolutions.

Logarithms and powers (the SNR, Pd, the threshold) come from `pipeline.geometry.strict_math` and dot
products are written out, so that the truth files' bytes do not depend on the processor
(issue 27): NumPy's `log10` and `**` run processor-specific kernels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from pipeline.geometry import asterix_units, geodesy
from pipeline.geometry import strict_math as sm
from pipeline.params import Aircraft, Radar

BEAM_CROSSING_ITERATIONS = 8
BEAM_CROSSING_TOLERANCE_DEG = 1e-5
AZIMUTH_RATE_STEP_S = 0.01


@dataclass(frozen=True)
class Measurements:
    """Quantised radar measurements of a set of plots, with their ECEF positions (eqs 4.1-4.6)."""

    time_unix_s: np.ndarray
    time_of_day_s: np.ndarray
    range_m: np.ndarray
    azimuth_deg: np.ndarray
    flight_level: np.ndarray
    altitude_m: np.ndarray
    ecef: np.ndarray


def beam_azimuth_deg(time_unix_s: np.ndarray, radar: Radar) -> np.ndarray:
    """Where the antenna points at a time: 0 at each north crossing, clockwise."""
    return np.mod(np.asarray(time_unix_s) / radar.scan_period_s, 1.0) * 360.0


def scan_numbers(start_unix_s: float, end_unix_s: float, radar: Radar) -> np.ndarray:
    """Scans (north crossing k at k * scan period) that overlap [start, end]."""
    first = int(np.floor(start_unix_s / radar.scan_period_s))
    last = int(np.floor(end_unix_s / radar.scan_period_s))
    return np.arange(first, last + 1, dtype=np.int64)


def beam_crossings(trajectory: CubicHermiteSpline, radar: Radar) -> tuple[np.ndarray, np.ndarray]:
    """Times when the beam sweeps over a moving target, and the scan (north crossing) each follows.

    The lead of the beam over the target's unwrapped azimuth grows while the beam turns
    faster than the target moves in azimuth, which holds everywhere except within a few
    hundred metres of passing overhead. Each multiple of 360 deg of lead is one crossing,
    so a target on north gets exactly one plot a turn. Crossings are located on the 1 s
    truth and refined by Newton steps on the exact trajectory (slope: beam rate minus the
    target's azimuth rate). A crossing that does not converge (the target outruns the
    beam, overhead) is dropped: it lies in the cone of silence, where nothing is detected.
    """
    knots = trajectory.x
    origin, end = knots[0], knots[-1]
    rate = 360.0 / radar.scan_period_s
    phase = float(beam_azimuth_deg(origin, radar))
    azimuth = geodesy.azimuth_deg(trajectory(knots), radar)
    unwrapped = np.degrees(np.unwrap(np.radians(azimuth)))
    lead = phase + (knots - origin) * rate - unwrapped
    turns = np.arange(np.ceil(lead.min() / 360.0), np.floor(lead.max() / 360.0) + 1.0) * 360.0
    elapsed = np.interp(turns, np.maximum.accumulate(lead), knots - origin)

    def residual_and_slope(elapsed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = origin + elapsed
        exact = geodesy.azimuth_deg(trajectory(np.clip(t, origin, end)), radar)
        guess = np.interp(elapsed, knots - origin, unwrapped)
        target = guess + np.mod(exact - guess + 180.0, 360.0) - 180.0
        ahead = geodesy.azimuth_deg(trajectory(np.clip(t + AZIMUTH_RATE_STEP_S, origin, end)), radar)
        behind = geodesy.azimuth_deg(trajectory(np.clip(t - AZIMUTH_RATE_STEP_S, origin, end)), radar)
        azimuth_rate = (np.mod(ahead - behind + 180.0, 360.0) - 180.0) / (2.0 * AZIMUTH_RATE_STEP_S)
        return phase + elapsed * rate - target - turns, np.maximum(rate - azimuth_rate, 0.05 * rate)

    for _ in range(BEAM_CROSSING_ITERATIONS):
        residual, slope = residual_and_slope(elapsed)
        elapsed = np.clip(elapsed - residual / slope, 0.0, end - origin)
    residual, _ = residual_and_slope(elapsed)
    converged = np.abs(residual) < BEAM_CROSSING_TOLERANCE_DEG
    crossing = np.unique(origin + elapsed[converged])
    return crossing, np.floor(crossing / radar.scan_period_s).astype(np.int64)


def mean_rcs(velocity_ecef: np.ndarray, line_of_sight_ecef: np.ndarray, kind: Aircraft) -> np.ndarray:
    """Aspect-dependent mean RCS: rcs_front nose- or tail-on, rcs_side broadside."""
    cos_aspect = np.add.reduce(velocity_ecef * line_of_sight_ecef, axis=1) / (
        sm.norm(velocity_ecef, axis=1) * sm.norm(line_of_sight_ecef, axis=1))
    sin2 = 1.0 - np.clip(cos_aspect, -1.0, 1.0) ** 2
    return kind.rcs_front_m2 + (kind.rcs_side_m2 - kind.rcs_front_m2) * sin2


def mean_snr(range_m: np.ndarray, rcs_m2: np.ndarray, radar: Radar) -> np.ndarray:
    """Radar equation relative to the reference target: linear mean SNR."""
    ratio = radar.reference_range_m / np.asarray(range_m)
    reference = sm.power(10.0, radar.reference_snr_db / 10.0)
    return reference * (rcs_m2 / radar.reference_rcs_m2) * ((ratio * ratio) * (ratio * ratio))


def detection_probability(snr: np.ndarray, radar: Radar) -> np.ndarray:
    """Swerling 1, square-law detector: Pd = Pfa^(1 / (1 + SNR))."""
    return sm.power(radar.false_alarm_probability, 1.0 / (1.0 + np.asarray(snr)))


def detect(rng: np.random.Generator, snr: np.ndarray, radar: Radar) -> np.ndarray:
    """Draw detections: the received power of a Swerling-1 target in noise is exponential with
    mean 1 + SNR (in noise units); it is detected above the threshold -ln(Pfa)."""
    power = (1.0 + np.asarray(snr)) * rng.exponential(1.0, size=np.shape(snr))
    return power > -sm.log(radar.false_alarm_probability)


def in_coverage(range_m: np.ndarray, altitude_m: np.ndarray, elevation_deg: np.ndarray, radar: Radar) -> np.ndarray:
    """Inside the instrumented range, under the ceiling, below the cone of silence and above the horizon."""
    covered = ((range_m >= radar.range_min_m) & (range_m <= radar.range_max_m) & (altitude_m <= radar.altitude_max_m)
               & (elevation_deg <= radar.max_elevation_deg))
    if radar.horizon:
        covered &= ~geodesy.below_horizon(range_m, altitude_m, radar)
    return covered


def measure(time_unix_s: np.ndarray, range_m: np.ndarray, azimuth_deg: np.ndarray, altitude_m: np.ndarray,
            radar: Radar, reference_unix_s: np.ndarray) -> Measurements:
    """Quantise measurements to CAT048 resolutions, recover Unix time, and place them in ECEF.

    `reference_unix_s` is the receiver's clock used to resolve the day of the time of day.
    """
    tod = asterix_units.time_of_day(time_unix_s)
    q_range = asterix_units.quantise_range(range_m)
    q_azimuth = asterix_units.quantise_azimuth(azimuth_deg)
    flight_level = asterix_units.altitude_to_flight_level(altitude_m)
    q_altitude = asterix_units.flight_level_to_altitude(flight_level)
    return Measurements(
        time_unix_s=asterix_units.unix_from_time_of_day(tod, reference_unix_s),
        time_of_day_s=tod,
        range_m=q_range,
        azimuth_deg=q_azimuth,
        flight_level=flight_level,
        altitude_m=q_altitude,
        ecef=geodesy.plot_to_ecef(q_range, q_azimuth, q_altitude, radar),
    )


def add_measurement_noise(rng: np.random.Generator, range_m: np.ndarray, azimuth_deg: np.ndarray,
                          altitude_m: np.ndarray, radar: Radar) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = len(range_m)
    return (range_m + rng.normal(0.0, radar.sigma_range_m, n),
            np.mod(azimuth_deg + rng.normal(0.0, radar.sigma_azimuth_deg, n), 360.0),
            altitude_m + rng.normal(0.0, radar.sigma_altitude_m, n))


def false_plot_draws(rng: np.random.Generator, scans: np.ndarray, radar: Radar
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Clutter: a Poisson number of plots per scan, uniform in range, azimuth and altitude.

    Returns (scan, time, range, azimuth, altitude). The altitude is uniform between the
    ground and the ceiling, capped at what the slant range can reach (radar height plus
    range) so every false plot has a real elevation.
    """
    counts = rng.poisson(radar.false_plots_per_scan, size=len(scans))
    scan = np.repeat(scans, counts)
    n = len(scan)
    range_m = rng.uniform(radar.range_min_m, radar.range_max_m, n)
    azimuth = rng.uniform(0.0, 360.0, n)
    altitude = rng.uniform(0.0, 1.0, n) * np.minimum(radar.altitude_max_m, radar.height_m + range_m)
    time = scan * radar.scan_period_s + azimuth / 360.0 * radar.scan_period_s
    return scan, time, range_m, azimuth, altitude

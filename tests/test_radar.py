"""The radar: plots where and when the beam sees a target, detection, false plots, ASTERIX units, midnight."""

from __future__ import annotations

from datetime import datetime, timezone

import numpy as np
import pytest
from scipy.interpolate import CubicHermiteSpline

from pipeline.geometry import asterix_units, geodesy
from pipeline.simulation import radar as radar_model
from pipeline.simulation import routes, simulate

# CAT048 time of day resolution (I048/140), written out so a change of the module's constant is caught.
TIME_OF_DAY_STEP_S = 1.0 / 128.0


def columns(table):
    return {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}


def angle_difference_deg(a, b):
    """a - b wrapped into [-180, 180), so 359.9 and 0.1 are 0.2 deg apart."""
    return np.mod(np.asarray(a) - np.asarray(b) + 180.0, 360.0) - 180.0


@pytest.fixture(scope="module")
def params(make_params):
    return make_params(3)


@pytest.fixture(scope="module")
def simulated(params):
    """Route truth, plots and per-scan truth of the small training split, as numpy columns."""
    split = params.routes.split("train")
    route_table = routes.generate_split(params, split)
    plots, truth = simulate.simulate_split(params, split, route_table)
    return columns(route_table), columns(plots), columns(truth)


# --- Beam timing -----------------------------------------------------------------------------------------------


def test_target_plot_times_follow_the_beam(params, simulated):
    """At each target plot's time stamp the beam points at the target, up to the 1/128 s time quantisation."""
    _, plots, _ = simulated
    target = plots["is_target"]
    assert target.sum() > 100
    true_ecef = np.stack([plots["true_x_ecef_m"], plots["true_y_ecef_m"], plots["true_z_ecef_m"]], axis=1)[target]
    _, true_azimuth, _ = geodesy.true_measurement(true_ecef, params.radar)
    beam = radar_model.beam_azimuth_deg(plots["time_unix_s"][target], params.radar)
    beam_rate_dps = 360.0 / params.radar.scan_period_s
    assert np.abs(angle_difference_deg(true_azimuth, beam)).max() <= TIME_OF_DAY_STEP_S * beam_rate_dps


def test_truth_crossing_times_are_where_the_beam_meets_the_target(params, simulated):
    """At every (unquantised) crossing time of the truth table, the beam azimuth is the target's, to 1e-3 deg."""
    _, _, truth = simulated
    beam = radar_model.beam_azimuth_deg(truth["time_unix_s"], params.radar)
    assert np.abs(angle_difference_deg(truth["azimuth_deg"], beam)).max() < 1e-3


def test_target_plot_truth_is_the_route_at_the_plot_time(simulated):
    """true_x/y/z of a target plot is the route's position at the plot's (quantised) time stamp."""
    route_columns, plots, _ = simulated
    for route_id in np.unique(route_columns["route_id"]):
        route = {name: values[route_columns["route_id"] == route_id] for name, values in route_columns.items()}
        trajectory = CubicHermiteSpline(
            route["time_unix_s"], np.stack([route["x_ecef_m"], route["y_ecef_m"], route["z_ecef_m"]], axis=1),
            np.stack([route["vx_ecef_mps"], route["vy_ecef_mps"], route["vz_ecef_mps"]], axis=1))
        times = plots["time_unix_s"]
        inside = (plots["is_target"] & (plots["target_id"] == route_id)
                  & (times >= route["time_unix_s"][0]) & (times <= route["time_unix_s"][-1]))
        true_ecef = np.stack([plots["true_x_ecef_m"], plots["true_y_ecef_m"], plots["true_z_ecef_m"]], axis=1)
        np.testing.assert_allclose(true_ecef[inside], trajectory(times[inside]), rtol=0, atol=1e-3)


def test_no_double_plots(params, simulated):
    """Consecutive target plots (and beam crossings) of one scenario are at least half a scan period apart."""
    _, plots, truth = simulated
    for scenario in np.unique(truth["scenario_id"]):
        crossings = truth["time_unix_s"][truth["scenario_id"] == scenario]
        assert np.diff(crossings).min() >= 0.5 * params.radar.scan_period_s
        plot_times = plots["time_unix_s"][(plots["scenario_id"] == scenario) & plots["is_target"]]
        assert np.all(np.diff(plot_times) >= 0.5 * params.radar.scan_period_s)


@pytest.mark.parametrize("north_m", [100e3, 10e3])
@pytest.mark.parametrize("heading", ["east", "west"])
def test_route_across_north_is_crossed_once_per_revolution(params, north_m, heading):
    """A target flying straight across north gets one beam crossing per revolution: intervals ~ one scan period."""
    speed, duration = 250.0, 300.0
    sign = 1.0 if heading == "east" else -1.0

    def straight_across_north(t):
        t = np.asarray(t, dtype=float)
        return np.stack([sign * speed * (t - duration / 2), np.full(t.shape, north_m), np.full(t.shape, 9000.0)], -1)

    radar = params.radar
    route = routes.sample_route(routes.PlannedRoute(duration, straight_across_north), params.routes.start_time_unix_s,
                                params.routes.sample_interval_s, radar)
    n = len(route["time_unix_s"])
    route = {"route_id": np.zeros(n, np.int32), "aircraft_type": np.array(["airliner"] * n, dtype=object), **route}
    _, truth = simulate.simulate_scenario(params, params.routes.split("test"), route)

    azimuth = truth["azimuth_deg"]
    assert np.any(azimuth < 10.0) and np.any(azimuth > 350.0)  # it really crossed north
    # The target's azimuth rate is at most speed / north_m, so the beam catches it up every
    # period / (1 -+ rate / beam rate).
    period, beam_rate = radar.scan_period_s, 360.0 / radar.scan_period_s
    target_rate = np.degrees(speed / north_m)
    intervals = np.diff(truth["time_unix_s"])
    assert intervals.min() >= period / (1.0 + target_rate / beam_rate) - 1e-3
    assert intervals.max() <= period / (1.0 - target_rate / beam_rate) + 1e-3
    # As many crossings as the beam gains whole turns on the target over the route.
    swept = np.degrees(np.unwrap(np.radians(geodesy.true_measurement(
        np.stack([route["x_ecef_m"], route["y_ecef_m"], route["z_ecef_m"]], 1), radar)[1])))
    gained_turns = (duration * beam_rate - (swept[-1] - swept[0])) / 360.0
    assert abs(len(intervals) + 1 - gained_turns) <= 1.0


# --- Detection -------------------------------------------------------------------------------------------------


def test_snr_and_detection_probability_fall_with_range(params):
    """Mean SNR and Pd decrease with range; at the reference range and RCS, SNR is reference_snr_db."""
    radar = params.radar
    ranges = np.linspace(radar.range_min_m, radar.range_max_m, 1000)
    snr = radar_model.mean_snr(ranges, radar.reference_rcs_m2, radar)
    pd = radar_model.detection_probability(snr, radar)
    assert np.all(np.diff(snr) < 0.0)
    assert np.all(np.diff(pd) <= 0.0) and pd[-1] < pd[0]
    reference = radar_model.mean_snr(radar.reference_range_m, radar.reference_rcs_m2, radar)
    assert 10.0 * np.log10(reference) == pytest.approx(radar.reference_snr_db)


def test_snr_follows_the_radar_equation(params):
    """Mean SNR goes as RCS / R^4: half the range gives 16 times the SNR, twice the RCS twice the SNR."""
    radar = params.radar
    snr = radar_model.mean_snr(np.array([200e3, 100e3, 100e3]), np.array([10.0, 10.0, 20.0]), radar)
    assert snr[1] / snr[0] == pytest.approx(16.0)
    assert snr[2] / snr[1] == pytest.approx(2.0)


@pytest.mark.parametrize("snr", [1.0, 10.0, 100.0])
def test_detect_draws_swerling1_detection_probability(params, snr):
    """radar.detect over 200000 draws detects a fraction Pfa^(1/(1+SNR)), within 4 binomial sigmas."""
    draws = 200_000
    detected = radar_model.detect(np.random.default_rng(int(snr)), np.full(draws, snr), params.radar)
    expected = params.radar.false_alarm_probability ** (1.0 / (1.0 + snr))
    assert expected == pytest.approx(float(radar_model.detection_probability(snr, params.radar)))
    sigma = np.sqrt(draws * expected * (1.0 - expected))
    assert abs(detected.sum() - draws * expected) <= 4.0 * sigma


def test_detection_rate_is_higher_near_the_radar(params, simulated):
    """In simulated data, targets in coverage are detected more often in the near half of the range than beyond."""
    _, _, truth = simulated
    covered = truth["in_coverage"]
    near = truth["range_m"] <= params.radar.range_max_m / 2.0
    assert (covered & near).sum() > 100 and (covered & ~near).sum() > 100
    assert truth["detected"][covered & near].mean() > truth["detected"][covered & ~near].mean()
    assert not truth["detected"][~covered].any()


# --- False plots -----------------------------------------------------------------------------------------------


def test_false_plot_draws_match_their_rate_and_coverage(params):
    """Over 20000 scans false plots average false_plots_per_scan (4 standard errors) and lie in coverage."""
    radar, scans = params.radar, np.arange(1000, 21000)
    scan, time, range_m, azimuth, altitude = radar_model.false_plot_draws(np.random.default_rng(7), scans, radar)
    rate = radar.false_plots_per_scan
    assert abs(len(scan) / len(scans) - rate) <= 4.0 * np.sqrt(rate / len(scans))
    assert np.all((range_m >= radar.range_min_m) & (range_m <= radar.range_max_m))
    assert np.all((azimuth >= 0.0) & (azimuth < 360.0))
    assert np.all((altitude >= 0.0) & (altitude <= radar.altitude_max_m))
    # Each false plot is stamped when the beam sweeps its azimuth within its own scan.
    np.testing.assert_allclose(radar_model.beam_azimuth_deg(time, radar), azimuth, atol=1e-4)
    np.testing.assert_array_equal(np.floor(time / radar.scan_period_s).astype(np.int64), scan)


def test_false_plots_in_a_split_match_the_rate(params, simulated):
    """A split has about false_plots_per_scan false plots per scan its scenarios span (4 Poisson sigmas)."""
    route_columns, plots, _ = simulated
    spanned_scans = 0.0
    for route_id in np.unique(route_columns["route_id"]):
        times = route_columns["time_unix_s"][route_columns["route_id"] == route_id]
        spanned_scans += (times[-1] - times[0]) / params.radar.scan_period_s
    expected = params.radar.false_plots_per_scan * spanned_scans
    false_plots = int((~plots["is_target"]).sum())
    assert abs(false_plots - expected) <= 4.0 * np.sqrt(expected)
    assert np.all(plots["target_id"][~plots["is_target"]] == -1)
    assert np.all(np.isnan(plots["true_x_ecef_m"][~plots["is_target"]]))


# --- Measurements ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("column, step", [
    ("range_m", 1852.0 / 256.0),
    ("azimuth_deg", 360.0 / 2 ** 16),
    ("flight_level", 0.25),
    ("time_of_day_s", TIME_OF_DAY_STEP_S),
])
def test_plots_are_quantised_to_asterix_resolutions(simulated, column, step):
    """Every plot's range, azimuth, flight level and time of day is a whole number of CAT048 steps."""
    _, plots, _ = simulated
    values = plots[column]
    assert np.all(np.isclose(np.round(values / step) * step, values, rtol=0.0, atol=1e-9))
    assert len(np.unique(np.round(values / step))) > 100  # not all the same value


def test_plot_azimuth_range_and_altitude_are_in_bounds(params, simulated):
    """Quantised azimuths stay in [0, 360); ranges within coverage; altitude is the flight level in metres."""
    _, plots, _ = simulated
    assert np.all((plots["azimuth_deg"] >= 0.0) & (plots["azimuth_deg"] < 360.0))
    assert plots["range_m"].max() <= params.radar.range_max_m + 5 * params.radar.sigma_range_m
    np.testing.assert_allclose(plots["altitude_m"], plots["flight_level"] * 100.0 * 0.3048, rtol=1e-12)


def test_target_plot_errors_are_of_the_order_of_the_sigmas(simulated):
    """With the default sigmas the mean distance of a target plot from its truth is between 50 and 500 m."""
    _, plots, _ = simulated
    target = plots["is_target"]
    plot_ecef = np.stack([plots["x_ecef_m"], plots["y_ecef_m"], plots["z_ecef_m"]], axis=1)[target]
    true_ecef = np.stack([plots["true_x_ecef_m"], plots["true_y_ecef_m"], plots["true_z_ecef_m"]], axis=1)[target]
    assert 50.0 <= np.linalg.norm(plot_ecef - true_ecef, axis=1).mean() <= 500.0


# --- Time through midnight ---------------------------------------------------------------------------------------

MIDNIGHT = datetime(2026, 6, 2, tzinfo=timezone.utc).timestamp()


def test_time_of_day_after_midnight_resolves_to_the_next_day():
    """A time of day just after midnight, read with a clock just before it, is the next day (and vice versa)."""
    assert asterix_units.unix_from_time_of_day(0.5, MIDNIGHT - 2.0) == MIDNIGHT + 0.5
    assert asterix_units.unix_from_time_of_day(86399.5, MIDNIGHT + 2.0) == MIDNIGHT - 0.5
    assert asterix_units.unix_from_time_of_day(43200.0, MIDNIGHT + 3600.0) == MIDNIGHT + 43200.0
    np.testing.assert_array_equal(asterix_units.time_of_day(np.array([MIDNIGHT - 0.5, MIDNIGHT, MIDNIGHT + 0.5])),
                                  [86399.5, 0.0, 0.5])


def test_scenarios_run_through_midnight(make_params):
    """Routes starting at 23:59:00 UTC give increasing plot times across midnight, exact to 1/256 s."""
    params = make_params(2, {"routes.start_time_utc": "2026-06-01T23:59:00Z", "routes.start_spread_s": 0.0})
    split = params.routes.split("test")
    plots, truth = (columns(table) for table in simulate.simulate_split(
        params, split, routes.generate_split(params, split)))
    across_midnight = 0
    for scenario in np.unique(truth["scenario_id"]):
        mine = plots["scenario_id"] == scenario
        target = mine & plots["is_target"]
        times, time_of_day = plots["time_unix_s"][target], plots["time_of_day_s"][target]
        assert np.all(np.diff(times) > 0.0)
        assert np.all(np.diff(plots["time_unix_s"][mine]) >= 0.0)
        # The Unix time is the time of day on the right date.
        np.testing.assert_array_equal(np.mod(plots["time_unix_s"][mine], 86400.0), plots["time_of_day_s"][mine])
        # Each target plot is stamped at its beam crossing, to half a time-of-day step.
        crossings = np.sort(truth["time_unix_s"][(truth["scenario_id"] == scenario) & truth["detected"]])
        assert len(crossings) == len(times)
        assert np.all(np.abs(times - crossings) <= TIME_OF_DAY_STEP_S / 2.0 + 1e-6)
        if len(times) and times[0] < MIDNIGHT < times[-1]:
            across_midnight += 1
            assert time_of_day[times > MIDNIGHT].min() < 60.0
            assert time_of_day[times < MIDNIGHT].max() > 86400.0 - 60.0
    assert across_midnight > 0  # at least one scenario had target plots on both sides of midnight

"""Routes: inside coverage, inside each aircraft type's envelope, reproducible per (seed, strategy, index)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry import geodesy
from pipeline.params import STRATEGIES
from pipeline.simulation import routes

ROUTES_PER_STRATEGY = 8
# geodesy.local_to_geodetic maps the planning plane to the earth with under 0.3 % distortion of
# horizontal distances, so ECEF speeds are allowed 0.5 % off the planned ones.
PROJECTION_TOLERANCE = 0.005
# Steps of 1 s are chords of turns of at most 12 deg/s: chord / arc >= sin(x/2) / (x/2) > 0.998.
CHORD_FACTOR = 0.998


@pytest.fixture(scope="module")
def params(make_params):
    return make_params(ROUTES_PER_STRATEGY)


@pytest.fixture(scope="module")
def train_table(params):
    return routes.generate_split(params, params.routes.split("train"))


def per_route(table):
    """Each route's columns as numpy arrays, in route order."""
    columns = {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}
    ids = columns["route_id"]
    return [{name: values[ids == route_id] for name, values in columns.items()} for route_id in np.unique(ids)]


@pytest.fixture(scope="module")
def train_routes(params, train_table):
    """(aircraft type, route columns) of every training route."""
    return [(params.aircraft[route["aircraft_type"][0]], route) for route in per_route(train_table)]


def position(route):
    return np.stack([route["x_ecef_m"], route["y_ecef_m"], route["z_ecef_m"]], axis=1)


def velocity(route):
    return np.stack([route["vx_ecef_mps"], route["vy_ecef_mps"], route["vz_ecef_mps"]], axis=1)


def planar_length(route):
    """Sum of the step distances on the radar's tangent plane, where routes are planned."""
    return float(np.hypot(np.diff(route["east_m"]), np.diff(route["north_m"])).sum())


def routes_of(train_routes, strategy):
    chosen = [(kind, route) for kind, route in train_routes if route["strategy"][0] == strategy]
    assert len(chosen) == ROUTES_PER_STRATEGY
    return chosen


def random_turn_routes(train_routes):
    return routes_of(train_routes, "random_turns")


def speed_interval(kind, strategy):
    """The speeds a strategy flies a type at: sustained turns at the type's holding speeds."""
    if strategy == "sustained_turns":
        return kind.holding_speed_min_mps, kind.holding_speed_max_mps
    return kind.speed_min_mps, kind.speed_max_mps


def headings_deg(route):
    """Unwrapped heading (deg from north) of each 1 s step on the planning plane."""
    return np.degrees(np.unwrap(np.arctan2(np.diff(route["east_m"]), np.diff(route["north_m"]))))


def test_split_holds_the_requested_routes_numbered_strategy_by_strategy(params, train_table):
    """A split has counts[strategy] routes per strategy, ids 0..n-1 in the order of STRATEGIES."""
    route_ids = np.unique(train_table.column("route_id").to_numpy())
    assert route_ids.tolist() == list(range(len(STRATEGIES) * ROUTES_PER_STRATEGY))
    split_routes = per_route(train_table)
    assert [route["strategy"][0] for route in split_routes] == [
        strategy for strategy in STRATEGIES for _ in range(ROUTES_PER_STRATEGY)]
    assert {route["aircraft_type"][0] for route in split_routes} <= set(params.routes.split("train").aircraft_mix)


def test_every_sample_is_in_coverage_and_in_its_altitude_band(params, train_routes):
    """Every truth sample lies in the coverage box and in its aircraft type's altitude band."""
    half_side = np.sqrt(2.0) * params.radar.range_max_m / 2.0
    for kind, route in train_routes:
        assert np.all(np.abs(route["east_m"]) <= half_side)
        assert np.all(np.abs(route["north_m"]) <= half_side)
        altitude = route["altitude_m"]
        assert np.all((altitude > 0.0) & (altitude <= params.radar.altitude_max_m))
        assert np.all((altitude >= kind.altitude_min_m - 1e-6) & (altitude <= kind.altitude_max_m + 1e-6)), kind.name


def test_geodetic_columns_describe_the_ecef_position(train_routes):
    """latitude/longitude/altitude columns are the same points as the ECEF columns."""
    for _, route in train_routes:
        np.testing.assert_allclose(
            geodesy.geodetic_to_ecef(route["latitude_deg"], route["longitude_deg"], route["altitude_m"]),
            position(route), rtol=0, atol=1e-3)


def test_speed_and_acceleration_stay_in_the_envelope(params, train_routes):
    """ECEF speed is within the type's speed interval (holding speeds for sustained turns) and the 1 s
    velocity change within its max acceleration, for every strategy."""
    step = params.routes.sample_interval_s
    for kind, route in train_routes:
        speed = np.linalg.norm(velocity(route), axis=1)
        low, high = speed_interval(kind, route["strategy"][0])
        assert speed.min() >= low * (1.0 - PROJECTION_TOLERANCE), kind.name
        assert speed.max() <= high * (1.0 + PROJECTION_TOLERANCE), kind.name
        acceleration = np.linalg.norm(np.diff(velocity(route), axis=0), axis=1) / step
        assert acceleration.max() <= kind.max_acceleration_mps2 * 1.02 + 0.05, kind.name


def test_random_turns_keep_speed_and_altitude_and_length(params, train_routes):
    """Random-turn routes fly at one speed (0.5 %) and altitude, and between min_length_m and length_m[1] long."""
    cfg = params.routes.random_turns
    for _, route in random_turn_routes(train_routes):
        speed = np.linalg.norm(velocity(route), axis=1)
        assert np.ptp(speed) <= PROJECTION_TOLERANCE * speed.mean()
        assert np.ptp(route["altitude_m"]) < 1e-6
        assert cfg.min_length_m * CHORD_FACTOR <= planar_length(route) <= cfg.length_max_m


def test_random_turns_are_300_to_500_km_unless_they_leave_coverage(params, train_routes):
    """A random-turn route shorter than length_m[0] ends within one step of the coverage box edge."""
    cfg, step = params.routes.random_turns, params.routes.sample_interval_s
    half_side = np.sqrt(2.0) * params.radar.range_max_m / 2.0
    full_length = 0
    for _, route in random_turn_routes(train_routes):
        speed = float(np.linalg.norm(velocity(route)[-1]))
        length = planar_length(route)
        to_edge = half_side - max(abs(route["east_m"][-1]), abs(route["north_m"][-1]))
        if to_edge > speed * step:
            # The last sample is within one step of the drawn length.
            assert length >= cfg.length_min_m * CHORD_FACTOR - speed * step
            full_length += 1
        assert length <= cfg.length_max_m
    assert full_length > 0  # the rule was exercised on at least one route that stayed in coverage


def test_sustained_turns_turn_at_one_rate_in_the_interval_or_at_the_envelope(params, train_routes):
    """Holding patterns and orbits: constant speed and altitude; every turning step at one rate, drawn in
    turn_rate_dps or capped where the type cannot fly it (v * omega <= max_acceleration); whole
    360 deg laps or orbits; both kinds in the split."""
    cfg, step = params.routes.sustained_turns, params.routes.sample_interval_s
    kinds = set()
    for kind, route in routes_of(train_routes, "sustained_turns"):
        speed = np.linalg.norm(velocity(route), axis=1)
        assert np.ptp(speed) <= PROJECTION_TOLERANCE * speed.mean()
        assert np.ptp(route["altitude_m"]) < 1e-6
        heading = headings_deg(route)
        rate = np.abs(np.diff(heading)) / step
        turning = rate > 0.75 * rate.max()     # a step half in a turn turns at half the rate
        assert np.ptp(rate[turning]) < 1e-6 * rate.max()
        speed_on_plane = np.hypot(np.diff(route["east_m"]), np.diff(route["north_m"])).max() / step
        cap = min(kind.max_turn_rate_dps, np.degrees(kind.max_acceleration_mps2 / speed_on_plane))
        # A 180 deg turn lasts whole steps: the rate is lowered by at most one step in the turn (< 2 %).
        assert min(cfg.turn_rate_min_dps, cap) * 0.98 <= rate.max() <= min(cfg.turn_rate_max_dps, cap) * 1.001
        laps = abs(heading[-1] - heading[0]) / 360.0
        assert laps >= 1.0 - 1e-9 and abs(laps - round(laps)) < 1e-6, laps
        straight_between_turns = np.flatnonzero(turning)
        kinds.add("holding" if np.any(np.diff(straight_between_turns) > 2) else "orbit")
    assert kinds == {"holding", "orbit"}


def test_climb_dive_routes_climb_and_dive_smoothly_within_the_vertical_rate(params, train_routes):
    """Climb-dive routes change altitude by at least altitude_change_m[0], at vertical speeds up to
    vertical_rate_fraction[1] x the type's max_vertical_rate_mps, with a continuous vertical speed whose
    changes stay within vertical_acceleration_fraction x max_acceleration."""
    cfg, step = params.routes.climb_dive, params.routes.sample_interval_s
    for kind, route in routes_of(train_routes, "climb_dive"):
        altitude = route["altitude_m"]
        assert np.ptp(altitude) >= cfg.altitude_change_min_m - 1e-6, kind.name
        vertical_speed = np.diff(altitude) / step
        assert np.abs(vertical_speed).max() <= cfg.vertical_rate_max_fraction * kind.max_vertical_rate_mps + 1e-6
        vertical_acceleration = np.abs(np.diff(vertical_speed)) / step
        assert vertical_acceleration.max() <= cfg.vertical_acceleration_fraction * kind.max_acceleration_mps2 + 1e-6


def test_truth_is_sampled_at_the_sample_interval(params, train_routes):
    """Truth samples are sample_interval_s apart and start within start_spread_s of start_time_utc."""
    step, start = params.routes.sample_interval_s, params.routes.start_time_unix_s
    for _, route in train_routes:
        np.testing.assert_allclose(np.diff(route["time_unix_s"]), step, rtol=0, atol=1e-6)
        assert start <= route["time_unix_s"][0] <= start + params.routes.start_spread_s


def test_velocity_is_the_derivative_of_position(params, train_routes):
    """The central difference of 1 s positions matches the velocity columns: within a_max*dt/2, typically 2 m/s."""
    step = params.routes.sample_interval_s
    for kind, route in train_routes:
        p = position(route)
        central = (p[2:] - p[:-2]) / (2.0 * step)
        mismatch = np.linalg.norm(central - velocity(route)[1:-1], axis=1)
        # The mean velocity over [t-dt, t+dt] differs from v(t) by at most a_max * dt / 2.
        assert mismatch.max() <= kind.max_acceleration_mps2 * step / 2.0 + 0.5, kind.name
        assert np.median(mismatch) < 2.0, kind.name


def test_splits_are_independent(params, train_table):
    """No route of the test split starts where a training route starts."""
    test_table = routes.generate_split(params, params.routes.split("test"))
    train_starts = {tuple(np.round(position(route)[0], 3)) for route in per_route(train_table)}
    test_starts = {tuple(np.round(position(route)[0], 3)) for route in per_route(test_table)}
    assert len(test_starts) == test_table.column("route_id").to_numpy().max() + 1
    assert not train_starts & test_starts


def test_generating_a_split_twice_gives_the_same_table(make_params):
    """The same params give the same split, row for row."""
    params = make_params(2)
    split = params.routes.split("calibration")
    assert routes.generate_split(params, split).equals(routes.generate_split(params, split))


def test_a_route_does_not_change_with_the_counts_of_its_split(make_params):
    """Route i of a strategy depends only on (split seed, strategy, i), not on how many routes the split has."""
    few, more = make_params(2), make_params(4)
    few_table = routes.generate_split(few, few.routes.split("test"))
    more_table = routes.generate_split(more, more.routes.split("test"))
    for strategy in STRATEGIES:
        few_routes = [r for r in per_route(few_table) if r["strategy"][0] == strategy]
        more_routes = [r for r in per_route(more_table) if r["strategy"][0] == strategy]
        assert len(few_routes) == 2 and len(more_routes) == 4
        for a, b in zip(few_routes, more_routes):
            assert a.keys() == b.keys()
            for name in a:
                if name != "route_id":
                    np.testing.assert_array_equal(a[name], b[name], err_msg=f"{strategy} {name}")
    # And generate_route gives that route on its own, whatever id it is given.
    alone = routes.generate_route(few, few.routes.split("test"), "random_turns", 1, route_id=99)
    assert alone.drop_columns(["route_id"]).equals(
        more_table.filter(more_table.column("route_id").to_numpy() == 5).drop_columns(["route_id"]))


def test_the_thesis_strategies_do_not_change_with_the_newer_ones(make_params):
    """Adding sustained_turns and climb_dive routes to a split leaves its constant-jerk and random-turn
    routes (ids included) as they were: new strategies take the next indices in STRATEGIES."""
    without = make_params(2, {f"routes.splits.test.{strategy}": 0 for strategy in STRATEGIES[2:]})
    with_new = make_params(2)
    old = routes.generate_split(without, without.routes.split("test"))
    new = routes.generate_split(with_new, with_new.routes.split("test"))
    assert new.num_rows > old.num_rows
    assert new.slice(0, old.num_rows).equals(old)

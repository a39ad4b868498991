"""Aircraft routes: the thesis's two strategies and two of ours, inside the radar's coverage box.

Routes are planned on the radar's tangent plane (east, north) with an altitude above the
ellipsoid, as analytic functions of time, then sampled and mapped to the earth by
`geodesy.local_to_geodetic`. Velocity is differentiated from the analytic trajectory, so
it is exact to well under a millimetre per second rather than a finite difference of the
1 s samples.

- Constant jerk: random waypoints; each waypoint's velocity points at the next one with a
  speed from the aircraft's interval; between waypoints a cubic per axis with position
  and velocity fixed at both ends (a Hermite spline, which is Stone Soup's constant-jerk
  model between two states). A waypoint whose leg breaks the envelope (acceleration,
  speed) or leaves the box is redrawn.
- Random turns: constant speed and altitude, a sequence of constant-rate turns of random
  rate and duration, until the drawn length (300-500 km) is flown or the route leaves
  coverage. Turn rates are capped by the aircraft's turn rate and by its acceleration
  (centripetal v*omega <= a_max).
- Sustained turns (ours, issue 13): a straight entry leg, then minutes of turning at one
  constant rate, then a straight exit leg, at constant speed and altitude. Either a holding
  pattern (the ICAO Doc 8168 racetrack: 180 deg turns joined by straight legs of 1-1.5 min,
  whole laps) or a calibration orbit (consecutive 360 deg turns). The rate is drawn in
  `routes.sustained_turns.turn_rate_dps` (1.5-3 deg/s; ICAO's holding turns are 3 deg/s or
  a 25 deg bank, whichever is less) and capped like the random turns, at the type's holding
  speed (`aircraft.<type>.holding_speed_mps`, a true airspeed). With the default envelope the
  light aircraft (50-65 m/s, a_max 6 m/s^2) and the fighter (130-180 m/s, a_max 60 m/s^2) fly
  the whole 1.5-3 deg/s; the airliner cannot: its a_max of 3 m/s^2 (a 17 deg bank) at
  150-200 m/s allows only 0.86-1.15 deg/s, which it flies. Its a_max is not raised for these
  routes (a 25 deg bank, 4.6 m/s^2, would give 1.3-1.7 deg/s) because every route of a type
  keeps one envelope, and raising it would change the existing routes.
- Climb and dive (ours, issue 13): constant horizontal speed through gentle random turns
  (the random turns' sequence, at most `routes.climb_dive.turn_rate_dps`), and level flight
  alternating with climbs and dives inside the type's altitude band. Each climb or dive
  ramps the vertical speed at a constant vertical acceleration (a share of a_max) up to a
  rate drawn as a share of `aircraft.<type>.max_vertical_rate_mps`, holds it and ramps it
  back down, so velocity is continuous. The turns use what the vertical acceleration leaves
  of a_max (sqrt(a_max^2 - a_v^2), at right angles), and the horizontal speed is drawn so
  the steepest climb stays below the top speed. A route ends after its drawn length or when
  it leaves coverage, and is redrawn if shorter than `min_length_m` or if it leaves before
  finishing its first climb or dive.

Sines, cosines and vector lengths come from `pipeline.geometry.strict_math`, which gives the same bits on
every processor, as do the conversions of `geodesy`: with NumPy's and the C library's,
processor-specific in the last bit, the route files' bytes differ from machine to machine, and
a last bit can even tip a redraw decision (a leg's duration, a box test) and so a whole route
(issue 27).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np
import pyarrow as pa
from scipy.interpolate import CubicHermiteSpline

from pipeline import io
from pipeline.geometry import geodesy
from pipeline.geometry import strict_math as sm
from pipeline.params import (
    STRATEGIES,
    Aircraft,
    ClimbDive,
    ConstantJerk,
    Params,
    Radar,
    RandomTurns,
    Routes,
    Split,
    SustainedTurns,
)

DIFFERENTIATION_STEP_S = 0.05

ROUTE_SCHEMA = io.schema(
    ("route_id", pa.int32()),
    ("strategy", pa.string()),
    ("aircraft_type", pa.string()),
    ("time_unix_s", pa.float64()),
    ("x_ecef_m", pa.float64()),
    ("y_ecef_m", pa.float64()),
    ("z_ecef_m", pa.float64()),
    ("vx_ecef_mps", pa.float64()),
    ("vy_ecef_mps", pa.float64()),
    ("vz_ecef_mps", pa.float64()),
    ("latitude_deg", pa.float64()),
    ("longitude_deg", pa.float64()),
    ("altitude_m", pa.float64()),
    ("east_m", pa.float64()),
    ("north_m", pa.float64()),
)


class RouteGenerationError(RuntimeError):
    """The route parameters make it impossible to draw a valid route."""


@dataclass(frozen=True)
class CoverageBox:
    """Square of side sqrt(2)*R_max centred on the radar, from the ground to the ceiling."""

    half_side_m: float
    ceiling_m: float

    @classmethod
    def of(cls, radar: Radar) -> "CoverageBox":
        return cls(half_side_m=radar.range_max_m * np.sqrt(2.0) / 2.0, ceiling_m=radar.altitude_max_m)

    def contains(self, local: np.ndarray) -> np.ndarray:
        """Rows of (east, north, altitude) that lie inside the box."""
        return ((np.abs(local[..., 0]) <= self.half_side_m) & (np.abs(local[..., 1]) <= self.half_side_m)
                & (local[..., 2] > 0.0) & (local[..., 2] <= self.ceiling_m))


@dataclass(frozen=True)
class PlannedRoute:
    """A route as a function of time since its start: t (s) -> (east, north, altitude) rows."""

    duration_s: float
    position: Callable[[np.ndarray], np.ndarray]


def _random_point(rng: np.random.Generator, box: CoverageBox, kind: Aircraft) -> np.ndarray:
    return np.array([rng.uniform(-box.half_side_m, box.half_side_m), rng.uniform(-box.half_side_m, box.half_side_m),
                     rng.uniform(kind.altitude_min_m, kind.altitude_max_m)])


def _leg_is_flyable(start: np.ndarray, end: np.ndarray, v_start: np.ndarray, v_end: np.ndarray,
                    kind: Aircraft, box: CoverageBox) -> tuple[bool, float]:
    """Hermite leg between two states: within acceleration, speed and box? Returns (ok, duration)."""
    duration = 2.0 * sm.norm(end - start) / (sm.norm(v_start) + sm.norm(v_end))
    leg = CubicHermiteSpline([0.0, duration], np.stack([start, end]), np.stack([v_start, v_end]))
    # Acceleration of a cubic is linear in time, so its norm peaks at an end of the leg.
    acceleration = leg(np.array([0.0, duration]), 2)
    if sm.norm(acceleration, axis=1).max() > kind.max_acceleration_mps2:
        return False, duration
    t = np.linspace(0.0, duration, max(32, int(duration / 2.0)))
    speed = sm.norm(leg(t, 1), axis=1)
    if speed.min() < kind.speed_min_mps or speed.max() > kind.speed_max_mps:
        return False, duration
    points = leg(t)
    inside_band = (points[:, 2] >= kind.altitude_min_m) & (points[:, 2] <= kind.altitude_max_m)
    return bool(box.contains(points).all() and inside_band.all()), duration


def _next_waypoint(rng: np.random.Generator, previous: np.ndarray, cfg: ConstantJerk, box: CoverageBox,
                   kind: Aircraft) -> np.ndarray:
    sin_bearing, cos_bearing = sm.sin_cos(rng.uniform(0.0, 2.0 * np.pi))
    distance = rng.uniform(cfg.min_leg_m, cfg.max_leg_m)
    return np.array([previous[0] + distance * sin_bearing, previous[1] + distance * cos_bearing,
                     rng.uniform(kind.altitude_min_m, kind.altitude_max_m)])


def _velocity_towards(rng: np.random.Generator, start: np.ndarray, target: np.ndarray, kind: Aircraft) -> np.ndarray:
    direction = (target - start) / sm.norm(target - start)
    return direction * rng.uniform(kind.speed_min_mps, kind.speed_max_mps)


def plan_constant_jerk(rng: np.random.Generator, kind: Aircraft, cfg: ConstantJerk, box: CoverageBox) -> PlannedRoute:
    """Waypoints joined by constant-jerk (cubic Hermite) legs; see the module docstring."""
    count = int(rng.integers(cfg.waypoints_min, cfg.waypoints_max + 1))
    for _ in range(cfg.attempts):
        points = [_random_point(rng, box, kind)]
        first = _next_waypoint(rng, points[0], cfg, box, kind)
        if not box.contains(first):
            continue
        points.append(first)
        velocities = [_velocity_towards(rng, points[0], points[1], kind)]
        times = [0.0]
        for index in range(2, count + 1):
            for _ in range(cfg.attempts):
                if index < count:
                    candidate = _next_waypoint(rng, points[-1], cfg, box, kind)
                    if not box.contains(candidate):
                        continue
                    velocity = _velocity_towards(rng, points[-1], candidate, kind)
                else:
                    candidate = None
                    velocity = _velocity_towards(rng, points[-2], points[-1], kind)
                ok, duration = _leg_is_flyable(points[-2], points[-1], velocities[-1], velocity, kind, box)
                if ok:
                    break
            else:
                break
            velocities.append(velocity)
            times.append(times[-1] + duration)
            if candidate is not None:
                points.append(candidate)
        if len(velocities) == count:
            spline = CubicHermiteSpline(np.array(times), np.stack(points), np.stack(velocities))
            return PlannedRoute(duration_s=times[-1], position=spline)
    raise RouteGenerationError(
        f"constant_jerk: no {kind.name} route of {count} waypoints within {cfg.attempts} attempts; widen "
        f"routes.constant_jerk.min_leg_m/max_leg_m or aircraft.{kind.name}.max_acceleration_mps2")


def max_turn_rate(kind: Aircraft, speed: float, acceleration: float) -> float:
    """Fastest turn (rad/s) at `speed` within the type's turn rate and a centripetal `acceleration`."""
    return min(np.radians(kind.max_turn_rate_dps), acceleration / speed)


def _turn_sequence(rng: np.random.Generator, total_s: float, max_rate: float, duration_min_s: float,
                   duration_max_s: float, step_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Start times and turn rates (rad/s, uniform within +-max_rate) of constant-rate segments covering total_s.

    Durations are whole sampling steps so each sample falls inside one segment.
    """
    starts, rates, elapsed = [], [], 0.0
    while elapsed < total_s:
        starts.append(elapsed)
        rates.append(rng.uniform(-max_rate, max_rate))
        elapsed += max(step_s, round(rng.uniform(duration_min_s, duration_max_s) / step_s) * step_s)
    return np.array(starts), np.array(rates)


def coordinated_turns(origin: np.ndarray, heading: float, speed: float, starts: np.ndarray,
                       rates: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Closed-form position of constant-speed flight through constant-rate turns (heading from north)."""
    durations = np.diff(np.append(starts, np.inf))
    headings = heading + np.concatenate([[0.0], np.cumsum(rates[:-1] * durations[:-1])])
    east, north = _turn_displacement(speed, headings[:-1], rates[:-1], durations[:-1])
    segment_east = origin[0] + np.concatenate([[0.0], np.cumsum(east)])
    segment_north = origin[1] + np.concatenate([[0.0], np.cumsum(north)])

    def position(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(starts) - 1)
        d_east, d_north = _turn_displacement(speed, headings[k], rates[k], t - starts[k])
        return np.stack([segment_east[k] + d_east, segment_north[k] + d_north, np.full(t.shape, origin[2])], axis=-1)

    return position


def _turn_displacement(speed: float, heading: np.ndarray, rate: np.ndarray, elapsed: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """East and north displacement after `elapsed` seconds of a turn at `rate` from `heading`."""
    turned = rate * elapsed
    straight = np.abs(rate) < 1e-12
    safe_rate = np.where(straight, 1.0, rate)
    (sin_start, cos_start), (sin_end, cos_end) = sm.sin_cos(heading), sm.sin_cos(heading + turned)
    east = np.where(straight, speed * elapsed * sin_start, speed / safe_rate * (cos_start - cos_end))
    north = np.where(straight, speed * elapsed * cos_start, speed / safe_rate * (sin_end - sin_start))
    return east, north


def _sample_times(duration_s: float, step_s: float) -> np.ndarray:
    """The truth sample times of a route: every step_s from 0 to its duration inclusive."""
    return np.arange(0.0, duration_s + 1e-9, step_s)


def _time_in_coverage(position: Callable[[np.ndarray], np.ndarray], duration_s: float, box: CoverageBox,
                      step_s: float) -> float:
    """Time of the last sample before the route first leaves the box (0 if it starts outside)."""
    t = np.arange(0.0, duration_s + step_s, step_s)
    t = t[t <= duration_s]
    inside = box.contains(position(t))
    samples_inside = len(t) if inside.all() else int(np.argmax(~inside))
    return float(t[samples_inside - 1]) if samples_inside else 0.0


def plan_random_turns(rng: np.random.Generator, kind: Aircraft, cfg: RandomTurns, box: CoverageBox,
                      step_s: float, attempts: int = 1000) -> PlannedRoute:
    """Constant speed and altitude through random turns, until the length is flown or coverage is left."""
    for _ in range(attempts):
        origin = _random_point(rng, box, kind)
        heading = rng.uniform(0.0, 2.0 * np.pi)
        speed = rng.uniform(kind.speed_min_mps, kind.speed_max_mps)
        length = rng.uniform(cfg.length_min_m, cfg.length_max_m)
        starts, rates = _turn_sequence(rng, length / speed, max_turn_rate(kind, speed, kind.max_acceleration_mps2),
                                       cfg.turn_duration_min_s, cfg.turn_duration_max_s, step_s)
        position = coordinated_turns(origin, heading, speed, starts, rates)
        end = _time_in_coverage(position, length / speed, box, step_s)
        if end * speed >= cfg.min_length_m:
            return PlannedRoute(duration_s=end, position=position)
    raise RouteGenerationError(f"random_turns: no {kind.name} route of at least "
                               f"routes.random_turns.min_length_m = {cfg.min_length_m} m in {attempts} attempts")


def _sustained_turn_segments(rng: np.random.Generator, cfg: SustainedTurns, rate: float, step_s: float
                             ) -> tuple[np.ndarray, np.ndarray]:
    """Durations (s) and rates (rad/s) of the entry leg, the laps or orbits and the exit leg.

    A 180 deg turn lasts whole sampling steps, at `rate` or just below it, so the turns close
    exactly and each sample falls inside one segment. A holding pattern's lap is turn, leg,
    turn, leg (ICAO Doc 8168 racetrack); an orbit is one 360 deg turn. The side is random
    (ICAO's standard holding turns right, a non-standard one left).
    """
    half_turn = np.ceil(np.pi / rate / step_s) * step_s
    rate = np.pi / half_turn * rng.choice([-1.0, 1.0])
    laps = max(1, round(rng.uniform(cfg.turning_time_min_s, cfg.turning_time_max_s) / (2.0 * half_turn)))
    if rng.uniform() < cfg.holding_probability:
        leg = round(rng.uniform(cfg.holding_leg_min_s, cfg.holding_leg_max_s) / step_s) * step_s
        lap_durations, lap_rates = [half_turn, leg, half_turn, leg], [rate, 0.0, rate, 0.0]
    else:
        lap_durations, lap_rates = [2.0 * half_turn], [rate]
    entry = round(rng.uniform(cfg.straight_min_s, cfg.straight_max_s) / step_s) * step_s
    exit_leg = round(rng.uniform(cfg.straight_min_s, cfg.straight_max_s) / step_s) * step_s
    return (np.concatenate([[entry], np.tile(lap_durations, laps), [exit_leg]]),
            np.concatenate([[0.0], np.tile(lap_rates, laps), [0.0]]))


def plan_sustained_turns(rng: np.random.Generator, kind: Aircraft, cfg: SustainedTurns, box: CoverageBox,
                         step_s: float) -> PlannedRoute:
    """A holding pattern or a calibration orbit at constant speed, altitude and turn rate; see the module docstring."""
    for _ in range(cfg.attempts):
        origin = _random_point(rng, box, kind)
        heading = rng.uniform(0.0, 2.0 * np.pi)
        speed = rng.uniform(kind.holding_speed_min_mps, kind.holding_speed_max_mps)
        rate = min(np.radians(rng.uniform(cfg.turn_rate_min_dps, cfg.turn_rate_max_dps)),
                   max_turn_rate(kind, speed, kind.max_acceleration_mps2))
        durations, rates = _sustained_turn_segments(rng, cfg, rate, step_s)
        position = coordinated_turns(origin, heading, speed, np.cumsum(durations) - durations, rates)
        duration = float(durations.sum())
        if box.contains(position(_sample_times(duration, step_s))).all():
            return PlannedRoute(duration_s=duration, position=position)
    raise RouteGenerationError(f"sustained_turns: no {kind.name} route inside the coverage box in "
                               f"routes.sustained_turns.attempts = {cfg.attempts} attempts")


def _altitude_change(rng: np.random.Generator, kind: Aircraft, cfg: ClimbDive, altitude: float) -> float:
    """Signed altitude change of the next climb or dive: up or down in proportion to the room left in
    the type's band (params ensure one side has room for the smallest change), never beyond it."""
    room_up, room_down = kind.altitude_max_m - altitude, altitude - kind.altitude_min_m
    up = rng.uniform() * (room_up + room_down) < room_up
    if (room_up if up else room_down) < cfg.altitude_change_min_m:
        up = not up
    change = rng.uniform(cfg.altitude_change_min_m, min(cfg.altitude_change_max_m, room_up if up else room_down))
    return change if up else -change


def _climbs_and_dives(rng: np.random.Generator, kind: Aircraft, cfg: ClimbDive, altitude: float, total_s: float,
                      acceleration: float) -> tuple[np.ndarray, np.ndarray]:
    """Start times and vertical accelerations of level flight alternating with climbs and dives.

    A climb or dive ramps the vertical speed up at constant `acceleration`, holds it and ramps
    it back to zero, so the vertical speed is continuous (no step in velocity). A change too
    small to reach the drawn rate is flown with a lower one (a triangular profile).
    """
    durations, accelerations, elapsed = [], [], 0.0
    while elapsed < total_s:
        level = rng.uniform(cfg.level_min_s, cfg.level_max_s)
        change = _altitude_change(rng, kind, cfg, altitude)
        rate = rng.uniform(cfg.vertical_rate_min_fraction, cfg.vertical_rate_max_fraction) * kind.max_vertical_rate_mps
        rate = min(rate, np.sqrt(abs(change) * acceleration))
        ramp = rate / acceleration
        hold = abs(change) / rate - ramp
        durations += [level, ramp, hold, ramp]
        accelerations += [0.0, np.sign(change) * acceleration, 0.0, -np.sign(change) * acceleration]
        altitude += change
        elapsed += level + 2.0 * ramp + hold
    return np.concatenate([[0.0], np.cumsum(durations)]), np.append(accelerations, 0.0)


def _vertical_profile(start: float, knots: np.ndarray, accelerations: np.ndarray
                      ) -> Callable[[np.ndarray], np.ndarray]:
    """Closed-form altitude under piecewise-constant vertical acceleration, level at `start` before knots[0]."""
    durations = np.diff(knots)
    rates = np.concatenate([[0.0], np.cumsum(accelerations[:-1] * durations)])
    heights = start + np.concatenate([[0.0], np.cumsum(rates[:-1] * durations
                                                       + 0.5 * accelerations[:-1] * durations ** 2)])

    def altitude(t: np.ndarray) -> np.ndarray:
        k = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(knots) - 1)
        elapsed = t - knots[k]
        return heights[k] + rates[k] * elapsed + 0.5 * accelerations[k] * elapsed ** 2

    return altitude


def _with_altitude(horizontal: Callable[[np.ndarray], np.ndarray], altitude: Callable[[np.ndarray], np.ndarray]
                   ) -> Callable[[np.ndarray], np.ndarray]:
    """A route's position: east and north from `horizontal`, its altitude from `altitude`."""
    def position(t: np.ndarray) -> np.ndarray:
        local = horizontal(t)
        local[..., 2] = altitude(np.asarray(t, dtype=float))
        return local

    return position


def climb_speed_max_mps(kind: Aircraft) -> float:
    """Fastest horizontal speed of a climb_dive route: in its steepest climb it flies at top speed."""
    top, vertical = kind.speed_max_mps, kind.max_vertical_rate_mps
    return float(np.sqrt(top * top - vertical * vertical))


def plan_climb_dive(rng: np.random.Generator, kind: Aircraft, cfg: ClimbDive, box: CoverageBox,
                    step_s: float) -> PlannedRoute:
    """Constant horizontal speed through gentle turns, level flight alternating with climbs and dives,
    until the length is flown or coverage is left; see the module docstring."""
    vertical_acceleration = cfg.vertical_acceleration_fraction * kind.max_acceleration_mps2
    turn_acceleration = np.sqrt(kind.max_acceleration_mps2 * kind.max_acceleration_mps2
                                - vertical_acceleration * vertical_acceleration)
    for _ in range(cfg.attempts):
        origin = _random_point(rng, box, kind)
        heading = rng.uniform(0.0, 2.0 * np.pi)
        speed = rng.uniform(kind.speed_min_mps, climb_speed_max_mps(kind))
        total = rng.uniform(cfg.length_min_m, cfg.length_max_m) / speed
        max_rate = min(np.radians(cfg.turn_rate_dps), max_turn_rate(kind, speed, turn_acceleration))
        starts, rates = _turn_sequence(rng, total, max_rate, cfg.turn_duration_min_s, cfg.turn_duration_max_s, step_s)
        horizontal = coordinated_turns(origin, heading, speed, starts, rates)
        knots, accelerations = _climbs_and_dives(rng, kind, cfg, origin[2], total, vertical_acceleration)
        position = _with_altitude(horizontal, _vertical_profile(origin[2], knots, accelerations))
        end = _time_in_coverage(position, total, box, step_s)
        # knots[4]: the end of the first climb or dive, which every route flies whole.
        if end * speed >= cfg.min_length_m and end >= knots[4]:
            return PlannedRoute(duration_s=end, position=position)
    raise RouteGenerationError(f"climb_dive: no {kind.name} route of at least routes.climb_dive.min_length_m = "
                               f"{cfg.min_length_m} m and one whole climb or dive in routes.climb_dive.attempts = "
                               f"{cfg.attempts} attempts")


def sample_route(planned: PlannedRoute, start_time_unix_s: float, step_s: float, radar: Radar) -> dict[str, np.ndarray]:
    """Truth columns of one route at `step_s` spacing: time, ECEF position and velocity, geodetic."""
    t = _sample_times(planned.duration_s, step_s)
    local = planned.position(t)
    lat, lon, alt = geodesy.local_to_geodetic(local[:, 0], local[:, 1], local[:, 2], radar)
    ecef = geodesy.geodetic_to_ecef(lat, lon, alt)
    velocity = (_ecef_at(planned, t + DIFFERENTIATION_STEP_S, radar)
                - _ecef_at(planned, t - DIFFERENTIATION_STEP_S, radar)) / (2.0 * DIFFERENTIATION_STEP_S)
    return {
        "time_unix_s": start_time_unix_s + t,
        "x_ecef_m": ecef[:, 0], "y_ecef_m": ecef[:, 1], "z_ecef_m": ecef[:, 2],
        "vx_ecef_mps": velocity[:, 0], "vy_ecef_mps": velocity[:, 1], "vz_ecef_mps": velocity[:, 2],
        "latitude_deg": lat, "longitude_deg": lon, "altitude_m": alt,
        "east_m": local[:, 0], "north_m": local[:, 1],
    }


def _ecef_at(planned: PlannedRoute, t: np.ndarray, radar: Radar) -> np.ndarray:
    # The analytic trajectories extend smoothly a little past both ends, so +-dt is safe there.
    local = planned.position(t)
    lat, lon, alt = geodesy.local_to_geodetic(local[:, 0], local[:, 1], local[:, 2], radar)
    return geodesy.geodetic_to_ecef(lat, lon, alt)


def draw_aircraft(rng: np.random.Generator, mix: Mapping[str, float], aircraft: Mapping[str, Aircraft]) -> Aircraft:
    """An aircraft type drawn by the weights of `mix` (type name -> weight)."""
    names = sorted(mix)
    weights = np.array([mix[name] for name in names])
    return aircraft[names[int(rng.choice(len(names), p=weights / weights.sum()))]]


def plan_route(rng: np.random.Generator, strategy: str, kind: Aircraft, routes: Routes, box: CoverageBox
               ) -> PlannedRoute:
    """A route of `strategy` (one of STRATEGIES) for an aircraft of type `kind`."""
    step = routes.sample_interval_s
    if strategy == "constant_jerk":
        return plan_constant_jerk(rng, kind, routes.constant_jerk, box)
    if strategy == "random_turns":
        return plan_random_turns(rng, kind, routes.random_turns, box, step)
    if strategy == "sustained_turns":
        return plan_sustained_turns(rng, kind, routes.sustained_turns, box, step)
    return plan_climb_dive(rng, kind, routes.climb_dive, box, step)


def generate_route(params: Params, split: Split, strategy: str, index: int, route_id: int) -> pa.Table:
    """One route of a split. Its random stream depends only on (split seed, strategy, index)."""
    rng = np.random.default_rng([split.seed, STRATEGIES.index(strategy), index])
    routes, radar = params.routes, params.radar
    kind = draw_aircraft(rng, split.aircraft_mix, params.aircraft)
    start = routes.start_time_unix_s + rng.uniform(0.0, routes.start_spread_s)
    planned = plan_route(rng, strategy, kind, routes, CoverageBox.of(radar))
    columns = sample_route(planned, start, routes.sample_interval_s, radar)
    n = len(columns["time_unix_s"])
    columns = {"route_id": np.full(n, route_id, np.int32), "strategy": [strategy] * n,
               "aircraft_type": [kind.name] * n, **columns}
    return pa.Table.from_pydict(columns, schema=ROUTE_SCHEMA)


def generate_split(params: Params, split: Split, progress: Callable[[int, int], None] | None = None) -> pa.Table:
    """All routes of a split: route ids number the routes strategy by strategy, in the order of STRATEGIES."""
    jobs = [(strategy, index) for strategy in STRATEGIES for index in range(split.counts[strategy])]
    tables = []
    for route_id, (strategy, index) in enumerate(jobs):
        tables.append(generate_route(params, split, strategy, index, route_id))
        if progress is not None:
            progress(route_id + 1, len(jobs))
    if not tables:
        return ROUTE_SCHEMA.empty_table()
    return pa.concat_tables(tables)

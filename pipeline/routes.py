"""Aircraft routes: the thesis's two strategies, inside the radar's coverage box.

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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pyarrow as pa
from scipy.interpolate import CubicHermiteSpline

from pipeline import geodesy, io
from pipeline.params import STRATEGIES, Aircraft, ConstantJerk, Params, RandomTurns, Radar, Split

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
    duration = 2.0 * np.linalg.norm(end - start) / (np.linalg.norm(v_start) + np.linalg.norm(v_end))
    leg = CubicHermiteSpline([0.0, duration], np.stack([start, end]), np.stack([v_start, v_end]))
    # Acceleration of a cubic is linear in time, so its norm peaks at an end of the leg.
    acceleration = leg(np.array([0.0, duration]), 2)
    if np.linalg.norm(acceleration, axis=1).max() > kind.max_acceleration_mps2:
        return False, duration
    t = np.linspace(0.0, duration, max(32, int(duration / 2.0)))
    speed = np.linalg.norm(leg(t, 1), axis=1)
    if speed.min() < kind.speed_min_mps or speed.max() > kind.speed_max_mps:
        return False, duration
    points = leg(t)
    inside_band = (points[:, 2] >= kind.altitude_min_m) & (points[:, 2] <= kind.altitude_max_m)
    return bool(box.contains(points).all() and inside_band.all()), duration


def _next_waypoint(rng: np.random.Generator, previous: np.ndarray, cfg: ConstantJerk, box: CoverageBox,
                   kind: Aircraft) -> np.ndarray:
    bearing = rng.uniform(0.0, 2.0 * np.pi)
    distance = rng.uniform(cfg.min_leg_m, cfg.max_leg_m)
    return np.array([previous[0] + distance * np.sin(bearing), previous[1] + distance * np.cos(bearing),
                     rng.uniform(kind.altitude_min_m, kind.altitude_max_m)])


def _velocity_towards(rng: np.random.Generator, start: np.ndarray, target: np.ndarray, kind: Aircraft) -> np.ndarray:
    direction = (target - start) / np.linalg.norm(target - start)
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


def _turn_sequence(rng: np.random.Generator, speed: float, length: float, kind: Aircraft, cfg: RandomTurns,
                   step_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Start times and turn rates (rad/s) of constant-rate segments covering the route length.

    Durations are whole sampling steps so each sample falls inside one segment.
    """
    max_rate = min(np.radians(kind.max_turn_rate_dps), kind.max_acceleration_mps2 / speed)
    total = length / speed
    starts, rates, elapsed = [], [], 0.0
    while elapsed < total:
        starts.append(elapsed)
        rates.append(rng.uniform(-max_rate, max_rate))
        elapsed += max(step_s, round(rng.uniform(cfg.turn_duration_min_s, cfg.turn_duration_max_s) / step_s) * step_s)
    return np.array(starts), np.array(rates)


def _coordinated_turns(origin: np.ndarray, heading: float, speed: float, starts: np.ndarray,
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
    east = np.where(straight, speed * elapsed * np.sin(heading),
                    speed / safe_rate * (np.cos(heading) - np.cos(heading + turned)))
    north = np.where(straight, speed * elapsed * np.cos(heading),
                     speed / safe_rate * (np.sin(heading + turned) - np.sin(heading)))
    return east, north


def plan_random_turns(rng: np.random.Generator, kind: Aircraft, cfg: RandomTurns, box: CoverageBox,
                      step_s: float, attempts: int = 1000) -> PlannedRoute:
    """Constant speed and altitude through random turns, until the length is flown or coverage is left."""
    for _ in range(attempts):
        origin = _random_point(rng, box, kind)
        heading = rng.uniform(0.0, 2.0 * np.pi)
        speed = rng.uniform(kind.speed_min_mps, kind.speed_max_mps)
        length = rng.uniform(cfg.length_min_m, cfg.length_max_m)
        starts, rates = _turn_sequence(rng, speed, length, kind, cfg, step_s)
        position = _coordinated_turns(origin, heading, speed, starts, rates)
        t = np.arange(0.0, length / speed + step_s, step_s)
        t = t[t <= length / speed]
        inside = box.contains(position(t))
        samples_inside = len(t) if inside.all() else int(np.argmax(~inside))
        end = t[samples_inside - 1] if samples_inside else 0.0
        if end * speed >= cfg.min_length_m:
            return PlannedRoute(duration_s=float(end), position=position)
    raise RouteGenerationError(f"random_turns: no {kind.name} route of at least "
                               f"routes.random_turns.min_length_m = {cfg.min_length_m} m in {attempts} attempts")


def sample_route(planned: PlannedRoute, start_time_unix_s: float, step_s: float, radar: Radar) -> dict[str, np.ndarray]:
    """Truth columns of one route at `step_s` spacing: time, ECEF position and velocity, geodetic."""
    t = np.arange(0.0, planned.duration_s + 1e-9, step_s)
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


def _draw_aircraft(rng: np.random.Generator, split: Split, aircraft: dict[str, Aircraft]) -> Aircraft:
    names = sorted(split.aircraft_mix)
    weights = np.array([split.aircraft_mix[name] for name in names])
    return aircraft[names[int(rng.choice(len(names), p=weights / weights.sum()))]]


def generate_route(params: Params, split: Split, strategy: str, index: int, route_id: int) -> pa.Table:
    """One route of a split. Its random stream depends only on (split seed, strategy, index)."""
    rng = np.random.default_rng([split.seed, STRATEGIES.index(strategy), index])
    routes, radar = params.routes, params.radar
    kind = _draw_aircraft(rng, split, dict(params.aircraft))
    start = routes.start_time_unix_s + rng.uniform(0.0, routes.start_spread_s)
    box = CoverageBox.of(radar)
    if strategy == "constant_jerk":
        planned = plan_constant_jerk(rng, kind, routes.constant_jerk, box)
    else:
        planned = plan_random_turns(rng, kind, routes.random_turns, box, routes.sample_interval_s)
    columns = sample_route(planned, start, routes.sample_interval_s, radar)
    n = len(columns["time_unix_s"])
    columns = {"route_id": np.full(n, route_id, np.int32), "strategy": [strategy] * n,
               "aircraft_type": [kind.name] * n, **columns}
    return pa.Table.from_pydict(columns, schema=ROUTE_SCHEMA)


def generate_split(params: Params, split: Split, progress: Callable[[int, int], None] | None = None) -> pa.Table:
    """All routes of a split: route ids number the constant-jerk routes first, then random turns."""
    jobs = [(strategy, index) for strategy in STRATEGIES for index in range(split.counts[strategy])]
    tables = []
    for route_id, (strategy, index) in enumerate(jobs):
        tables.append(generate_route(params, split, strategy, index, route_id))
        if progress is not None:
            progress(route_id + 1, len(jobs))
    if not tables:
        return ROUTE_SCHEMA.empty_table()
    return pa.concat_tables(tables)

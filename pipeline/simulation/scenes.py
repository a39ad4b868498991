"""Multi-target scenes (issue 16): many aircraft at once past the same radar, with the situations
where association is hard placed on purpose in every scene.

Scene k lasts `scenes.duration_s` from `routes.start_time_utc` + k x duration (the scenes follow one
another, like a recording cut in pieces). Its layout draws from one stream seeded by
(scenes.seed, k); its aircraft (ids 0, 1, ... in this order, the plots' `target_id`) are:

- a **crossing**: two aircraft of one type at one altitude, straight and level, whose routes
  cross at a shallow angle (`crossing_angle_deg`) at a point `situation_range_m` from the radar,
  both there at the same instant, 30-70 % into the scene;
- a **formation** of `formation_size` aircraft of one type, line abreast `formation_spacing_m`
  apart at one altitude and speed, flying straight from the scene's start until, 30-60 % into
  it, at a split point `situation_range_m` from the radar, neighbours turn `formation_split_deg`
  apart (each at its type's fastest turn, the right half to the right, the left half to the
  left, the middle one of an odd number straight on) and fly on straight;
- one aircraft **entering** coverage, flying in across its edge 10-50 % into the scene, and one
  **leaving**, flying out across it 50-90 % into the scene (or sooner, starting no nearer than
  half the edge's range). The edge is the nearer of `radar.range_max_m` and the radar horizon at
  the aircraft's altitude (`coverage_edge_m`); both fly within 30 deg of the radial;
- the **others**, drawn with the route strategies of `pipeline.simulation.routes` (weights
  `scenes.strategies`), each appearing at a uniform time in the first `start_spread` of the
  scene where its planner starts it, and redrawn while it would appear nearer than
  `separation_m` (horizontally) to an aircraft flying then; they fly until their route or the
  scene ends. So lifetimes overlap and aircraft keep appearing.

Types come from `scenes.aircraft_mix`, one per situation. The situation points are capped at
90 % of the coverage edge of the aircraft's altitude, so a low light aircraft's crossing is not
below the horizon (`check_scenes`).

The radar is the single-target splits' (`pipeline.simulation.simulate`): each aircraft's plots come from
`simulate.aircraft_plots`, its detections and noise drawing from streams seeded by
(simulate.seed, scenes.seed, k, 1, aircraft id, stream); the scene's clutter from
`simulate.false_plots` over the whole scene, seeded by (simulate.seed, scenes.seed, k, 0).
Each aircraft gets its own plot at every detection, however close another is: the simulator
does not merge plots within one resolution cell (hence the formation spacing's lower bound,
`params.formation_resolution_m`).

Trigonometry and lengths use `pipeline.geometry.strict_math`, as `pipeline.simulation.routes` does and for its reason:
the same bits on every processor (issue 27).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pyarrow as pa

from pipeline.geometry import geodesy
from pipeline.geometry import strict_math as sm
from pipeline.params import STRATEGIES, Aircraft, ParamError, Params, Radar
from pipeline.simulation import routes, simulate
from pipeline.simulation.routes import CoverageBox, PlannedRoute, RouteGenerationError

SCENE_ROUTE_SCHEMA = pa.schema([pa.field("scene_id", pa.int32(), nullable=False), *routes.ROUTE_SCHEMA])
CROSSING, FORMATION, ENTERING, LEAVING = "crossing", "formation", "entering", "leaving"  # an aircraft's role
CROSSING_TIME = (0.3, 0.7)   # shares of the scene: when the crossing pair meets ...
SPLIT_TIME = (0.3, 0.6)      # ... when the formation splits ...
ENTER_TIME = (0.1, 0.5)      # ... when the entering aircraft crosses the coverage edge ...
LEAVE_TIME = (0.5, 0.9)      # ... and when the leaving one does
EDGE_MARGIN = 0.9            # situation points lie within this share of the coverage edge
OFF_RADIAL_RAD = np.radians(30.0)  # the entering and leaving aircraft's heading off the radial, at most
EDGE_STEP_M = 100.0


@dataclass(frozen=True)
class SceneAircraft:
    """One aircraft of a scene: its route (local east, north, altitude as a function of the time
    since it appeared), when it appears (s after the scene's start), its type, and its role (a
    situation, or the route strategy it flies)."""

    planned: PlannedRoute
    start_s: float
    kind: Aircraft
    role: str


def coverage_edge_m(altitude_m: float, radar: Radar) -> float:
    """The farthest slant range (m, to EDGE_STEP_M) at which an aircraft at `altitude_m` is in
    coverage: the instrumented range or the radar horizon, whichever is nearer."""
    ranges = np.arange(0.0, radar.range_max_m + EDGE_STEP_M / 2.0, EDGE_STEP_M)
    if radar.horizon:
        ranges = ranges[~geodesy.below_horizon(ranges, altitude_m, radar)]
    return float(ranges.max())


def check_scenes(params: Params) -> None:
    """What pipeline.params cannot check without the radar's geometry: every type of the mix must see its
    situations, so the near end of `situation_range_m` must lie within EDGE_MARGIN of the coverage
    edge at the type's lowest altitude. Raises ParamError naming the key."""
    scenes = params.scenes
    for name, weight in scenes.aircraft_mix.items():
        kind = params.aircraft[name]
        edge = EDGE_MARGIN * coverage_edge_m(kind.altitude_min_m, params.radar)
        if weight > 0.0 and scenes.situation_range_min_m > edge:
            raise ParamError(f"scenes.situation_range_m = {[scenes.situation_range_min_m, scenes.situation_range_max_m]}: "
                             f"starts beyond the coverage of aircraft.{name} at its lowest altitude "
                             f"{kind.altitude_min_m:.0f} m ({edge:.0f} m, {EDGE_MARGIN:.0%} of the radar horizon there)")


def _unit(heading: float) -> np.ndarray:
    """East and north of a heading (rad from north, clockwise)."""
    return np.array(sm.sin_cos(heading))


def _straight(east_north: np.ndarray, altitude: float, heading: float, speed: float, duration_s: float
              ) -> PlannedRoute:
    """Straight and level flight from (east, north) m at `altitude` m."""
    return PlannedRoute(duration_s, routes.coordinated_turns(np.append(east_north, altitude), heading, speed,
                                                             np.zeros(1), np.zeros(1)))


def _situation_point(rng: np.random.Generator, params: Params, altitude: float) -> np.ndarray:
    """(east, north) m of a situation: `situation_range_m` from the radar in a random direction, at
    most EDGE_MARGIN of the coverage edge at `altitude`."""
    scenes = params.scenes
    far = min(scenes.situation_range_max_m, EDGE_MARGIN * coverage_edge_m(altitude, params.radar))
    return rng.uniform(scenes.situation_range_min_m, far) * _unit(rng.uniform(0.0, 2.0 * np.pi))


def _altitude_and_speed(rng: np.random.Generator, kind: Aircraft) -> tuple[float, float]:
    return rng.uniform(kind.altitude_min_m, kind.altitude_max_m), rng.uniform(kind.speed_min_mps, kind.speed_max_mps)


def plan_crossing(rng: np.random.Generator, params: Params) -> list[SceneAircraft]:
    """Two aircraft of one type at one altitude, meeting at a situation point at a shallow angle."""
    scenes = params.scenes
    kind = routes.draw_aircraft(rng, scenes.aircraft_mix, params.aircraft)
    altitude, _ = _altitude_and_speed(rng, kind)
    point = _situation_point(rng, params, altitude)
    meet = rng.uniform(*CROSSING_TIME) * scenes.duration_s
    heading = rng.uniform(0.0, 2.0 * np.pi)
    angle = np.radians(rng.uniform(scenes.crossing_angle_min_deg, scenes.crossing_angle_max_deg)) * rng.choice([-1, 1])
    pair = []
    for course in (heading, heading + angle):
        speed = rng.uniform(kind.speed_min_mps, kind.speed_max_mps)
        pair.append(SceneAircraft(_straight(point - speed * meet * _unit(course), altitude, course, speed,
                                            scenes.duration_s), 0.0, kind, CROSSING))
    return pair


def plan_formation(rng: np.random.Generator, params: Params) -> list[SceneAircraft]:
    """A formation line abreast that splits at a situation point; its start is redrawn until it too
    lies within EDGE_MARGIN of the coverage edge, so the radar sees it fly together."""
    scenes, radar = params.scenes, params.radar
    kind = routes.draw_aircraft(rng, scenes.aircraft_mix, params.aircraft)
    size = int(rng.integers(scenes.formation_size_min, scenes.formation_size_max + 1))
    spacing = rng.uniform(scenes.formation_spacing_min_m, scenes.formation_spacing_max_m)
    split = rng.uniform(*SPLIT_TIME) * scenes.duration_s
    for _ in range(scenes.attempts):
        altitude, speed = _altitude_and_speed(rng, kind)
        heading = rng.uniform(0.0, 2.0 * np.pi)
        start = _situation_point(rng, params, altitude) - speed * split * _unit(heading)
        if sm.norm(start) <= EDGE_MARGIN * coverage_edge_m(altitude, radar):
            break
    else:
        raise RouteGenerationError(f"scenes: no {kind.name} formation starting inside coverage in scenes.attempts = "
                                   f"{scenes.attempts} draws; lower scenes.duration_s or scenes.situation_range_m")
    sin_heading, cos_heading = sm.sin_cos(heading)
    right = np.array([cos_heading, -sin_heading])  # the unit vector to the formation's right
    rate = routes.max_turn_rate(kind, speed, kind.max_acceleration_mps2)
    members = []
    for place in np.arange(size) - (size - 1) / 2.0:  # positions across the line, in spacings
        turn = np.radians(place * scenes.formation_split_deg)
        origin = np.append(start + place * spacing * right, altitude)
        if place == 0.0:
            planned = _straight(origin[:2], altitude, heading, speed, scenes.duration_s)
        else:
            planned = PlannedRoute(scenes.duration_s, routes.coordinated_turns(
                origin, heading, speed, np.array([0.0, split, split + abs(turn) / rate]),
                np.array([0.0, np.sign(turn) * rate, 0.0])))
        members.append(SceneAircraft(planned, 0.0, kind, FORMATION))
    return members


def plan_edge_crossing(rng: np.random.Generator, params: Params, entering: bool) -> SceneAircraft:
    """An aircraft flying into coverage across its edge (ENTER_TIME into the scene), or out of it
    (LEAVE_TIME, or sooner: it starts no nearer than half the edge's range)."""
    scenes = params.scenes
    kind = routes.draw_aircraft(rng, scenes.aircraft_mix, params.aircraft)
    altitude, speed = _altitude_and_speed(rng, kind)
    edge = coverage_edge_m(altitude, params.radar)
    bearing = rng.uniform(0.0, 2.0 * np.pi)  # from the radar to the aircraft
    off_radial = rng.uniform(-OFF_RADIAL_RAD, OFF_RADIAL_RAD)
    if entering:
        crossing = rng.uniform(*ENTER_TIME) * scenes.duration_s
        start, heading = edge + speed * crossing, bearing + np.pi + off_radial
    else:
        crossing = min(rng.uniform(*LEAVE_TIME) * scenes.duration_s, edge / (2.0 * speed))
        start, heading = edge - speed * crossing, bearing + off_radial
    return SceneAircraft(_straight(start * _unit(bearing), altitude, heading, speed, scenes.duration_s), 0.0, kind,
                         ENTERING if entering else LEAVING)


def _position_at(aircraft: SceneAircraft, scene_time_s: float) -> np.ndarray | None:
    """Local (east, north, altitude) m of an aircraft at a time of the scene, None when it is not flying."""
    elapsed = scene_time_s - aircraft.start_s
    if elapsed < 0.0 or elapsed > aircraft.planned.duration_s:
        return None
    return aircraft.planned.position(np.array([elapsed]))[0]


def _clear(candidate: SceneAircraft, placed: list[SceneAircraft], separation_m: float) -> bool:
    """Whether the candidate appears at least `separation_m` (horizontally) from every aircraft flying then."""
    here = candidate.planned.position(np.zeros(1))[0, :2]
    others = [_position_at(other, candidate.start_s) for other in placed]
    return all(sm.norm(there[:2] - here) >= separation_m for there in others if there is not None)


def plan_others(rng: np.random.Generator, params: Params, count: int, placed: list[SceneAircraft]
                ) -> list[SceneAircraft]:
    """`count` aircraft flying the route strategies, each appearing in the first `start_spread` of
    the scene at least `separation_m` from the aircraft of `placed` and from each other."""
    scenes = params.scenes
    box = CoverageBox.of(params.radar)
    names = [name for name in STRATEGIES if name in scenes.strategies]
    weights = np.array([scenes.strategies[name] for name in names])
    others: list[SceneAircraft] = []
    for number in range(count):
        for _ in range(scenes.attempts):
            strategy = names[int(rng.choice(len(names), p=weights / weights.sum()))]
            kind = routes.draw_aircraft(rng, scenes.aircraft_mix, params.aircraft)
            appears = rng.uniform(0.0, scenes.start_spread * scenes.duration_s)
            planned = routes.plan_route(rng, strategy, kind, params.routes, box)
            candidate = SceneAircraft(PlannedRoute(min(planned.duration_s, scenes.duration_s - appears),
                                                   planned.position), appears, kind, strategy)
            if _clear(candidate, placed + others, scenes.separation_m):
                others.append(candidate)
                break
        else:
            raise RouteGenerationError(f"scenes: aircraft {len(placed) + number} found no place "
                                       f"scenes.separation_m = {scenes.separation_m:.0f} m from the others in "
                                       f"scenes.attempts = {scenes.attempts} draws; lower scenes.aircraft")
    return others


def plan_scene(params: Params, scene_id: int) -> list[SceneAircraft]:
    """The aircraft of scene `scene_id` in id order: the crossing pair, the formation, the aircraft
    entering and leaving coverage, the others. Its stream depends only on (scenes.seed, scene_id)."""
    rng = np.random.default_rng([params.scenes.seed, scene_id])
    placed = [*plan_crossing(rng, params), *plan_formation(rng, params),
              plan_edge_crossing(rng, params, entering=True), plan_edge_crossing(rng, params, entering=False)]
    return placed + plan_others(rng, params, params.scenes.aircraft - len(placed), placed)


def scene_start_unix_s(params: Params, scene_id: int) -> float:
    return params.routes.start_time_unix_s + scene_id * params.scenes.duration_s


def scene_routes(params: Params, scene_id: int, aircraft: list[SceneAircraft]) -> pa.Table:
    """The truth of a scene's aircraft (SCENE_ROUTE_SCHEMA), sampled as the routes stage samples
    routes; `route_id` is the aircraft's id (its position in `aircraft`), `strategy` its role."""
    start = scene_start_unix_s(params, scene_id)
    tables = []
    for aircraft_id, one in enumerate(aircraft):
        columns = routes.sample_route(one.planned, start + one.start_s, params.routes.sample_interval_s, params.radar)
        n = len(columns["time_unix_s"])
        tables.append(pa.Table.from_pydict({
            "scene_id": np.full(n, scene_id, np.int32), "route_id": np.full(n, aircraft_id, np.int32),
            "strategy": [one.role] * n, "aircraft_type": [one.kind.name] * n, **columns}, schema=SCENE_ROUTE_SCHEMA))
    return pa.concat_tables(tables)


def simulate_scene(params: Params, scene_id: int, table: pa.Table
                   ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Plots (unsorted, without plot ids; scenario_id = scene id, target_id = aircraft id) and
    per-scan truth of one scene's routes (`scene_routes`), with the clutter of the whole scene."""
    seeds = [params.simulate_seed, params.scenes.seed, scene_id]
    plot_parts, truth_parts = [], []
    for route in simulate.routes_by_id(table):
        aircraft_id = int(route["route_id"][0])
        detection_rng, noise_rng = (np.random.default_rng([*seeds, 1, aircraft_id, stream]) for stream in range(2))
        plots, truth = simulate.aircraft_plots(params, route, detection_rng, noise_rng, scene_id, aircraft_id)
        plot_parts.append(plots)
        truth_parts.append(truth)
    start = scene_start_unix_s(params, scene_id)
    plot_parts.append(simulate.false_plots(params, np.random.default_rng([*seeds, 0]), start,
                                           start + params.scenes.duration_s, scene_id))
    return ({name: np.concatenate([part[name] for part in plot_parts]) for name in plot_parts[0]},
            {name: np.concatenate([part[name] for part in truth_parts]) for name in truth_parts[0]})


def generate_scenes(params: Params, progress: Callable[[int, int], None] | None = None
                    ) -> tuple[pa.Table, pa.Table, pa.Table]:
    """Every scene of params: routes (SCENE_ROUTE_SCHEMA), plots (simulate.PLOT_SCHEMA, time order
    within each scene, plot ids numbered in that order) and truth (simulate.TRUTH_SCHEMA)."""
    check_scenes(params)
    route_tables, plot_parts, truth_parts = [], [], []
    for scene_id in range(params.scenes.count):
        table = scene_routes(params, scene_id, plan_scene(params, scene_id))
        plots, truth = simulate_scene(params, scene_id, table)
        route_tables.append(table)
        plot_parts.append(plots)
        truth_parts.append(truth)
        if progress is not None:
            progress(scene_id + 1, params.scenes.count)
    return (pa.concat_tables(route_tables), *simulate.tables(plot_parts, truth_parts))

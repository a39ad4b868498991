"""The simulated world's sections: the radar, the aircraft types, the route strategies and splits, the
multi-target scenes and the training windows (params.yaml `radar`, `aircraft`, `routes`, `scenes`, `windows`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Mapping

from pipeline.params.declare import ParamError, Section, get, given, knob, positive, upper, weights_of

# New strategies go at the end: a route's random stream is seeded by its strategy's index here.
STRATEGIES = ("constant_jerk", "random_turns", "sustained_turns", "climb_dive")
SITUATION_AIRCRAFT = 4  # a scene's crossing pair, its aircraft entering and its aircraft leaving coverage


@dataclass(frozen=True)
class Radar(Section):
    """The simulated radar (thesis: 10 RPM, R_max = 400 km); `fusion.radars` changes some of its keys."""

    sac: int = knob("ASTERIX system area code (I048/010, I034/010)", 0, 255)
    sic: int = knob("ASTERIX system identification code; radar id = sac * 256 + sic", 0, 255)
    latitude_deg: float = knob("site latitude (ours: southern Finland, where the thesis was written)", -90.0, 90.0)
    longitude_deg: float = knob("site longitude", -180.0, 180.0)
    height_m: float = knob("antenna height above the WGS-84 ellipsoid", -500.0, 10000.0)
    rotation_rpm: float = positive("antenna rotation (thesis: 10 RPM, a 6 s scan)")
    range_max_m: float = positive("instrumented range (thesis: R_max = 400 km)")
    range_min_m: float = knob("blind range: no plots inside it (ours); below range_max_m", 0.0)
    altitude_max_m: float = positive("coverage height (thesis: maximum altitude coverage)")
    sigma_range_m: float = knob("Gaussian range error (ours: mean raw plot error of the thesis's order, 218.8 m)", 0.0)
    sigma_azimuth_deg: float = knob("Gaussian azimuth error", 0.0)
    sigma_altitude_m: float = knob("Gaussian altitude error", 0.0)
    reference_snr_db: float = knob("mean SNR of a reference_rcs_m2 target at reference_range_m")
    reference_range_m: float = positive("range of the reference SNR")
    reference_rcs_m2: float = positive("RCS of the reference SNR")
    false_alarm_probability: float = knob("per resolution cell; sets the detection threshold", 0.0, 1.0, open_low=True)
    false_plots_per_scan: float = knob("Poisson mean (~10 false plots per target plot, as the thesis's data)", 0.0)
    horizon: bool = knob("targets below the radar horizon are not detected")
    effective_earth_radius_factor: float = positive("refraction: 4/3 is the standard earth")
    max_elevation_deg: float = knob("cone of silence (ours): nothing detected above this elevation", 0.0, 90.0,
                                    open_low=True)

    @property
    def radar_id(self) -> int:
        """SAC and SIC packed as ASTERIX data source identifiers usually are."""
        return self.sac * 256 + self.sic

    @property
    def scan_period_s(self) -> float:
        return 60.0 / self.rotation_rpm

    def check(self, path: str, context: Mapping[str, Any]) -> Radar:
        if self.range_min_m >= self.range_max_m:
            raise ParamError(f"{path}.range_min_m = {self.range_min_m}: must be below range_max_m = {self.range_max_m}")
        return self


@dataclass(frozen=True)
class Aircraft(Section):
    """An aircraft type (`aircraft.<name>`): the envelope every route of the type respects. Holding speeds
    are true airspeeds (ICAO Doc 8168's are indicated: about 1.3-1.7x faster true at 6-12 km)."""

    name: str = given()
    speed_min_mps: float = knob("[lower, upper] speed (the thesis's scaling assumes at most 400 m/s)", 0.0,
                                open_low=True, pair=True, why="speeds must be positive")
    speed_max_mps: float = upper("fastest speed")
    max_turn_rate_dps: float = positive("turn rate at most")
    max_acceleration_mps2: float = positive("acceleration at most; sustained turns keep v * omega below it")
    altitude_min_m: float = knob("[lower, upper] altitude, within radar.altitude_max_m", 0.0, pair=True)
    altitude_max_m: float = upper("highest altitude")
    rcs_front_m2: float = positive("aspect-dependent mean RCS: nose and tail ...")
    rcs_side_m2: float = positive("... to broadside")
    holding_speed_min_mps: float = knob("[lower, upper] speed of sustained turns (holding patterns, orbits; ours)",
                                        0.0, open_low=True, pair=True, why="speeds must be positive")
    holding_speed_max_mps: float = upper("fastest holding speed")
    max_vertical_rate_mps: float = positive("climbs and dives (climb_dive) at most this fast (ours)")

    def check(self, path: str, context: Mapping[str, Any]) -> Aircraft:
        if self.max_vertical_rate_mps ** 2 > self.speed_max_mps ** 2 - self.speed_min_mps ** 2:
            raise ParamError(f"{path}.max_vertical_rate_mps = {self.max_vertical_rate_mps}: a climb at that rate and "
                             f"the slowest speed {self.speed_min_mps} would exceed the top speed {self.speed_max_mps}")
        return self


@dataclass(frozen=True)
class ConstantJerk(Section):
    """`routes.constant_jerk`: waypoint routes flown with constant jerk between waypoints."""

    waypoints_min: int = knob("[lower, upper] waypoints per route (inclusive)", 2.0, pair=True)
    waypoints_max: int = upper("most waypoints")
    min_leg_m: float = positive("shortest waypoint-to-waypoint distance (ours); at most max_leg_m")
    max_leg_m: float = positive("longest waypoint-to-waypoint distance")
    attempts: int = knob("redraws of a waypoint before the route is restarted", 1)

    def check(self, path: str, context: Mapping[str, Any]) -> ConstantJerk:
        if self.min_leg_m > self.max_leg_m:
            raise ParamError(f"{path}.min_leg_m = {self.min_leg_m}: above max_leg_m = {self.max_leg_m}")
        return self


@dataclass(frozen=True)
class RandomTurns(Section):
    """`routes.random_turns`: straight legs and turns of random rate and duration (thesis: 300-500 km)."""

    length_min_m: float = knob("[lower, upper] route length (thesis: 300-500 km)", 0.0, pair=True)
    length_max_m: float = upper("longest route")
    turn_duration_min_s: float = knob("[lower, upper] duration of a turn", 0.0, open_low=True, pair=True,
                                      why="durations must be positive")
    turn_duration_max_s: float = upper("longest turn")
    min_length_m: float = knob("a route that leaves coverage sooner is redrawn (ours)", 0.0)


@dataclass(frozen=True)
class SustainedTurns(Section):
    """`routes.sustained_turns` (ours, issue 13): holding patterns and calibration orbits, constant speed and
    altitude."""

    holding_probability: float = knob("a holding pattern (racetrack), else an orbit of 360 deg turns", 0.0, 1.0)
    turn_rate_min_dps: float = positive("[lower, upper] turn rate drawn per route, capped by the type's turn rate and "
                                        "max_acceleration / speed (ICAO Doc 8168: 3 deg/s or 25 deg bank)", pair=True)
    turn_rate_max_dps: float = upper("fastest turn rate")
    turning_time_min_s: float = positive("[lower, upper] total time in turns, whole laps or orbits (at least one)",
                                         pair=True)
    turning_time_max_s: float = upper("longest time in turns")
    holding_leg_min_s: float = positive("[lower, upper] straight legs between a holding pattern's 180 deg turns "
                                        "(ICAO Doc 8168: 1 min up to 14000 ft, 1.5 min above)", pair=True)
    holding_leg_max_s: float = upper("longest holding leg")
    straight_min_s: float = knob("[lower, upper] the straight entry leg and, drawn again, the exit leg", 0.0, pair=True)
    straight_max_s: float = upper("longest entry or exit leg")
    attempts: int = knob("redraws of a route that leaves the coverage box", 1)


@dataclass(frozen=True)
class ClimbDive(Section):
    """`routes.climb_dive` (ours, issue 13): level flight alternating with climbs and dives, gentle turns."""

    length_min_m: float = positive("[lower, upper] route length", pair=True)
    length_max_m: float = upper("longest route")
    min_length_m: float = knob("a route that leaves coverage sooner is redrawn", 0.0)
    level_min_s: float = positive("[lower, upper] level flight before each climb or dive", pair=True)
    level_max_s: float = upper("longest level flight")
    altitude_change_min_m: float = positive("[lower, upper] change per climb or dive, inside the type's altitude band "
                                            "(the lower at most half of every type's band)", pair=True)
    altitude_change_max_m: float = upper("largest change")
    vertical_rate_min_fraction: float = positive("[lower, upper] vertical speed of a climb or dive, times "
                                                 "aircraft.<type>.max_vertical_rate_mps", high=1.0, pair=True)
    vertical_rate_max_fraction: float = upper("fastest share")
    vertical_acceleration_fraction: float = knob("times max_acceleration_mps2: the vertical acceleration that starts "
                                                 "and ends each climb or dive", 0.0, 1.0, open_low=True)
    turn_rate_dps: float = knob("gentle turns of a random rate up to this, either way (0: straight)", 0.0)
    turn_duration_min_s: float = positive("[lower, upper] duration of a gentle turn", pair=True)
    turn_duration_max_s: float = upper("longest gentle turn")
    attempts: int = knob("redraws of a route shorter than min_length_m", 1)

    def check(self, path: str, context: Mapping[str, Any]) -> ClimbDive:
        change = [self.altitude_change_min_m, self.altitude_change_max_m]
        for kind in context["aircraft"].values():
            if change[0] > (kind.altitude_max_m - kind.altitude_min_m) / 2.0:
                raise ParamError(f"{path}.altitude_change_m = {change}: the smallest change is above half the "
                                 f"altitude band of aircraft.{kind.name} ({kind.altitude_min_m}-{kind.altitude_max_m} "
                                 "m), so neither a climb nor a dive may fit")
        return self


@dataclass(frozen=True)
class Split(Section):
    """`routes.splits.<name>`: a split's routes per strategy (their share of it) and its own seed."""

    name: str = given()
    counts: Mapping[str, int] = knob("routes of the strategy in the split", 0, keys=STRATEGIES)
    seed: int = knob("the split's routes; every split has its own", 0)
    aircraft_mix: Mapping[str, float] = knob("aircraft type -> weight", 0.0, read=weights_of("aircraft",
                                                                                           "aircraft type"))


def _start_time(tree: Mapping[str, Any], key: str, path: str, context: Mapping[str, Any]) -> float:
    text = get(tree, key, path)
    try:
        moment = datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError as error:
        raise ParamError(f"{path}.{key} = {text!r}: not an ISO 8601 time ({error})") from None
    if moment.tzinfo is None:
        raise ParamError(f"{path}.{key} = {text!r}: give a time zone, e.g. a trailing Z for UTC")
    return moment.timestamp()


@dataclass(frozen=True)
class Routes(Section):
    """`routes`: the truth of every split, sampled every sample_interval_s, by four strategies."""

    sample_interval_s: float = positive("truth sampling (1 s or finer)")
    start_time_unix_s: float = knob("ISO 8601 time, with its zone: the first route's start", key="start_time_utc",
                                    read=_start_time)
    start_spread_s: float = knob("each route starts at a uniform offset in this span (some cross midnight)", 0.0)
    constant_jerk: ConstantJerk = knob("waypoint routes")
    random_turns: RandomTurns = knob("turns of random rate")
    sustained_turns: SustainedTurns = knob("holding patterns and orbits")
    climb_dive: ClimbDive = knob("climbs and dives")
    splits: tuple[Split, ...] = knob("the splits by name (train, test, calibration)")

    def split(self, name: str) -> Split:
        for split in self.splits:
            if split.name == name:
                return split
        raise ParamError(f"routes.splits.{name}: no such split (have {[s.name for s in self.splits]})")

    def check(self, path: str, context: Mapping[str, Any]) -> Routes:
        seeds = [split.seed for split in self.splits]
        if len(set(seeds)) != len(seeds):
            raise ParamError(f"{path}.splits seeds = {seeds}: every split needs its own seed so no route repeats")
        ceiling = context["radar"].altitude_max_m
        for kind in context["aircraft"].values():
            if kind.altitude_max_m > ceiling:
                raise ParamError(f"aircraft.{kind.name}.altitude_m upper bound {kind.altitude_max_m} is above "
                                 f"radar.altitude_max_m = {ceiling}: routes must stay in coverage")
        return self


def _split_name(tree: Mapping[str, Any], key: str, path: str, context: Mapping[str, Any]) -> str:
    name = get(tree, key, path)
    if not isinstance(name, str) or not name:
        raise ParamError(f"{path}.{key} = {name!r}: must be a non-empty string")
    if name not in [split.name for split in context["routes"].splits]:
        raise ParamError(f"{path}.{key} = {name!r}: no such split in routes.splits")
    return name


def split_knob(doc: str = "trained on this split's target plots less the windows stage's hold-out segments") -> Any:
    """A section's `split`: the name of one of routes.splits."""
    return knob(doc, read=_split_name)


@dataclass(frozen=True)
class Scenes(Section):
    """`scenes` (ours, issue 16): `count` scenes of `aircraft` aircraft each over `duration_s`, every one with a
    crossing, a formation and aircraft entering and leaving coverage (`pipeline.simulation.scenes`)."""

    count: int = knob("scenes", 1)
    aircraft: int = knob("aircraft per scene, the placed situations' included (a crossing pair, a formation, one "
                         "entering and one leaving coverage); at most what fits the coverage separation_m apart", 1)
    duration_s: float = positive("length of a scene")
    seed: int = knob("scene layouts; the radar's draws come from simulate.seed and this", 0)
    aircraft_mix: Mapping[str, float] = knob("aircraft type -> weight", 0.0, read=weights_of("aircraft",
                                                                                           "aircraft type"))
    strategies: Mapping[str, float] = knob("route strategy -> weight, for the aircraft not placed in a situation",
                                           0.0, read=weights_of(STRATEGIES, "route strategy"))
    start_spread: float = knob("those start at uniform times in the first this share of the scene", 0.0, 1.0,
                               open_high=True)
    separation_m: float = positive("no aircraft appears nearer than this to another (a formation's members apart)")
    situation_range_min_m: float = positive("[lower, upper] the crossing point and the formation's split point lie "
                                            "this far from the radar, within [radar.range_min_m, range_max_m]",
                                            pair=True)
    situation_range_max_m: float = upper("farthest situation")
    crossing_angle_min_deg: float = positive("[lower, upper] two routes crossing at one altitude", high=90.0, pair=True)
    crossing_angle_max_deg: float = upper("widest crossing")
    formation_size_min: int = knob("[lower, upper] aircraft in the formation, line abreast", 2.0, pair=True)
    formation_size_max: int = upper("largest formation")
    formation_spacing_min_m: float = positive("[lower, upper] formation spacing, above the radar's resolution at "
                                              "situation_range_m's far end", pair=True)
    formation_spacing_max_m: float = upper("widest spacing")
    formation_split_deg: float = knob("neighbours in the formation turn this far apart when it splits", 0.0, 180.0,
                                      open_low=True, open_high=True)
    attempts: int = knob("redraws of an aircraft that appears nearer than separation_m to another", 1)

    def check(self, path: str, context: Mapping[str, Any]) -> Scenes:
        """A scene holds its situations (SITUATION_AIRCRAFT and the largest formation) and no more aircraft than
        fit the coverage box (side sqrt(2) R_max) separation_m apart, packed hexagonally (sqrt(3)/2
        separation_m^2 each); the closest formation is resolvable where it is put (formation_resolution_m)."""
        radar, situation = context["radar"], [self.situation_range_min_m, self.situation_range_max_m]
        if situation[1] > radar.range_max_m:
            raise ParamError(f"{path}.situation_range_m = {situation}: must lie in (0, {radar.range_max_m}]")
        if situation[0] < radar.range_min_m:
            raise ParamError(f"{path}.situation_range_m = {situation}: starts inside the radar's blind range "
                             f"radar.range_min_m = {radar.range_min_m}")
        needed = SITUATION_AIRCRAFT + self.formation_size_max
        if self.aircraft < needed:
            raise ParamError(f"{path}.aircraft = {self.aircraft}: a scene needs at least {needed} (a crossing pair, a "
                             f"formation of up to formation_size = {self.formation_size_max}, one aircraft entering "
                             "and one leaving coverage)")
        capacity = int(2.0 * radar.range_max_m ** 2 / (math.sqrt(3.0) / 2.0 * self.separation_m ** 2))
        if self.aircraft > capacity:
            raise ParamError(f"{path}.aircraft = {self.aircraft}: more than the {capacity} that fit the coverage box "
                             f"(side sqrt(2) x radar.range_max_m) {self.separation_m:.0f} m apart "
                             "(scenes.separation_m)")
        resolution = formation_resolution_m(radar, self.situation_range_max_m)
        if self.formation_spacing_min_m <= resolution:
            spacing = [self.formation_spacing_min_m, self.formation_spacing_max_m]
            raise ParamError(f"{path}.formation_spacing_m = {spacing}: the closest formation, {spacing[0]:.0f} m "
                             f"apart, is within the radar's resolution, {resolution:.0f} m at "
                             f"{self.situation_range_max_m:.0f} m (the far end of scenes.situation_range_m)")
        return self


def formation_resolution_m(radar: Radar, range_m: float) -> float:
    """A proxy of the radar's resolution at `range_m`: the larger of its range error and its
    cross-range error (azimuth error times range), one sigma each. Two aircraft nearer than that
    are hard to tell apart from their plots (the simulator gives each its own plot all the same:
    it does not merge plots in one resolution cell)."""
    return max(radar.sigma_range_m, range_m * math.radians(radar.sigma_azimuth_deg))


@dataclass(frozen=True)
class Windows(Section):
    """`windows`: the networks' training material (thesis 4.2.3-4.2.4) and its scaling."""

    segment_gap_s: float = positive("plots further apart than this start a new segment")
    holdout_fraction: float = knob("share of training segments kept for separate model evaluation", 0.0, 1.0)
    seed: int = knob("hold-out choice and balancing draws", 0)
    filter_length: int = knob("plots per filter window", 2)
    predictor_inputs: int = knob("states in; a window spans one more (targets: the next states)", 2)
    autoencoder_length: int = knob("plots per autoencoder window", 2)
    calibration_max_delay_s: float = positive("5th plot of a calibration window: less than this after the 4th ...")
    calibration_max_distance_m: float = positive("... and within this distance of it")
    balance_bins: int = knob("linearity histogram bins", 2)
    balance_high_bins: int = knob("the last bins, drawn down to the count of all the others; below balance_bins", 1)
    frame: str = knob("radial (ours: cross-range, down-range, up at the window's first plot, the same at any site), "
                      "enu (east-north-up there) or ecef (the thesis)", choices=("ecef", "enu", "radial"))
    centre_range: bool = knob("the thesis is ambiguous; false: R is only divided by range_scale_m")
    dt_max_s: float = positive("scale: dT_max")
    position_max_diff_m: float = positive("scale: X/Y/Z maxDiff (aircraft at most 400 m/s)")
    range_scale_m: float = positive("scale: R_max")

    def check(self, path: str, context: Mapping[str, Any]) -> Windows:
        if self.balance_high_bins >= self.balance_bins:
            raise ParamError(f"{path}.balance_high_bins = {self.balance_high_bins}: must be below "
                             f"balance_bins = {self.balance_bins}")
        return self

"""Load `params.yaml` into typed, validated objects.

Every stage reads its knobs through here so that a bad value stops the stage before it
writes anything, with a message naming the key and the value (``radar.latitude_deg =
95.0: must be in [-90, 90]``) instead of a traceback deep inside the simulation.
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass, fields
from datetime import datetime
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import yaml

# New strategies go at the end: a route's random stream is seeded by its strategy's index here.
STRATEGIES = ("constant_jerk", "random_turns", "sustained_turns", "climb_dive")
MAX_CONFIRM_N = 52  # an M-of-N track's last confirm_n opportunities are the bits of its weight (a double's 53)


class ParamError(ValueError):
    """A value in params.yaml is missing or invalid; the message names the key."""


@dataclass(frozen=True)
class Radar:
    sac: int
    sic: int
    latitude_deg: float
    longitude_deg: float
    height_m: float
    rotation_rpm: float
    range_max_m: float
    range_min_m: float
    altitude_max_m: float
    sigma_range_m: float
    sigma_azimuth_deg: float
    sigma_altitude_m: float
    reference_snr_db: float
    reference_range_m: float
    reference_rcs_m2: float
    false_alarm_probability: float
    false_plots_per_scan: float
    horizon: bool
    effective_earth_radius_factor: float
    max_elevation_deg: float

    @property
    def radar_id(self) -> int:
        """SAC and SIC packed as ASTERIX data source identifiers usually are."""
        return self.sac * 256 + self.sic

    @property
    def scan_period_s(self) -> float:
        return 60.0 / self.rotation_rpm


@dataclass(frozen=True)
class Aircraft:
    name: str
    speed_min_mps: float
    speed_max_mps: float
    max_turn_rate_dps: float
    max_acceleration_mps2: float
    altitude_min_m: float
    altitude_max_m: float
    rcs_front_m2: float
    rcs_side_m2: float
    holding_speed_min_mps: float   # sustained turns (holding patterns, orbits) are flown at these speeds
    holding_speed_max_mps: float
    max_vertical_rate_mps: float   # climbs and dives (climb_dive) at most this fast


@dataclass(frozen=True)
class ConstantJerk:
    waypoints_min: int
    waypoints_max: int
    min_leg_m: float
    max_leg_m: float
    attempts: int


@dataclass(frozen=True)
class RandomTurns:
    length_min_m: float
    length_max_m: float
    turn_duration_min_s: float
    turn_duration_max_s: float
    min_length_m: float


@dataclass(frozen=True)
class SustainedTurns:
    holding_probability: float     # a holding pattern (racetrack), else a calibration orbit (360 deg turns)
    turn_rate_min_dps: float
    turn_rate_max_dps: float
    turning_time_min_s: float      # total time in turns, whole laps or orbits
    turning_time_max_s: float
    holding_leg_min_s: float       # the straight legs between a holding pattern's 180 deg turns
    holding_leg_max_s: float
    straight_min_s: float          # the entry and the exit leg
    straight_max_s: float
    attempts: int


@dataclass(frozen=True)
class ClimbDive:
    length_min_m: float
    length_max_m: float
    min_length_m: float
    level_min_s: float             # level flight before each climb or dive
    level_max_s: float
    altitude_change_min_m: float
    altitude_change_max_m: float
    vertical_rate_min_fraction: float   # of the type's max_vertical_rate_mps
    vertical_rate_max_fraction: float
    vertical_acceleration_fraction: float  # of the type's max_acceleration_mps2
    turn_rate_dps: float           # the gentle turns: at most this rate, either way
    turn_duration_min_s: float
    turn_duration_max_s: float
    attempts: int


@dataclass(frozen=True)
class Split:
    name: str
    counts: Mapping[str, int]
    seed: int
    aircraft_mix: Mapping[str, float]


@dataclass(frozen=True)
class Scenes:
    """Multi-target scenes (`pipeline.simulation.scenes`): `count` scenes of `aircraft` aircraft each, over
    `duration_s`, every one with a crossing, a formation and aircraft entering and leaving coverage."""

    count: int
    aircraft: int                       # per scene, the placed situations' aircraft included
    duration_s: float
    seed: int
    aircraft_mix: Mapping[str, float]   # type name -> weight
    strategies: Mapping[str, float]     # route strategy -> weight, for the aircraft not placed in a situation
    start_spread: float                 # those start at uniform times in the first this share of the scene
    separation_m: float                 # no aircraft appears nearer than this to another (within a formation apart)
    situation_range_min_m: float        # the crossing point and the formation's split point lie this far
    situation_range_max_m: float        #   from the radar (horizontally)
    crossing_angle_min_deg: float
    crossing_angle_max_deg: float
    formation_size_min: int
    formation_size_max: int
    formation_spacing_min_m: float
    formation_spacing_max_m: float
    formation_split_deg: float          # neighbours in the formation turn this far apart when it splits
    attempts: int                       # redraws of an aircraft that appears too near another


@dataclass(frozen=True)
class Routes:
    sample_interval_s: float
    start_time_unix_s: float
    start_spread_s: float
    constant_jerk: ConstantJerk
    random_turns: RandomTurns
    sustained_turns: SustainedTurns
    climb_dive: ClimbDive
    splits: tuple[Split, ...]

    def split(self, name: str) -> Split:
        for split in self.splits:
            if split.name == name:
                return split
        raise ParamError(f"routes.splits.{name}: no such split (have {[s.name for s in self.splits]})")


@dataclass(frozen=True)
class Windows:
    segment_gap_s: float
    holdout_fraction: float
    seed: int
    filter_length: int
    predictor_inputs: int
    autoencoder_length: int
    calibration_max_delay_s: float
    calibration_max_distance_m: float
    balance_bins: int
    balance_high_bins: int
    frame: str
    centre_range: bool
    dt_max_s: float
    position_max_diff_m: float
    range_scale_m: float


@dataclass(frozen=True)
class NetworkTraining:
    hidden: tuple[int, ...]
    decoder_hidden: tuple[int, ...]
    output_steps: int
    epochs: int
    batch_size: int
    learning_rate: float
    validation_fraction: float
    seed: int
    early_stopping_patience: int
    early_stopping_min_improvement: float
    lr_decay_factor: float
    lr_decay_patience: int


@dataclass(frozen=True)
class Training:
    tracking_uri: str
    experiment: str
    accelerator: str
    devices: int | str
    strategy: str
    threads: int
    deterministic: bool
    kalman_acceleration_std_mps2: float
    kalman_truth_sigma_m: float
    networks: Mapping[str, NetworkTraining]


@dataclass(frozen=True)
class TrackerParams:
    weight_start: float
    weight_candidate: float
    weight_confirmed: float
    weight_step: float
    silence_s: float
    silence_scans: float    # thesis: a track is lowered after max(silence_s, this many scans of its latest radar)
    prefilter_m: float
    young_track_plots: int
    young_track_plots_ae: int
    filter_plots: int
    mia_samples: int
    mia_ball_radius_m: float
    mia_k_no_padding: float
    mia_k_padded_base: float
    seed: int
    inference: str
    kalman_gate_probability: float
    management: str         # the track management rule of every run that names none (registry.MANAGEMENT)
    confirm_m: int          # m_of_n: confirmed at this many associations ...
    confirm_n: int          # ... within the last this many opportunities (scans)
    delete_after_s: float   # m_of_n: a confirmed track silent this long (s) ...
    delete_after_scans: float  # ... and this many scans of its latest radar, whichever is longer, is deleted
    mature_first: bool      # a plot a mature track gates is not offered to young tracks (run.Composition)
    revisit_scans: float    # a track is offered no plot of a radar within this many of its scans of the last (0: off)
    lstm_update_gate_m: float  # the LSTM update's chi-square gate never beyond this of the prediction (issue 18)
    young_window_fallback: bool  # lstm_update's young tracks also take what RadiusGate(window_m) takes (issue 27)
    refusal_warning_share: float  # `track` warns when a learned gate refused this share of the plots in the window


@dataclass(frozen=True)
class EvaluationRun:
    """One evaluation run: a method, its window (m) and, if the run names one, its track
    management rule (None: the tracker's, `tracker.management`); or a reference of
    `evaluate.references` (`reference`: the raw plots or the oracle, no window of its own: 0)."""

    method: str
    window_m: float
    management: str | None = None
    reference: bool = False

    @property
    def name(self) -> str:
        """`<method>_<window>`, and `_<rule>` when the run names its rule (`imm_4000_m_of_n`);
        `<method>_reference` for a reference (`oracle_reference`). The reports' key of the run."""
        if self.reference:
            return f"{self.method}_reference"
        base = f"{self.method}_{self.window_m:.0f}"
        return base if self.management is None else f"{base}_{self.management}"


@dataclass(frozen=True)
class Site:
    """A radar site other than the training one, where `evaluate_sites` flies the evaluated routes."""

    name: str
    latitude_deg: float
    longitude_deg: float
    height_m: float     # antenna height above the WGS-84 ellipsoid


@dataclass(frozen=True)
class Evaluate:
    split: str
    runs: tuple[EvaluationRun, ...]
    references: tuple[str, ...]
    ospa_cutoff_m: float
    ospa_order: float
    gospa_cutoff_m: float           # GOSPA (alpha = 2, `pipeline.bench.gospa`): cutoff c ...
    gospa_order: float              # ... and order p
    example_scenarios: int
    example_run: str
    sites: tuple[Site, ...]         # evaluate_sites: the same routes at these radar sites (empty: none)
    site_runs: tuple[str, ...]      # evaluate_sites: the runs (by name) scored at the sites (empty: every run)
    scene_runs: tuple[str, ...]     # evaluate_scenes: the runs (by name) scored on the scenes (empty: every run)

    def runs_at_sites(self) -> tuple[EvaluationRun, ...]:
        """The runs `evaluate_sites` scores: those `site_runs` names, in `runs` order, or all of them."""
        return tuple(run for run in self.runs if not self.site_runs or run.name in self.site_runs)

    def runs_on_scenes(self) -> tuple[EvaluationRun, ...]:
        """The runs `evaluate_scenes` scores: those `scene_runs` names, in `runs` order, or all of them."""
        return tuple(run for run in self.runs if not self.scene_runs or run.name in self.scene_runs)

    def reference_runs(self) -> tuple[EvaluationRun, ...]:
        """The references as runs, in `references` order (`plots_reference`, `oracle_reference`)."""
        return tuple(EvaluationRun(method, 0.0, reference=True) for method in self.references)


@dataclass(frozen=True)
class Kalman:
    split: str
    cost: str
    burn_in_updates: int
    restart_gap_s: float
    max_iterations: int
    velocity_std_mps: float
    acceleration_std_mps2: float
    noise_std: Mapping[str, tuple[float, ...]]   # start values by filter kind
    imm_switch_probability: float
    imm_initial_cv_probability: float


KALMAN_NET_BASES = ("cv", "ca", "singer")   # base filters the network can scale (one motion model each)
KALMAN_NET_CELLS = ("gru", "mlp")
GRADIENT_KINDS = ("cv", "ca", "singer", "imm")  # filters tuned by gradient descent
TRACK_MODELS = ("kalman", "two_point")          # association.tracks: how the synthetic radars make track points
MIN_SCENE_SIZE = 10                             # association.scene_size: the network's convolutions need this much


@dataclass(frozen=True)
class KalmanNet:
    """The network-scaled filter, the gradient-tuned baselines and their hold-out comparison (params.yaml)."""

    split: str
    base: str
    cell: str
    hidden: int
    noise_std: float
    manoeuvre_time_s: float
    velocity_std_mps: float
    acceleration_std_mps2: float
    r0_scale: float
    q_amplitude: float
    r_amplitude: float
    manoeuvre_amplitude: float
    velocity_scale_mps: float
    nis_scale: float
    restart_gap_s: float
    burn_in_updates: int
    segment_plots: int
    truncation_steps: int
    batch_segments: int
    epochs: int
    learning_rate: float
    seed: int
    baselines: tuple[str, ...]
    baseline_epochs: int
    baseline_learning_rate: float
    noise_scales: tuple[float, ...]
    noise_seed: int


@dataclass(frozen=True)
class Association:
    """Two radars' track-to-track association on the seed's synthetic setting (params.yaml `association`)."""

    targets: tuple[int, int]
    area_m: float
    scan_period_s: float
    track_points: int
    noise_m: tuple[float, float]
    detection_probability: float
    speed_mps: tuple[float, float]
    acceleration_std_mps2: float
    tracks: str
    train_bias_m: tuple[float, float]
    eval_bias_m: tuple[float, ...]
    eval_scenes: int
    eval_seed: int
    gate_probability: float
    double_threshold_hits: int
    max_bias_m: float
    vote_radius_m: float
    max_iterations: int
    max_time_offset_s: float        # bias_robust also estimates a clock offset of radar 2 up to this (0: not)
    scene_size: int
    scene_diameter_m: float
    feature_hidden: tuple[int, ...]
    decision_hidden: int
    decision_threshold: float
    epochs: int
    scenes_per_epoch: int
    scenes_per_batch: int
    learning_rate: float
    seed: int


@dataclass(frozen=True)
class LSTMUpdate:
    """The LSTM update on a Kalman prediction and its hold-out comparison (params.yaml `lstm_update`)."""

    split: str
    hidden: int
    dropout: float
    mc_samples: int
    detach_prediction: bool
    position_scale_m: float
    velocity_scale_mps: float
    acceleration_scale_mps2: float
    time_scale_s: float
    initial_alpha: float
    initial_beta: float
    floor_m: float
    start_velocity_std_mps: float
    restart_gap_s: float
    burn_in_updates: int
    segment_plots: int
    truncation_steps: int
    batch_segments: int
    epochs: int
    learning_rate: float
    seed: int
    validation_fraction: float
    calibration_ages: int
    calibration_gaps: int
    turn_share: float
    range_shares: tuple[float, ...]


@dataclass(frozen=True)
class Associate:
    """`python -m pipeline associate` on two track tables (params.yaml `associate`; pipeline/association/common_time_states.py)."""

    step_s: float                   # common times this far apart over the tables' overlap
    max_age_s: float                # a track's last update no older than this at a common time
    velocity_baseline_s: float      # velocity from the last update and the latest one at least this much earlier
    acceleration_std_mps2: float    # white-noise acceleration of the extrapolation to the common time
    fusion_criterion: str           # covariance intersection minimises this (track_fusion.CRITERIA)
    keep_probability: float         # the keep gate of association with memory (association_memory)
    max_speed_mps: float            # consecutive updates of one track further apart than this: two aircraft


@dataclass(frozen=True)
class FusionRadar:
    """One radar of the fusion stage: what it is (`radar`, params' `radar` with the entry's keys changed), its
    registration bias (range m, azimuth deg, site east and north m: the tracker believes the radar that much
    away from where it is) and the seed of its detections, noise and clutter (in place of simulate.seed)."""

    radar: Radar
    bias_range_m: float
    bias_azimuth_deg: float
    bias_east_m: float
    bias_north_m: float
    seed: int


@dataclass(frozen=True)
class Fusion:
    """The fusion stage (params.yaml `fusion`; pipeline/bench/radar_fusion.py)."""

    scenes: int
    tracker: str
    window_m: float
    methods: tuple[str, ...]
    radars: tuple[FusionRadar, FusionRadar]
    sweep_scenes: int                     # the first this many scenes in the bias sweep (fusion_bias_sweep)
    sweep_bias_m: tuple[float, ...]       # radar 2's registration bias lengths there, m


@dataclass(frozen=True)
class Params:
    radar: Radar
    aircraft: Mapping[str, Aircraft]
    routes: Routes
    scenes: Scenes
    simulate_seed: int
    example_routes: int
    windows: Windows
    training: Training
    tracker: TrackerParams
    kalman: Kalman
    kalman_net: KalmanNet
    association: Association
    lstm_update: LSTMUpdate
    evaluate: Evaluate
    workers: int        # compute.workers: processes for independent work; results do not depend on it
    associate: Associate
    fusion: Fusion
    chunk_plots: int    # compute.chunk_plots: plots `track` holds placed at a time; results do not depend on it


class _Section(Mapping):
    """A mapping of the params tree that remembers which of its keys the parser read.

    The parser's reads are the one list of known keys: whatever it never read is a key nobody
    uses (a misspelt `sigma_rnage_m` beside the real `sigma_range_m`, which would otherwise
    leave the run on the old value without a word). Iterating a section reads all of its
    keys, because the parser iterates only sections whose keys the user names (aircraft
    types, splits, aircraft mixes)."""

    def __init__(self, tree: Mapping[Any, Any], path: str) -> None:
        self._tree = tree
        self._path = path
        self._values = {key: _tracked(value, f"{path}.{key}" if path else str(key)) for key, value in tree.items()}
        self._read: set[Any] = set()

    def __getitem__(self, key: Any) -> Any:
        value = self._values[key]
        self._read.add(key)
        return value

    def __iter__(self) -> Iterator[Any]:
        self._read.update(self._values)
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __repr__(self) -> str:
        return repr(self._tree)

    def unread(self) -> list[str]:
        """'<path> = <value>: unknown key (did you mean <nearest read key>?)' for every key never read."""
        problems = []
        for key, value in self._values.items():
            if key in self._read:
                for child in value if isinstance(value, list) else [value]:
                    if isinstance(child, _Section):
                        problems += child.unread()
                continue
            near = difflib.get_close_matches(str(key), [str(known) for known in self._read], n=1)
            hint = f"did you mean {near[0]}?" if near else f"known: {', '.join(sorted(map(str, self._read)))}"
            path = f"{self._path}.{key}" if self._path else str(key)
            problems.append(f"{path} = {self._tree[key]!r}: unknown key ({hint})")
        return problems


def _tracked(value: Any, path: str) -> Any:
    if isinstance(value, Mapping):
        return _Section(value, path)
    if isinstance(value, list):
        return [_tracked(item, f"{path}[{index}]") for index, item in enumerate(value)]
    return value


def _get(tree: Mapping[str, Any], key: str, path: str) -> Any:
    if not isinstance(tree, Mapping) or key not in tree:
        raise ParamError(f"{path}.{key}: missing")
    return tree[key]


def _number(tree: Mapping[str, Any], key: str, path: str, low: float = -math.inf,
            high: float = math.inf, low_open: bool = False, high_open: bool = False) -> float:
    value = _get(tree, key, path)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ParamError(f"{path}.{key} = {value!r}: must be a finite number")
    if value < low or value > high or (low_open and value == low) or (high_open and value == high):
        brackets = ("(" if low_open else "[", ")" if high_open else "]")
        raise ParamError(f"{path}.{key} = {value!r}: must be in {brackets[0]}{low}, {high}{brackets[1]}")
    return float(value)


def _positive(tree: Mapping[str, Any], key: str, path: str) -> float:
    return _number(tree, key, path, 0.0, low_open=True)


def _integer(tree: Mapping[str, Any], key: str, path: str, low: int = 0) -> int:
    value = _get(tree, key, path)
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ParamError(f"{path}.{key} = {value!r}: must be an integer >= {low}")
    return value


def _boolean(tree: Mapping[str, Any], key: str, path: str) -> bool:
    value = _get(tree, key, path)
    if not isinstance(value, bool):
        raise ParamError(f"{path}.{key} = {value!r}: must be true or false")
    return value


def _interval(tree: Mapping[str, Any], key: str, path: str, low: float = 0.0) -> tuple[float, float]:
    value = _get(tree, key, path)
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ParamError(f"{path}.{key} = {value!r}: must be a [lower, upper] pair")
    pair = {"lower": value[0], "upper": value[1]}
    lower = _number(pair, "lower", f"{path}.{key}", low)
    upper = _number(pair, "upper", f"{path}.{key}", low)
    if lower > upper:
        raise ParamError(f"{path}.{key} = {value!r}: lower bound {lower} is above upper bound {upper}")
    return lower, upper


def _positive_interval(tree: Mapping[str, Any], key: str, path: str, high: float = math.inf) -> tuple[float, float]:
    """An ordered [lower, upper] pair with 0 < lower and upper <= high."""
    lower, upper = _interval(tree, key, path)
    if lower <= 0.0 or upper > high:
        raise ParamError(f"{path}.{key} = {[lower, upper]}: must lie in (0, {high}]")
    return lower, upper


def _radar(tree: Mapping[str, Any]) -> Radar:
    p = "radar"
    radar = Radar(
        sac=_integer(tree, "sac", p),
        sic=_integer(tree, "sic", p),
        latitude_deg=_number(tree, "latitude_deg", p, -90.0, 90.0),
        longitude_deg=_number(tree, "longitude_deg", p, -180.0, 180.0),
        height_m=_number(tree, "height_m", p, -500.0, 10000.0),
        rotation_rpm=_positive(tree, "rotation_rpm", p),
        range_max_m=_positive(tree, "range_max_m", p),
        range_min_m=_number(tree, "range_min_m", p, 0.0),
        altitude_max_m=_positive(tree, "altitude_max_m", p),
        sigma_range_m=_number(tree, "sigma_range_m", p, 0.0),
        sigma_azimuth_deg=_number(tree, "sigma_azimuth_deg", p, 0.0),
        sigma_altitude_m=_number(tree, "sigma_altitude_m", p, 0.0),
        reference_snr_db=_number(tree, "reference_snr_db", p),
        reference_range_m=_positive(tree, "reference_range_m", p),
        reference_rcs_m2=_positive(tree, "reference_rcs_m2", p),
        false_alarm_probability=_number(tree, "false_alarm_probability", p, 0.0, 1.0, low_open=True),
        false_plots_per_scan=_number(tree, "false_plots_per_scan", p, 0.0),
        horizon=_boolean(tree, "horizon", p),
        effective_earth_radius_factor=_positive(tree, "effective_earth_radius_factor", p),
        max_elevation_deg=_number(tree, "max_elevation_deg", p, 0.0, 90.0, low_open=True),
    )
    if radar.sac > 255 or radar.sic > 255:
        raise ParamError(f"radar.sac/sic = {radar.sac}/{radar.sic}: each must fit in one byte (0-255)")
    if radar.range_min_m >= radar.range_max_m:
        raise ParamError(f"radar.range_min_m = {radar.range_min_m}: must be below range_max_m = {radar.range_max_m}")
    return radar


def _aircraft(name: str, tree: Mapping[str, Any]) -> Aircraft:
    p = f"aircraft.{name}"
    speed = _interval(tree, "speed_mps", p)
    altitude = _interval(tree, "altitude_m", p)
    holding = _interval(tree, "holding_speed_mps", p)
    for key, interval in (("speed_mps", speed), ("holding_speed_mps", holding)):
        if interval[0] <= 0.0:
            raise ParamError(f"{p}.{key} = {list(interval)}: speeds must be positive")
    kind = Aircraft(
        name=name,
        speed_min_mps=speed[0],
        speed_max_mps=speed[1],
        max_turn_rate_dps=_positive(tree, "max_turn_rate_dps", p),
        max_acceleration_mps2=_positive(tree, "max_acceleration_mps2", p),
        altitude_min_m=altitude[0],
        altitude_max_m=altitude[1],
        rcs_front_m2=_positive(tree, "rcs_front_m2", p),
        rcs_side_m2=_positive(tree, "rcs_side_m2", p),
        holding_speed_min_mps=holding[0],
        holding_speed_max_mps=holding[1],
        max_vertical_rate_mps=_positive(tree, "max_vertical_rate_mps", p),
    )
    if kind.max_vertical_rate_mps ** 2 > kind.speed_max_mps ** 2 - kind.speed_min_mps ** 2:
        raise ParamError(f"{p}.max_vertical_rate_mps = {kind.max_vertical_rate_mps}: a climb at that rate and the "
                         f"slowest speed {kind.speed_min_mps} would exceed the top speed {kind.speed_max_mps}")
    return kind


def _split(name: str, tree: Mapping[str, Any], aircraft: Mapping[str, Aircraft]) -> Split:
    p = f"routes.splits.{name}"
    counts = {strategy: _integer(tree, strategy, p) for strategy in STRATEGIES}
    return Split(name=name, counts=counts, seed=_integer(tree, "seed", p),
                 aircraft_mix=_weights(tree, "aircraft_mix", p, list(aircraft), "aircraft type"))


def _weights(tree: Mapping[str, Any], key: str, p: str, known: list[str], what: str) -> dict[str, float]:
    """A mapping of some of `known` names to weights >= 0, not all zero (an aircraft mix, strategy weights)."""
    weights_tree = _get(tree, key, p)
    if not isinstance(weights_tree, Mapping) or not weights_tree:
        raise ParamError(f"{p}.{key} = {weights_tree!r}: must map {what}s to weights")
    for name in weights_tree:
        if name not in known:
            raise ParamError(f"{p}.{key}.{name}: unknown {what} (known: {sorted(known)})")
    weights = {name: _number(weights_tree, name, f"{p}.{key}", 0.0) for name in weights_tree}
    if sum(weights.values()) <= 0.0:
        raise ParamError(f"{p}.{key} = {dict(weights)}: weights must not all be zero")
    return weights


SITUATION_AIRCRAFT = 4  # a scene's crossing pair, its aircraft entering and its aircraft leaving coverage


def _scenes(tree: Mapping[str, Any], aircraft: Mapping[str, Aircraft], radar: Radar) -> Scenes:
    """The `scenes` section. Besides each value's range: a scene must hold its placed situations
    (SITUATION_AIRCRAFT aircraft and the largest formation), and no more aircraft than fit the
    coverage box (side sqrt(2) R_max) with `separation_m` between them, packed hexagonally (each
    aircraft a disc of diameter separation_m, sqrt(3)/2 separation_m^2 of area); and the closest
    formation must be resolvable at the farthest place it is put (`formation_resolution_m`)."""
    p = "scenes"
    size = _interval(tree, "formation_size", p, 2.0)
    if size != (int(size[0]), int(size[1])):
        raise ParamError(f"{p}.formation_size = {list(size)}: must be whole numbers of aircraft, at least 2")
    situation = _positive_interval(tree, "situation_range_m", p, radar.range_max_m)
    if situation[0] < radar.range_min_m:
        raise ParamError(f"{p}.situation_range_m = {list(situation)}: starts inside the radar's blind range "
                         f"radar.range_min_m = {radar.range_min_m}")
    spacing = _positive_interval(tree, "formation_spacing_m", p)
    angle = _positive_interval(tree, "crossing_angle_deg", p, 90.0)
    scenes = Scenes(
        count=_integer(tree, "count", p, 1), aircraft=_integer(tree, "aircraft", p, 1),
        duration_s=_positive(tree, "duration_s", p), seed=_integer(tree, "seed", p),
        aircraft_mix=_weights(tree, "aircraft_mix", p, list(aircraft), "aircraft type"),
        strategies=_weights(tree, "strategies", p, list(STRATEGIES), "route strategy"),
        start_spread=_number(tree, "start_spread", p, 0.0, 1.0, high_open=True),
        separation_m=_positive(tree, "separation_m", p),
        situation_range_min_m=situation[0], situation_range_max_m=situation[1],
        crossing_angle_min_deg=angle[0], crossing_angle_max_deg=angle[1],
        formation_size_min=int(size[0]), formation_size_max=int(size[1]),
        formation_spacing_min_m=spacing[0], formation_spacing_max_m=spacing[1],
        formation_split_deg=_number(tree, "formation_split_deg", p, 0.0, 180.0, low_open=True, high_open=True),
        attempts=_integer(tree, "attempts", p, 1))
    needed = SITUATION_AIRCRAFT + scenes.formation_size_max
    if scenes.aircraft < needed:
        raise ParamError(f"{p}.aircraft = {scenes.aircraft}: a scene needs at least {needed} (a crossing pair, a "
                         f"formation of up to formation_size = {scenes.formation_size_max}, one aircraft entering and "
                         "one leaving coverage)")
    capacity = int(2.0 * radar.range_max_m ** 2 / (math.sqrt(3.0) / 2.0 * scenes.separation_m ** 2))
    if scenes.aircraft > capacity:
        raise ParamError(f"{p}.aircraft = {scenes.aircraft}: more than the {capacity} that fit the coverage box "
                         f"(side sqrt(2) x radar.range_max_m) {scenes.separation_m:.0f} m apart (scenes.separation_m)")
    resolution = formation_resolution_m(radar, scenes.situation_range_max_m)
    if scenes.formation_spacing_min_m <= resolution:
        raise ParamError(f"{p}.formation_spacing_m = {list(spacing)}: the closest formation, "
                         f"{scenes.formation_spacing_min_m:.0f} m apart, is within the radar's resolution, "
                         f"{resolution:.0f} m at {scenes.situation_range_max_m:.0f} m (the far end of "
                         "scenes.situation_range_m)")
    return scenes


def formation_resolution_m(radar: Radar, range_m: float) -> float:
    """A proxy of the radar's resolution at `range_m`: the larger of its range error and its
    cross-range error (azimuth error times range), one sigma each. Two aircraft nearer than that
    are hard to tell apart from their plots (the simulator gives each its own plot all the same:
    it does not merge plots in one resolution cell)."""
    return max(radar.sigma_range_m, range_m * math.radians(radar.sigma_azimuth_deg))


def _start_time(text: Any) -> float:
    try:
        moment = datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError as error:
        raise ParamError(f"routes.start_time_utc = {text!r}: not an ISO 8601 time ({error})") from None
    if moment.tzinfo is None:
        raise ParamError(f"routes.start_time_utc = {text!r}: give a time zone, e.g. a trailing Z for UTC")
    return moment.timestamp()


def _sustained_turns(tree: Mapping[str, Any]) -> SustainedTurns:
    p = "routes.sustained_turns"
    rate = _positive_interval(tree, "turn_rate_dps", p)
    turning = _positive_interval(tree, "turning_time_s", p)
    leg = _positive_interval(tree, "holding_leg_s", p)
    straight = _interval(tree, "straight_s", p)
    return SustainedTurns(_number(tree, "holding_probability", p, 0.0, 1.0), *rate, *turning, *leg, *straight,
                          attempts=_integer(tree, "attempts", p, 1))


def _climb_dive(tree: Mapping[str, Any], aircraft: Mapping[str, Aircraft]) -> ClimbDive:
    p = "routes.climb_dive"
    length = _positive_interval(tree, "length_m", p)
    level = _positive_interval(tree, "level_s", p)
    change = _positive_interval(tree, "altitude_change_m", p)
    for kind in aircraft.values():
        if change[0] > (kind.altitude_max_m - kind.altitude_min_m) / 2.0:
            raise ParamError(f"{p}.altitude_change_m = {list(change)}: the smallest change is above half the altitude "
                             f"band of aircraft.{kind.name} ({kind.altitude_min_m}-{kind.altitude_max_m} m), so "
                             "neither a climb nor a dive may fit")
    rate = _positive_interval(tree, "vertical_rate_fraction", p, 1.0)
    turn = _positive_interval(tree, "turn_duration_s", p)
    return ClimbDive(*length, _number(tree, "min_length_m", p, 0.0), *level, *change, *rate,
                     vertical_acceleration_fraction=_number(tree, "vertical_acceleration_fraction", p, 0.0, 1.0,
                                                            low_open=True),
                     turn_rate_dps=_number(tree, "turn_rate_dps", p, 0.0),
                     turn_duration_min_s=turn[0], turn_duration_max_s=turn[1],
                     attempts=_integer(tree, "attempts", p, 1))


def _routes(tree: Mapping[str, Any], aircraft: Mapping[str, Aircraft], radar: Radar) -> Routes:
    p = "routes"
    cj = _get(tree, "constant_jerk", p)
    waypoints = _interval(cj, "waypoints", f"{p}.constant_jerk")
    legs = (_positive(cj, "min_leg_m", f"{p}.constant_jerk"), _positive(cj, "max_leg_m", f"{p}.constant_jerk"))
    if legs[0] > legs[1]:
        raise ParamError(f"{p}.constant_jerk.min_leg_m = {legs[0]}: above max_leg_m = {legs[1]}")
    if waypoints[0] < 2 or waypoints[0] != int(waypoints[0]) or waypoints[1] != int(waypoints[1]):
        raise ParamError(f"{p}.constant_jerk.waypoints = {list(waypoints)}: must be integers >= 2")
    rt = _get(tree, "random_turns", p)
    length = _interval(rt, "length_m", f"{p}.random_turns")
    duration = _interval(rt, "turn_duration_s", f"{p}.random_turns")
    if duration[0] <= 0.0:
        raise ParamError(f"{p}.random_turns.turn_duration_s = {list(duration)}: durations must be positive")
    splits_tree = _get(tree, "splits", p)
    if not isinstance(splits_tree, Mapping) or not splits_tree:
        raise ParamError(f"{p}.splits = {splits_tree!r}: must name at least one split")
    splits = tuple(_split(name, splits_tree[name], aircraft) for name in splits_tree)
    seeds = [split.seed for split in splits]
    if len(set(seeds)) != len(seeds):
        raise ParamError(f"{p}.splits seeds = {seeds}: every split needs its own seed so no route repeats")
    for kind in aircraft.values():
        if kind.altitude_max_m > radar.altitude_max_m:
            raise ParamError(f"aircraft.{kind.name}.altitude_m upper bound {kind.altitude_max_m} is above "
                             f"radar.altitude_max_m = {radar.altitude_max_m}: routes must stay in coverage")
    return Routes(
        sample_interval_s=_positive(tree, "sample_interval_s", p),
        start_time_unix_s=_start_time(_get(tree, "start_time_utc", p)),
        start_spread_s=_number(tree, "start_spread_s", p, 0.0),
        constant_jerk=ConstantJerk(int(waypoints[0]), int(waypoints[1]), legs[0], legs[1],
                                   _integer(cj, "attempts", f"{p}.constant_jerk", 1)),
        random_turns=RandomTurns(length[0], length[1], duration[0], duration[1],
                                 _number(rt, "min_length_m", f"{p}.random_turns", 0.0)),
        sustained_turns=_sustained_turns(_get(tree, "sustained_turns", p)),
        climb_dive=_climb_dive(_get(tree, "climb_dive", p), aircraft),
        splits=splits,
    )


def _windows(tree: Mapping[str, Any]) -> Windows:
    p = "windows"
    frame = _get(tree, "frame", p)
    if frame not in ("ecef", "enu", "radial"):
        raise ParamError(f"{p}.frame = {frame!r}: must be 'ecef', 'enu' or 'radial'")
    windows = Windows(
        segment_gap_s=_positive(tree, "segment_gap_s", p),
        holdout_fraction=_number(tree, "holdout_fraction", p, 0.0, 1.0),
        seed=_integer(tree, "seed", p),
        filter_length=_integer(tree, "filter_length", p, 2),
        predictor_inputs=_integer(tree, "predictor_inputs", p, 2),
        autoencoder_length=_integer(tree, "autoencoder_length", p, 2),
        calibration_max_delay_s=_positive(tree, "calibration_max_delay_s", p),
        calibration_max_distance_m=_positive(tree, "calibration_max_distance_m", p),
        balance_bins=_integer(tree, "balance_bins", p, 2),
        balance_high_bins=_integer(tree, "balance_high_bins", p, 1),
        frame=frame,
        centre_range=_boolean(tree, "centre_range", p),
        dt_max_s=_positive(tree, "dt_max_s", p),
        position_max_diff_m=_positive(tree, "position_max_diff_m", p),
        range_scale_m=_positive(tree, "range_scale_m", p),
    )
    if windows.balance_high_bins >= windows.balance_bins:
        raise ParamError(f"{p}.balance_high_bins = {windows.balance_high_bins}: must be below "
                         f"balance_bins = {windows.balance_bins}")
    return windows


def _sizes(tree: Mapping[str, Any], key: str, path: str) -> tuple[int, ...]:
    value = _get(tree, key, path)
    if (not isinstance(value, list) or not value
            or any(isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in value)):
        raise ParamError(f"{path}.{key} = {value!r}: must be a list of positive layer sizes")
    return tuple(value)


def _text(tree: Mapping[str, Any], key: str, path: str) -> str:
    value = _get(tree, key, path)
    if not isinstance(value, str) or not value:
        raise ParamError(f"{path}.{key} = {value!r}: must be a non-empty string")
    return value


def _network_training(kind: str, tree: Mapping[str, Any], windows: Windows) -> NetworkTraining:
    p = f"training.{kind}"
    output_steps = {"filter": None, "predictor": windows.predictor_inputs - 1,
                    "autoencoder": windows.autoencoder_length}[kind]
    if output_steps is None:
        output_steps = _integer(tree, "output_steps", p, 1)
        if output_steps > windows.filter_length:
            raise ParamError(f"{p}.output_steps = {output_steps}: above windows.filter_length = "
                             f"{windows.filter_length}")
    epochs = _integer(tree, "epochs", p, 1)
    patience = _integer(tree, "early_stopping_patience", p)
    if patience > epochs:
        raise ParamError(f"{p}.early_stopping_patience = {patience}: above {p}.epochs = {epochs}, so it could "
                         "never stop a run (0 turns early stopping off)")
    lr_decay_patience = _integer(tree, "lr_decay_patience", p)
    if lr_decay_patience > epochs:
        raise ParamError(f"{p}.lr_decay_patience = {lr_decay_patience}: above {p}.epochs = {epochs} "
                         "(0 turns the decay off)")
    validation_fraction = _number(tree, "validation_fraction", p, 0.0, 0.9)
    for key, value in (("early_stopping_patience", patience), ("lr_decay_patience", lr_decay_patience)):
        if value and not validation_fraction:
            raise ParamError(f"{p}.{key} = {value}: needs validation windows, but {p}.validation_fraction = 0")
    return NetworkTraining(
        hidden=_sizes(tree, "hidden", p),
        decoder_hidden=_sizes(tree, "decoder_hidden", p) if kind == "autoencoder" else (),
        output_steps=output_steps,
        epochs=epochs,
        batch_size=_integer(tree, "batch_size", p, 1),
        learning_rate=_positive(tree, "learning_rate", p),
        validation_fraction=validation_fraction,
        seed=_integer(tree, "seed", p),
        early_stopping_patience=patience,
        early_stopping_min_improvement=_number(tree, "early_stopping_min_improvement", p, 0.0, 0.5),
        lr_decay_factor=_number(tree, "lr_decay_factor", p, 0.0, 1.0, low_open=True),
        lr_decay_patience=lr_decay_patience,
    )


def _training(tree: Mapping[str, Any], windows: Windows) -> Training:
    p = "training"
    devices = _get(tree, "devices", p)
    if not (devices == "auto" or (isinstance(devices, int) and not isinstance(devices, bool) and devices >= 1)):
        raise ParamError(f"{p}.devices = {devices!r}: must be a positive integer or 'auto'")
    return Training(
        tracking_uri=_text(tree, "tracking_uri", p),
        experiment=_text(tree, "experiment", p),
        accelerator=_text(tree, "accelerator", p),
        devices=devices,
        strategy=_text(tree, "strategy", p),
        threads=_integer(tree, "threads", p, 1),
        deterministic=_boolean(tree, "deterministic", p),
        kalman_acceleration_std_mps2=_positive(tree, "kalman_acceleration_std_mps2", p),
        kalman_truth_sigma_m=_positive(tree, "kalman_truth_sigma_m", p),
        networks={kind: _network_training(kind, _get(tree, kind, p), windows)
                  for kind in ("filter", "predictor", "autoencoder")},
    )


def _tracker(tree: Mapping[str, Any], windows: Windows) -> TrackerParams:
    p = "tracker"
    tracker = TrackerParams(
        weight_start=_positive(tree, "weight_start", p),
        weight_candidate=_positive(tree, "weight_candidate", p),
        weight_confirmed=_positive(tree, "weight_confirmed", p),
        weight_step=_positive(tree, "weight_step", p),
        silence_s=_positive(tree, "silence_s", p),
        silence_scans=_number(tree, "silence_scans", p, 0.0),
        prefilter_m=_positive(tree, "prefilter_m", p),
        young_track_plots=_integer(tree, "young_track_plots", p, 1),
        young_track_plots_ae=_integer(tree, "young_track_plots_ae", p, windows.autoencoder_length),
        filter_plots=_integer(tree, "filter_plots", p, 1),
        mia_samples=_integer(tree, "mia_samples", p, 2),
        mia_ball_radius_m=_positive(tree, "mia_ball_radius_m", p),
        mia_k_no_padding=_positive(tree, "mia_k_no_padding", p),
        mia_k_padded_base=_positive(tree, "mia_k_padded_base", p),
        seed=_integer(tree, "seed", p),
        inference=_text(tree, "inference", p),
        kalman_gate_probability=_number(tree, "kalman_gate_probability", p, 0.0, 1.0, low_open=True),
        management=_get(tree, "management", p),
        confirm_m=_integer(tree, "confirm_m", p, 1),
        confirm_n=_integer(tree, "confirm_n", p, 1),
        delete_after_s=_positive(tree, "delete_after_s", p),
        delete_after_scans=_number(tree, "delete_after_scans", p, 0.0),
        mature_first=_boolean(tree, "mature_first", p),
        revisit_scans=_number(tree, "revisit_scans", p, 0.0, 1.0, high_open=True),
        lstm_update_gate_m=_positive(tree, "lstm_update_gate_m", p),
        young_window_fallback=_boolean(tree, "young_window_fallback", p),
        refusal_warning_share=_number(tree, "refusal_warning_share", p, 0.0, 1.0, low_open=True),
    )
    if tracker.confirm_m > tracker.confirm_n:
        raise ParamError(f"{p}.confirm_m = {tracker.confirm_m}: must not exceed confirm_n = {tracker.confirm_n}")
    if tracker.confirm_n > MAX_CONFIRM_N:
        raise ParamError(f"{p}.confirm_n = {tracker.confirm_n}: must be at most {MAX_CONFIRM_N}")
    if tracker.kalman_gate_probability >= 1.0:
        raise ParamError(f"{p}.kalman_gate_probability = {tracker.kalman_gate_probability}: must be below 1")
    if tracker.inference not in ("onnx", "torch"):
        raise ParamError(f"{p}.inference = {tracker.inference!r}: must be 'onnx' or 'torch'")
    if not tracker.weight_start < tracker.weight_candidate < tracker.weight_confirmed:
        raise ParamError(f"{p}: weights must rise: weight_start {tracker.weight_start} < weight_candidate "
                         f"{tracker.weight_candidate} < weight_confirmed {tracker.weight_confirmed}")
    if tracker.filter_plots != windows.filter_length:
        raise ParamError(f"{p}.filter_plots = {tracker.filter_plots}: the filter network reads "
                         f"windows.filter_length = {windows.filter_length} plots")
    return tracker


def _split_name(tree: Mapping[str, Any], p: str, splits: tuple[Split, ...]) -> str:
    """A section's `split`, which must be one of routes.splits."""
    split = _text(tree, "split", p)
    if split not in [s.name for s in splits]:
        raise ParamError(f"{p}.split = {split!r}: no such split in routes.splits")
    return split


def _evaluate(tree: Mapping[str, Any], splits: tuple[Split, ...]) -> Evaluate:
    p = "evaluate"
    split = _split_name(tree, p, splits)
    runs_tree = _get(tree, "runs", p)
    if not isinstance(runs_tree, list) or not runs_tree:
        raise ParamError(f"{p}.runs = {runs_tree!r}: must list at least one {{method, window_m}}")
    runs = []
    for index, run in enumerate(runs_tree):
        method = _get(run, "method", f"{p}.runs[{index}]")
        rule = run["management"] if "management" in run else None
        runs.append(EvaluationRun(method, _positive(run, "window_m", f"{p}.runs[{index}]"), rule))
    names = [run.name for run in runs]
    if len(set(names)) != len(names):
        raise ParamError(f"{p}.runs: {names} repeats a method, window and management rule")
    example_run = _text(tree, "example_run", p)
    if example_run not in names:
        raise ParamError(f"{p}.example_run = {example_run!r}: not one of the runs {names}")
    references = _get(tree, "references", p)
    if not isinstance(references, list):
        raise ParamError(f"{p}.references = {references!r}: must be a list of reference names")
    return Evaluate(split=split, runs=tuple(runs), references=tuple(references),
                    ospa_cutoff_m=_positive(tree, "ospa_cutoff_m", p), ospa_order=_positive(tree, "ospa_order", p),
                    gospa_cutoff_m=_positive(tree, "gospa_cutoff_m", p),
                    gospa_order=_number(tree, "gospa_order", p, 1.0),  # GOSPA is a metric for p >= 1
                    example_scenarios=_integer(tree, "example_scenarios", p), example_run=example_run,
                    sites=_sites(tree, p), site_runs=_run_names(tree, "site_runs", p, names),
                    scene_runs=_scene_runs(tree, p, names, example_run))


def _run_names(tree: Mapping[str, Any], key: str, p: str, names: list[str]) -> tuple[str, ...]:
    """A list of names of `evaluate.runs` (`<method>_<window>[_<rule>]`), each once ([]: all of them)."""
    chosen = _get(tree, key, p)
    if not isinstance(chosen, list) or any(name not in names for name in chosen) or len(set(chosen)) != len(chosen):
        raise ParamError(f"{p}.{key} = {chosen!r}: must list distinct names of the runs {names} ([]: all of them)")
    return tuple(chosen)


def _scene_runs(tree: Mapping[str, Any], p: str, names: list[str], example_run: str) -> tuple[str, ...]:
    """`evaluate.scene_runs`, which must hold `evaluate.example_run`: it draws reports/scene_example.png."""
    chosen = _run_names(tree, "scene_runs", p, names)
    if chosen and example_run not in chosen:
        raise ParamError(f"{p}.scene_runs = {list(chosen)}: must include evaluate.example_run = {example_run!r}, "
                         "whose tracks reports/scene_example.png draws")
    return chosen


SITE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")  # a site's name labels report rows and keys


def _sites(tree: Mapping[str, Any], p: str) -> tuple[Site, ...]:
    """`evaluate.sites`: named radar sites, each {name, latitude_deg, longitude_deg, height_m}; the
    latitude and longitude bounds are the radar's, but with the antimeridian only once, as +180."""
    sites_tree = _get(tree, "sites", p)
    if not isinstance(sites_tree, list):
        raise ParamError(f"{p}.sites = {sites_tree!r}: must be a list of {{name, latitude_deg, longitude_deg, "
                         "height_m}} (empty: no other sites)")
    sites = []
    for index, site in enumerate(sites_tree):
        path = f"{p}.sites[{index}]"
        if not isinstance(site, Mapping):
            raise ParamError(f"{path} = {site!r}: must be a mapping {{name, latitude_deg, longitude_deg, height_m}}")
        name = _get(site, "name", path)
        if not isinstance(name, str) or not SITE_NAME.fullmatch(name):
            raise ParamError(f"{path}.name = {name!r}: must be an identifier (letters, digits, _; not a digit first)")
        sites.append(Site(name, _number(site, "latitude_deg", path, -90.0, 90.0),
                          _number(site, "longitude_deg", path, -180.0, 180.0, low_open=True),
                          _number(site, "height_m", path, -500.0, 10000.0)))
    names = [site.name for site in sites]
    if len(set(names)) != len(names):
        raise ParamError(f"{p}.sites: names {names} repeat")
    return tuple(sites)


TUNING_COSTS = ("rmse", "nees", "rmse_in_gate")


def _kalman(tree: Mapping[str, Any], splits: tuple[Split, ...]) -> Kalman:
    p = "kalman"
    split = _split_name(tree, p, splits)
    cost = _text(tree, "cost", p)
    if cost not in TUNING_COSTS:
        raise ParamError(f"{p}.cost = {cost!r}: must be one of {TUNING_COSTS}")
    noise = {}
    for kind, count in (("cv", 1), ("ca", 1), ("imm", 2)):
        values = _get(tree, f"{kind}_noise_std", p)
        if (not isinstance(values, list) or len(values) != count
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in values)):
            raise ParamError(f"{p}.{kind}_noise_std = {values!r}: must list {count} positive number(s)")
        noise[kind] = tuple(float(v) for v in values)
    return Kalman(
        split=split, cost=cost, burn_in_updates=_integer(tree, "burn_in_updates", p),
        restart_gap_s=_positive(tree, "restart_gap_s", p), max_iterations=_integer(tree, "max_iterations", p, 1),
        velocity_std_mps=_positive(tree, "velocity_std_mps", p),
        acceleration_std_mps2=_positive(tree, "acceleration_std_mps2", p), noise_std=noise,
        imm_switch_probability=_number(tree, "imm_switch_probability", p, 0.0, 1.0, low_open=True,
                                       high_open=True),
        imm_initial_cv_probability=_number(tree, "imm_initial_cv_probability", p, 0.0, 1.0),
    )


def _kalman_net(tree: Mapping[str, Any], splits: tuple[Split, ...]) -> KalmanNet:
    """Checked before anything trains: Q0 and R0 positive definite (Q0 = noise_std^2 times a positive
    definite matrix of dt and tau, R0 = r0_scale times the plot's covariance), amplitudes above 1 (an
    untrained network gives every scale 1), truncation within a training segment."""
    p = "kalman_net"
    base, cell = _text(tree, "base", p), _text(tree, "cell", p)
    if base not in KALMAN_NET_BASES:
        raise ParamError(f"{p}.base = {base!r}: must be one of {KALMAN_NET_BASES}")
    if cell not in KALMAN_NET_CELLS:
        raise ParamError(f"{p}.cell = {cell!r}: must be one of {KALMAN_NET_CELLS}")
    for key in ("noise_std", "manoeuvre_time_s", "r0_scale"):
        value = _get(tree, key, p)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 or not math.isfinite(value):
            matrix = "R0" if key == "r0_scale" else "Q0"
            raise ParamError(f"{p}.{key} = {value!r}: {matrix} must be positive definite, so this must be a "
                             "positive number")
    amplitudes = {key: _number(tree, key, p) for key in ("q_amplitude", "r_amplitude", "manoeuvre_amplitude")}
    for key, value in amplitudes.items():
        if value <= 1.0:
            raise ParamError(f"{p}.{key} = {value!r}: must be above 1 (the largest scale the network can give; "
                             "it starts at 1)")
    segment_plots = _integer(tree, "segment_plots", p, 2)
    truncation = _integer(tree, "truncation_steps", p, 1)
    if truncation > segment_plots:
        raise ParamError(f"{p}.truncation_steps = {truncation}: longer than the training segments "
                         f"(segment_plots = {segment_plots})")
    burn_in = _integer(tree, "burn_in_updates", p)
    if burn_in >= segment_plots:
        raise ParamError(f"{p}.burn_in_updates = {burn_in}: leaves nothing of a {segment_plots}-plot segment to score")
    baselines = _get(tree, "baselines", p)
    if (not isinstance(baselines, list) or len(set(baselines)) != len(baselines)
            or not set(baselines) <= set(GRADIENT_KINDS)):
        raise ParamError(f"{p}.baselines = {baselines!r}: must list distinct kinds of {GRADIENT_KINDS}")
    scales = _get(tree, "noise_scales", p)
    if (not isinstance(scales, list) or not scales or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < math.inf for v in scales)):
        raise ParamError(f"{p}.noise_scales = {scales!r}: must list positive numbers")
    return KalmanNet(
        split=_split_name(tree, p, splits), base=base, cell=cell, hidden=_integer(tree, "hidden", p, 1),
        noise_std=float(tree["noise_std"]), manoeuvre_time_s=float(tree["manoeuvre_time_s"]),
        velocity_std_mps=_positive(tree, "velocity_std_mps", p),
        acceleration_std_mps2=_positive(tree, "acceleration_std_mps2", p), r0_scale=float(tree["r0_scale"]),
        **amplitudes, velocity_scale_mps=_positive(tree, "velocity_scale_mps", p),
        nis_scale=_positive(tree, "nis_scale", p), restart_gap_s=_positive(tree, "restart_gap_s", p),
        burn_in_updates=burn_in, segment_plots=segment_plots, truncation_steps=truncation,
        batch_segments=_integer(tree, "batch_segments", p, 1), epochs=_integer(tree, "epochs", p, 1),
        learning_rate=_positive(tree, "learning_rate", p), seed=_integer(tree, "seed", p),
        baselines=tuple(baselines), baseline_epochs=_integer(tree, "baseline_epochs", p, 1),
        baseline_learning_rate=_positive(tree, "baseline_learning_rate", p),
        noise_scales=tuple(float(v) for v in scales), noise_seed=_integer(tree, "noise_seed", p))


def _bias_lengths(tree: Mapping[str, Any], key: str, p: str) -> tuple[float, ...]:
    """A non-empty list of finite non-negative bias lengths (m)."""
    biases = _get(tree, key, p)
    if (not isinstance(biases, list) or not biases or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v < math.inf for v in biases)):
        raise ParamError(f"{p}.{key} = {biases!r}: must list non-negative numbers")
    return tuple(float(v) for v in biases)


def _association(tree: Mapping[str, Any]) -> Association:
    """Checked before anything trains: the target count fits the scene tensor, the double threshold fits the
    track history, the scene tensor is large enough for the network's convolutions."""
    p = "association"
    low, high = _interval(tree, "targets", p, 1)
    if low != int(low) or high != int(high):
        raise ParamError(f"{p}.targets = {[low, high]}: must be whole numbers")
    size = _integer(tree, "scene_size", p, MIN_SCENE_SIZE)
    if high > size:
        raise ParamError(f"{p}.targets = {[int(low), int(high)]}: more targets than scene_size = {size} tracks")
    track_points = _integer(tree, "track_points", p, 2)
    hits = _integer(tree, "double_threshold_hits", p, 1)
    if hits > track_points - 1:
        raise ParamError(f"{p}.double_threshold_hits = {hits}: above the track history of track_points - 1 = "
                         f"{track_points - 1} times")
    tracks = _text(tree, "tracks", p)
    if tracks not in TRACK_MODELS:
        raise ParamError(f"{p}.tracks = {tracks!r}: must be one of {TRACK_MODELS}")
    noise = _get(tree, "noise_m", p)
    if (not isinstance(noise, list) or len(noise) != 2 or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < math.inf for v in noise)):
        raise ParamError(f"{p}.noise_m = {noise!r}: must be two positive numbers (radar 1's and radar 2's sigma)")
    return Association(
        targets=(int(low), int(high)), area_m=_positive(tree, "area_m", p),
        scan_period_s=_positive(tree, "scan_period_s", p), track_points=track_points,
        noise_m=(float(noise[0]), float(noise[1])),
        detection_probability=_number(tree, "detection_probability", p, 0.0, 1.0, low_open=True),
        speed_mps=_positive_interval(tree, "speed_mps", p),
        acceleration_std_mps2=_number(tree, "acceleration_std_mps2", p, 0.0), tracks=tracks,
        train_bias_m=_interval(tree, "train_bias_m", p), eval_bias_m=_bias_lengths(tree, "eval_bias_m", p),
        eval_scenes=_integer(tree, "eval_scenes", p, 1), eval_seed=_integer(tree, "eval_seed", p),
        gate_probability=_number(tree, "gate_probability", p, 0.0, 1.0, low_open=True, high_open=True),
        double_threshold_hits=hits, max_bias_m=_positive(tree, "max_bias_m", p),
        vote_radius_m=_positive(tree, "vote_radius_m", p), max_iterations=_integer(tree, "max_iterations", p, 1),
        max_time_offset_s=_number(tree, "max_time_offset_s", p, 0.0),
        scene_size=size, scene_diameter_m=_positive(tree, "scene_diameter_m", p),
        feature_hidden=_sizes(tree, "feature_hidden", p), decision_hidden=_integer(tree, "decision_hidden", p, 1),
        decision_threshold=_number(tree, "decision_threshold", p, 0.0, 1.0, low_open=True, high_open=True),
        epochs=_integer(tree, "epochs", p, 1), scenes_per_epoch=_integer(tree, "scenes_per_epoch", p, 1),
        scenes_per_batch=_integer(tree, "scenes_per_batch", p, 1), learning_rate=_positive(tree, "learning_rate", p),
        seed=_integer(tree, "seed", p))


def _lstm_update(tree: Mapping[str, Any], splits: tuple[Split, ...], windows: Windows) -> LSTMUpdate:
    """Checked before anything trains: dropout in [0, 1), at least one MC sample, training sequences
    no shorter than the hold-out windows the estimator is scored on (`windows.filter_length`), the
    truncation and burn-in within a sequence."""
    p = "lstm_update"
    segment_plots = _integer(tree, "segment_plots", p, 2)
    if segment_plots < windows.filter_length:
        raise ParamError(f"{p}.segment_plots = {segment_plots}: shorter than the hold-out windows it is scored on "
                         f"(windows.filter_length = {windows.filter_length})")
    truncation = _integer(tree, "truncation_steps", p, 1)
    if truncation > segment_plots:
        raise ParamError(f"{p}.truncation_steps = {truncation}: longer than the training sequences "
                         f"(segment_plots = {segment_plots})")
    burn_in = _integer(tree, "burn_in_updates", p)
    if burn_in >= segment_plots:
        raise ParamError(f"{p}.burn_in_updates = {burn_in}: leaves nothing of a {segment_plots}-plot sequence to score")
    ages = _integer(tree, "calibration_ages", p, 1)
    if ages >= segment_plots:
        raise ParamError(f"{p}.calibration_ages = {ages}: not younger than the validation windows it is fitted on "
                         f"(segment_plots = {segment_plots})")
    shares = _get(tree, "range_shares", p)
    if (not isinstance(shares, list) or not shares or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v <= 1 for v in shares)):
        raise ParamError(f"{p}.range_shares = {shares!r}: must list shares of the range, in (0, 1]")
    return LSTMUpdate(
        split=_split_name(tree, p, splits), hidden=_integer(tree, "hidden", p, 1),
        dropout=_number(tree, "dropout", p, 0.0, 1.0, high_open=True), mc_samples=_integer(tree, "mc_samples", p, 1),
        detach_prediction=_boolean(tree, "detach_prediction", p),
        position_scale_m=_positive(tree, "position_scale_m", p),
        velocity_scale_mps=_positive(tree, "velocity_scale_mps", p),
        acceleration_scale_mps2=_positive(tree, "acceleration_scale_mps2", p),
        time_scale_s=_positive(tree, "time_scale_s", p), initial_alpha=_number(tree, "initial_alpha", p, 0.0, 1.0),
        initial_beta=_number(tree, "initial_beta", p, 0.0, 2.0), floor_m=_positive(tree, "floor_m", p),
        start_velocity_std_mps=_positive(tree, "start_velocity_std_mps", p),
        restart_gap_s=_positive(tree, "restart_gap_s", p), burn_in_updates=burn_in, segment_plots=segment_plots,
        truncation_steps=truncation, batch_segments=_integer(tree, "batch_segments", p, 1),
        epochs=_integer(tree, "epochs", p, 1), learning_rate=_positive(tree, "learning_rate", p),
        seed=_integer(tree, "seed", p),
        validation_fraction=_number(tree, "validation_fraction", p, 0.0, 1.0, low_open=True, high_open=True),
        calibration_ages=ages, calibration_gaps=_integer(tree, "calibration_gaps", p, 1),
        turn_share=_number(tree, "turn_share", p, 0.0, 1.0, low_open=True, high_open=True),
        range_shares=tuple(float(v) for v in shares))


def _associate(tree: Mapping[str, Any]) -> Associate:
    """Every knob checked; the fusion criterion one of track_fusion's."""
    p = "associate"
    max_age = _positive(tree, "max_age_s", p)
    criterion = _text(tree, "fusion_criterion", p)
    return Associate(step_s=_positive(tree, "step_s", p), max_age_s=max_age,
                     velocity_baseline_s=_positive(tree, "velocity_baseline_s", p),
                     acceleration_std_mps2=_number(tree, "acceleration_std_mps2", p, 0.0), fusion_criterion=criterion,
                     keep_probability=_number(tree, "keep_probability", p, 0.0, 1.0, low_open=True, high_open=True),
                     max_speed_mps=_positive(tree, "max_speed_mps", p))


FUSION_BIAS_KEYS = ("bias_range_m", "bias_azimuth_deg", "bias_east_m", "bias_north_m")


def _fusion_radar(entry: Any, index: int, radar_tree: Mapping[str, Any]) -> FusionRadar:
    """An entry of fusion.radars: params' radar with the entry's radar keys changed (checked as `radar` is), its
    biases and seed."""
    p = f"fusion.radars[{index}]"
    if not isinstance(entry, Mapping):
        raise ParamError(f"{p} = {entry!r}: must be a mapping of radar keys, biases and seed")
    changes = {key: entry[key] for key in entry if key not in (*FUSION_BIAS_KEYS, "seed")}
    radar_keys = [field.name for field in fields(Radar)]
    unknown = sorted(set(changes) - set(radar_keys))
    if unknown:
        raise ParamError(f"{p}.{unknown[0]}: unknown key (a radar key, one of {FUSION_BIAS_KEYS} or seed)")
    # only the radar's known keys are taken from `radar`: a misspelt one there stays unread, hence an error
    base = {key: radar_tree[key] for key in radar_keys if key in radar_tree}
    try:
        radar = _radar({**base, **changes})
    except ParamError as error:
        raise ParamError(f"{p}: {error}") from None
    return FusionRadar(radar, *(_number(entry, key, p) for key in FUSION_BIAS_KEYS), _integer(entry, "seed", p))


def _fusion(tree: Mapping[str, Any], radar_tree: Mapping[str, Any]) -> Fusion:
    """Two radars of distinct ids (track-to-track association pairs two radars' tracks); registered methods."""
    p = "fusion"
    entries = _get(tree, "radars", p)
    if not isinstance(entries, list) or len(entries) != 2:
        raise ParamError(f"{p}.radars = {entries!r}: must list two radars (association pairs two radars' tracks)")
    radars = tuple(_fusion_radar(entry, index, radar_tree) for index, entry in enumerate(entries))
    if radars[0].radar.radar_id == radars[1].radar.radar_id:
        raise ParamError(f"{p}.radars: both radars have id {radars[0].radar.radar_id} (sac * 256 + sic): give the "
                         "second its own sic")
    tracker = _text(tree, "tracker", p)
    methods = _get(tree, "methods", p)
    if not isinstance(methods, list):
        raise ParamError(f"{p}.methods = {methods!r}: must be a list of association method names")
    scenes = _integer(tree, "scenes", p, 1)
    sweep_scenes = _integer(tree, "sweep_scenes", p, 1)
    if sweep_scenes > scenes:
        raise ParamError(f"{p}.sweep_scenes = {sweep_scenes}: must be at most {p}.scenes = {scenes} (the sweep reads "
                         "the fusion stage's first scenes)")
    return Fusion(scenes=scenes, tracker=tracker, window_m=_positive(tree, "window_m", p), methods=tuple(methods),
                  radars=radars, sweep_scenes=sweep_scenes, sweep_bias_m=_bias_lengths(tree, "sweep_bias_m", p))


def parse_tree(tree: Mapping[str, Any], name_checks: Sequence[Callable[[Params], None]] = ()) -> Params:
    """Validate a params tree (as read from YAML) and return typed params; a key the parser
    never reads is an error, so that a misspelt key cannot leave a run on the old value.

    The names of tracking methods, track management rules, associators and fusion criteria belong to
    their registries, which this ground-floor module does not import: `name_checks` (each raising
    ParamError) check them, before the rules across sections, so that a misspelt method is named as
    such (`pipeline.settings.parse_params` passes every registry's)."""
    tree = _Section(tree, "")
    radar = _radar(_get(tree, "radar", "params"))
    aircraft_tree = _get(tree, "aircraft", "params")
    if not isinstance(aircraft_tree, Mapping) or not aircraft_tree:
        raise ParamError(f"aircraft = {aircraft_tree!r}: must define at least one aircraft type")
    aircraft = {name: _aircraft(name, aircraft_tree[name]) for name in aircraft_tree}
    simulate = _get(tree, "simulate", "params")
    windows = _windows(_get(tree, "windows", "params"))
    routes = _routes(_get(tree, "routes", "params"), aircraft, radar)
    scenes = _scenes(_get(tree, "scenes", "params"), aircraft, radar)
    report = _get(tree, "report", "params")
    params = Params(
        radar=radar,
        aircraft=aircraft,
        routes=routes,
        scenes=scenes,
        simulate_seed=_integer(simulate, "seed", "simulate"),
        example_routes=_integer(report, "example_routes", "report", 1),
        windows=windows,
        training=_training(_get(tree, "training", "params"), windows),
        tracker=_tracker(_get(tree, "tracker", "params"), windows),
        kalman=_kalman(_get(tree, "kalman", "params"), routes.splits),
        kalman_net=_kalman_net(_get(tree, "kalman_net", "params"), routes.splits),
        association=_association(_get(tree, "association", "params")),
        lstm_update=_lstm_update(_get(tree, "lstm_update", "params"), routes.splits, windows),
        evaluate=_evaluate(_get(tree, "evaluate", "params"), routes.splits),
        workers=_integer(_get(tree, "compute", "params"), "workers", "compute", 1),
        associate=_associate(_get(tree, "associate", "params")),
        fusion=_fusion(_get(tree, "fusion", "params"), _get(tree, "radar", "params")),
        chunk_plots=_integer(_get(tree, "compute", "params"), "chunk_plots", "compute", 1),
    )
    unknown = tree.unread()
    if unknown:
        raise ParamError("; ".join(unknown))
    for check in name_checks:
        check(params)
    if params.associate.keep_probability < params.association.gate_probability:
        raise ParamError(f"associate.keep_probability = {params.associate.keep_probability}: must be at least "
                         f"association.gate_probability = {params.association.gate_probability} (a pair is kept "
                         "on a gate no tighter than the one it was formed on)")
    fastest = max(aircraft.values(), key=lambda a: a.speed_max_mps)
    if params.associate.max_speed_mps <= fastest.speed_max_mps:
        raise ParamError(f"associate.max_speed_mps = {params.associate.max_speed_mps}: must exceed the fastest "
                         f"aircraft's speed ({fastest.name}: {fastest.speed_max_mps} m/s), or its tracks would be "
                         "refused as two aircraft under one track id")
    return params


class ParamsLoader(yaml.SafeLoader):
    """PyYAML's safe loader, reading floats as YAML 1.2 does.

    DVC writes params.yaml as YAML 1.2: `dvc exp run -S training.predictor.learning_rate=0.000001`
    gives `learning_rate: 1e-06`, which YAML 1.1 (PyYAML) takes for a string. Every float
    YAML 1.2 accepts (1e-06, 2e-3, 1E-4, -.5, 5.) is read as a float here; plain integers still
    resolve as integers, because the float pattern needs a point or an exponent."""


ParamsLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:(?:[0-9]+\.[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?|[0-9]+[eE][-+]?[0-9]+)$"),
    list("-+0123456789."))


def load_params_tree(path: str | Path = "params.yaml") -> dict[str, Any]:
    """The params file as a plain tree, read as DVC reads it (see ParamsLoader), not validated."""
    path = Path(path)
    try:
        tree = yaml.load(path.read_text(), Loader=ParamsLoader)
    except FileNotFoundError:
        raise ParamError(f"{path}: params file not found") from None
    except (OSError, UnicodeDecodeError) as error:  # a folder, an unreadable file, a binary file
        raise ParamError(f"{path}: not a readable params file ({type(error).__name__}: {error})") from None
    except yaml.YAMLError as error:
        raise ParamError(f"{path}: not valid YAML ({error})") from None
    if not isinstance(tree, Mapping):
        raise ParamError(f"{path}: must hold a mapping of sections, got {type(tree).__name__}")
    return tree


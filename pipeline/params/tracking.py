"""The tracker's, the evaluation's and the two radars' sections, and `Params`, the whole file (params.yaml
`tracker`, `evaluate`, `associate`, `fusion`, and `simulate`, `report` and `compute`'s single knobs)."""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

from pipeline.params.declare import ParamError, Section, Tracked, build, get, given, knob, parse_section, positive
from pipeline.params.learning import Association, Confirmation, KalmanNet, Kalman, LSTMUpdate, Training
from pipeline.params.world import Aircraft, Radar, Routes, Scenes, Windows, split_knob

MAX_CONFIRM_N = 52  # an M-of-N track's last confirm_n opportunities are the bits of its weight (a double's 53)
SITE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")  # a site's name labels report rows and keys
DEVICE = re.compile(r"cpu|cuda(:[0-9]+)?")  # tracker.device: torch's names of the CPU and of CUDA devices
LEARNED_RUNTIMES = ("script", "eager")  # tracker.learned_runtime (pipeline/learning/step_runtime.py)


@dataclass(frozen=True)
class Management(Section):
    """`tracker.management`: the track management rules of every tracker (pipeline/tracker/management.py,
    m_of_n.py, sprt.py): the rule of every run that names none, the thesis's weights, the M-of-N rule's and the
    SPRT's knobs."""

    rule: str = knob("track management of every run that names none: thesis (the weights), m_of_n (Blackman "
                     "& Popoli 1999 M/N confirmation, time-out deletion) or sprt (the sequential probability ratio "
                     "test on hits and misses, Blackman & Popoli 1999 6.2)")
    weight_start: float = positive("a new track's weight; weights rise: start < candidate < confirmed")
    weight_candidate: float = positive("a candidate track's weight")
    weight_confirmed: float = positive("a confirmed (mature) track's weight")
    weight_step: float = positive("+ per association, - per silence period")
    silence_s: float = positive("no association and no weight change for this long: weight - step ...")
    silence_scans: float = knob("... or for this many scans of the radar of the track's latest plot, if longer "
                                "(ours, issue 27; 0: seconds only)", 0.0)
    confirm_m: int = knob("m_of_n: confirmed at the association making this many hits, at most confirm_n ...", 1)
    confirm_n: int = knob("... within the last this many opportunities (scans of the latest plot's radar)", 1,
                          MAX_CONFIRM_N)
    delete_after_s: float = positive("m_of_n: a confirmed track silent longer than this ...")
    delete_after_scans: float = knob("... and than this many scans of its latest plot's radar is deleted", 0.0)
    sprt_detection_probability: float = knob("sprt: P_D, an aircraft's plot in its track's gate in a scan", 0.0, 1.0,
                                             open_low=True, open_high=True)
    sprt_false_plot_probability: float = knob("sprt: P_F, a false plot in a clutter track's gate in a scan (below "
                                              "P_D)", 0.0, 1.0, open_low=True, open_high=True)
    sprt_false_track_probability: float = knob("sprt: alpha, the test's risk of confirming a clutter track", 0.0, 1.0,
                                               open_low=True, open_high=True)
    sprt_lost_track_probability: float = knob("sprt: beta, its risk of deleting an aircraft's track (alpha + beta "
                                              "< 1)", 0.0, 1.0, open_low=True, open_high=True)
    learned_false_track_probability: float = knob("learned (pipeline/tracker/learned_confirmation.py, over confirm_n "
                                                   "opportunities, deleting as m_of_n): the share of clutter's "
                                                   "candidate tracks (of two plots or more) it confirms, which sets "
                                                   "its threshold", 0.0, 1.0,
                                                   open_low=True, open_high=True)

    def check(self, path: str, context: Mapping[str, Any]) -> Management:
        if self.sprt_false_plot_probability >= self.sprt_detection_probability:
            raise ParamError(f"{path}.sprt_false_plot_probability = {self.sprt_false_plot_probability}: must be below "
                             f"{path}.sprt_detection_probability = {self.sprt_detection_probability} (a hit would "
                             "then speak for clutter)")
        if self.sprt_false_track_probability + self.sprt_lost_track_probability >= 1.0:
            raise ParamError(f"{path}.sprt_false_track_probability + sprt_lost_track_probability = "
                             f"{self.sprt_false_track_probability} + {self.sprt_lost_track_probability}: must be below 1")
        if self.confirm_m > self.confirm_n:
            raise ParamError(f"{path}.confirm_m = {self.confirm_m}: must not exceed {path}.confirm_n = "
                             f"{self.confirm_n}")
        if not self.weight_start < self.weight_candidate < self.weight_confirmed:
            raise ParamError(f"{path}: weights must rise: weight_start {self.weight_start} < weight_candidate "
                             f"{self.weight_candidate} < weight_confirmed {self.weight_confirmed}")
        return self


@dataclass(frozen=True)
class Candidates(Section):
    """`tracker.association`: which tracks a plot is offered to and how young tracks are gated, shared by every
    tracking method (pipeline/tracker/run.py, gate.py, registry.py)."""

    prefilter_m: float = positive("a plot farther than this from every track starts a new track")
    mature_first: bool = knob("a plot inside a mature track's gate is not offered to young tracks (ours)")
    revisit_scans: float = knob("a track that took a plot of a radar is offered no other of that radar within this "
                                "many of its scans (issue 27; 0: off)", 0.0, 1.0, open_high=True)
    young_track_plots: int = knob("below this many plots a track is gated by the constant radius (VIA, MIA)", 1)
    young_track_plots_ae: int = knob("... and for the autoencoder method", "windows.autoencoder_length")
    kalman_gate_probability: float = knob("the classical trackers' chi-square gate (3 degrees of freedom)", 0.0, 1.0,
                                          open_low=True, open_high=True)
    jpda_detection_probability: float = knob("JPDA (the *_jpda methods, pipeline/tracker/jpda.py): P_D, an aircraft's "
                                             "plot in a scan", 0.0, 1.0, open_low=True, open_high=True)
    jpda_clutter_density_per_m3: float = positive("JPDA: lambda, false plots per cubic metre in a scan")


@dataclass(frozen=True)
class Networks(Section):
    """`tracker.networks`: the thesis networks' tracker (pipeline/tracker/network_estimator.py)."""

    filter_plots: int = knob("with this many plots the filter network updates the state: windows.filter_length", 1)

    def check(self, path: str, context: Mapping[str, Any]) -> Networks:
        windows = context["windows"]
        if self.filter_plots != windows.filter_length:
            raise ParamError(f"{path}.filter_plots = {self.filter_plots}: the filter network reads "
                             f"windows.filter_length = {windows.filter_length} plots")
        return self


@dataclass(frozen=True)
class MIA(Section):
    """`tracker.mia`: the MIA method's sampled gate (thesis 4.6; pipeline/tracker/network_gates.py)."""

    samples: int = knob("MIA's samples", 2)
    ball_radius_m: float = positive("MIA's samples are normal (sigma = radius / 3), clipped to this ball")
    k_no_padding: float = positive("MIA's K when no state is padded ...")
    k_padded_base: float = positive("... else K = base - number of padded states")


@dataclass(frozen=True)
class LSTMUpdateGate(Section):
    """`tracker.lstm_update`: how the lstm_update method's tracker gates (pipeline/tracker/registry.py; the
    network's own knobs are params' `lstm_update`)."""

    gate_m: float = positive("the lstm_update method's chi-square gate takes no plot further than this from the "
                             "prediction (issue 18)")
    young_window_fallback: bool = knob("lstm_update's young tracks also take a plot within window_m (issue 27)")


@dataclass(frozen=True)
class TrackerParams(Section):
    """`tracker`: the neural tracker (thesis 4.4-4.6; pipeline/tracker/) and every tracker's management, its knobs
    grouped by the component that reads them (as Stone Soup keeps knobs on their components)."""

    seed: int = knob("MIA sampling", 0)
    inference: str = knob("the thesis networks: onnx (ONNX Runtime, ~5x faster per call) or torch; same outputs",
                          choices=("onnx", "torch"))
    refusal_warning_share: float = knob("`track` warns when a learned gate refused this share of the plots within "
                                        "window_m of a track it scored", 0.0, 1.0, open_low=True)
    management: Management = knob("the track management rules")
    association: Candidates = knob("candidates and gating shared by every method")
    networks: Networks = knob("the thesis networks' tracker")
    mia: MIA = knob("the MIA method's gate")
    lstm_update: LSTMUpdateGate = knob("the lstm_update method's gate")
    learned_runtime: str = knob("kalman_net's and lstm_update's batched steps: script (traced to TorchScript, up to "
                                "2.6x faster per call, the same bits) or eager (issue 29; pipeline/learning/"
                                "step_runtime.py)",
                                choices=LEARNED_RUNTIMES, default="script")
    device: str = knob("where kalman_net's and lstm_update's batched steps run: cpu, cuda or cuda:N (a CUDA device; "
                       "an error where torch sees none); issue 29, pipeline/learning/devices.py", default="cpu")

    def check(self, path: str, context: Mapping[str, Any]) -> TrackerParams:
        if not DEVICE.fullmatch(self.device):
            raise ParamError(f"{path}.device = {self.device!r}: must be cpu, cuda or cuda:N")
        return self


@dataclass(frozen=True)
class EvaluationRun(Section):
    """`evaluate.runs[]`: one evaluation run: a method, its window (m) and, if the run names one, its track
    management rule (None: the tracker's, `tracker.management.rule`); or a reference of `evaluate.references`
    (`reference`: the raw plots or the oracle, no window of its own: 0)."""

    method: str = knob("a tracking method of the tracker's registry")
    window_m: float = positive("its association window (the young tracks' radius)")
    management: str | None = knob("its track management rule (absent: tracker.management.rule)", default=None)
    reference: bool = given(False)

    @property
    def name(self) -> str:
        """`<method>_<window>`, and `_<rule>` when the run names its rule (`imm_4000_m_of_n`);
        `<method>_reference` for a reference (`oracle_reference`). The reports' key of the run."""
        if self.reference:
            return f"{self.method}_reference"
        base = f"{self.method}_{self.window_m:.0f}"
        return base if self.management is None else f"{base}_{self.management}"


@dataclass(frozen=True)
class Site(Section):
    """`evaluate.sites[]`: a radar site other than the training one, where `evaluate_sites` flies the routes."""

    name: str = knob("an identifier (letters, digits, _; not a digit first): labels report rows")
    latitude_deg: float = knob("site latitude", -90.0, 90.0)
    longitude_deg: float = knob("site longitude (the antimeridian once, as +180)", -180.0, 180.0, open_low=True)
    height_m: float = knob("antenna height above the WGS-84 ellipsoid", -500.0, 10000.0)

    def check(self, path: str, context: Mapping[str, Any]) -> Site:
        if not SITE_NAME.fullmatch(self.name):
            raise ParamError(f"{path}.name = {self.name!r}: must be an identifier (letters, digits, _; not a digit "
                             "first)")
        return self


NAMES = "must list distinct names of the runs {} ([]: all of them)"


@dataclass(frozen=True)
class Evaluate(Section):
    """`evaluate`: every method x window over the test split (thesis tables 5.1, 5.2), and the references."""

    split: str = split_knob("the split whose scenarios are tracked")
    runs: tuple[EvaluationRun, ...] = knob("the runs, at least one, names distinct")
    references: tuple[str, ...] = knob("raw target plots and the tuned IMM given the true association",
                                       why="must be a list of reference names")
    ospa_cutoff_m: float = positive("OSPA cutoff c (a missed or false track costs c) ...")
    ospa_order: float = positive("... and order p")
    gospa_cutoff_m: float = positive("GOSPA (alpha = 2, pipeline/bench/gospa.py) cutoff c ...")
    gospa_order: float = knob("... and order p (GOSPA is a metric for p >= 1)", 1.0)
    seeds: int = knob("draws of noise, detections and clutter each evaluation repeats over the same routes "
                      "(1: the simulate stage's alone; draw k > 0 simulates the split again with a seed from "
                      "(simulate.seed, k))", 1, 1000)
    bootstrap_replicates: int = knob("resamples of the units behind every metric's confidence interval "
                                     "(pipeline/bench/intervals.py: the paired percentile bootstrap)", 20, 1_000_000)
    confidence: float = knob("... the intervals' level (0.95: 95 % intervals)", 0.5, 1.0, open_high=True)
    bootstrap_seed: int = knob("... and the resamples' seed", 0)
    example_scenarios: int = knob("scenarios drawn in reports/tracks/scenario_<id>.png ...", 0)
    example_run: str = knob("... tracked by this run of runs (<method>_<window>)")
    sites: tuple[Site, ...] = knob("evaluate_sites: the same routes at these radar sites ([]: none)")
    site_runs: tuple[str, ...] = knob("evaluate_sites: the runs (by name) scored at the sites ([]: every run)")
    scene_runs: tuple[str, ...] = knob("evaluate_scenes: the runs (by name) scored on the scenes ([]: every run); "
                                       "holds example_run")

    def runs_at_sites(self) -> tuple[EvaluationRun, ...]:
        """The runs `evaluate_sites` scores: those `site_runs` names, in `runs` order, or all of them."""
        return tuple(run for run in self.runs if not self.site_runs or run.name in self.site_runs)

    def runs_on_scenes(self) -> tuple[EvaluationRun, ...]:
        """The runs `evaluate_scenes` scores: those `scene_runs` names, in `runs` order, or all of them."""
        return tuple(run for run in self.runs if not self.scene_runs or run.name in self.scene_runs)

    def reference_runs(self) -> tuple[EvaluationRun, ...]:
        """The references as runs, in `references` order (`plots_reference`, `oracle_reference`)."""
        return tuple(EvaluationRun(method, 0.0, reference=True) for method in self.references)

    def check(self, path: str, context: Mapping[str, Any]) -> Evaluate:
        if not self.runs:
            raise ParamError(f"{path}.runs = []: must list at least one {{method, window_m}}")
        names = [run.name for run in self.runs]
        if len(set(names)) != len(names):
            raise ParamError(f"{path}.runs: {names} repeats a method, window and management rule")
        if self.example_run not in names:
            raise ParamError(f"{path}.example_run = {self.example_run!r}: not one of the runs {names}")
        for key in ("site_runs", "scene_runs"):
            chosen = getattr(self, key)
            if any(name not in names for name in chosen) or len(set(chosen)) != len(chosen):
                raise ParamError(f"{path}.{key} = {list(chosen)!r}: {NAMES.format(names)}")
        if self.scene_runs and self.example_run not in self.scene_runs:
            raise ParamError(f"{path}.scene_runs = {list(self.scene_runs)}: must include evaluate.example_run = "
                             f"{self.example_run!r}, whose tracks reports/scene_example.png draws")
        sites = [site.name for site in self.sites]
        if len(set(sites)) != len(sites):
            raise ParamError(f"{path}.sites: names {sites} repeat")
        return self


@dataclass(frozen=True)
class Associate(Section):
    """`associate` (ours, issue 19): `python -m pipeline associate` on two users' track tables
    (pipeline/association/common_time_states.py); the methods' own knobs are association's."""

    step_s: float = positive("tracks are compared at common times this far apart over the tables' overlap")
    max_age_s: float = positive("a track whose last update is older than this at a common time is left out there")
    velocity_baseline_s: float = positive("a track's velocity from its last update and its latest one at least this "
                                          "much earlier")
    acceleration_std_mps2: float = knob("white-noise acceleration per axis of the extrapolation to the common time",
                                        0.0)
    fusion_criterion: str = knob("trace or determinant: what covariance intersection minimises (Julier & Uhlmann "
                                 "1997; track_fusion.CRITERIA)")
    keep_probability: float = knob("association with memory: last time's pairs kept while their chi-square statistic "
                                   "is under this quantile (at least association.gate_probability)", 0.0, 1.0,
                                   open_low=True, open_high=True)
    max_speed_mps: float = positive("two consecutive updates of one track implying a faster speed are two aircraft "
                                    "under one id (above every aircraft type's speed_mps)")


@dataclass(frozen=True)
class FusionRadar(Section):
    """`fusion.radars[]`: one radar of the fusion stage: what it is (`radar`, params' `radar` with the entry's
    keys changed), its registration bias (the tracker believes the radar that much away from where it is)
    and the seed of its detections, noise and clutter (in place of simulate.seed)."""

    radar: Radar = given()
    bias_range_m: float = knob("registration bias in range")
    bias_azimuth_deg: float = knob("registration bias in azimuth")
    bias_east_m: float = knob("site error east")
    bias_north_m: float = knob("site error north")
    seed: int = knob("its detections, noise and clutter", 0)


def _fusion_radars(tree: Mapping[str, Any], key: str, path: str, context: Mapping[str, Any]) -> tuple:
    """Two entries of params' radar with the entry's radar keys changed (checked as `radar` is), each of its biases
    and seed."""
    entries = get(tree, key, path)
    if not isinstance(entries, list) or len(entries) != 2:
        raise ParamError(f"{path}.{key} = {entries!r}: must list two radars (association pairs two radars' tracks)")
    biases = tuple(field.name for field in dataclasses.fields(FusionRadar) if field.name.startswith("bias_"))
    own = (*biases, "seed")
    radar_keys, radar_tree = [field.name for field in dataclasses.fields(Radar)], context["tree"]["radar"]
    radars = []
    for index, entry in enumerate(entries):
        here = f"{path}.{key}[{index}]"
        if not isinstance(entry, Mapping):
            raise ParamError(f"{here} = {entry!r}: must be a mapping of radar keys, biases and seed")
        changes = {name: entry[name] for name in entry if name not in own}
        unknown = sorted(set(changes) - set(radar_keys))
        if unknown:
            raise ParamError(f"{here}.{unknown[0]}: unknown key (a radar key, one of {biases} or seed)")
        # only the radar's known keys are taken from `radar`: a misspelt one there stays unread, hence an error
        base = {name: radar_tree[name] for name in radar_keys if name in radar_tree}
        try:
            radar = parse_section(Radar, {**base, **changes}, "radar", context)
        except ParamError as error:
            raise ParamError(f"{here}: {error}") from None
        radars.append(parse_section(FusionRadar, entry, here, context, dict(radar=radar)))
    if radars[0].radar.radar_id == radars[1].radar.radar_id:
        raise ParamError(f"{path}.{key}: both radars have id {radars[0].radar.radar_id} (sac * 256 + sic): give the "
                         "second its own sic")
    return tuple(radars)


@dataclass(frozen=True)
class Fusion(Section):
    """`fusion` (ours, issue 19; pipeline/bench/radar_fusion.py): the multi-target scenes seen by two radars, each
    tracked alone, their tracks associated by every method and fused; GOSPA of each picture."""

    scenes: int = knob("the first this many scenes of scenes:", 1)
    tracker: str = knob("each radar's local tracker: one giving covariances (not radius, via, mia or ae)")
    window_m: float = positive("its association window")
    methods: tuple[str, ...] = knob("track-to-track association methods compared (distinct)",
                                    why="must be a list of association method names")
    radars: tuple[FusionRadar, FusionRadar] = knob("exactly two: params' radar with the entry's keys changed (any "
                                                   "radar key), its registration bias and its seed",
                                                   read=_fusion_radars)
    sweep_scenes: int = knob("the bias sweep (fusion_bias_sweep) on the first this many scenes, at most scenes", 1)
    sweep_bias_m: tuple[float, ...] = knob("radar 2's site error lengths there (its range and azimuth biases 0)", 0.0)

    def check(self, path: str, context: Mapping[str, Any]) -> Fusion:
        if self.sweep_scenes > self.scenes:
            raise ParamError(f"{path}.sweep_scenes = {self.sweep_scenes}: must be at most {path}.scenes = "
                             f"{self.scenes} (the sweep reads the fusion stage's first scenes)")
        return self


STONE_SOUP_ASSOCIATIONS = ("gnn", "jpda")  # pipeline/peers/stone_soup.py: GNNWith2DAssignment, JPDAwithEHM


@dataclass(frozen=True)
class Scorecard(Section):
    """`scorecard` (ours, issue 32): the surveillance scorecard's choices where EUROCAE ED-129C and the ECAC
    guidelines leave one open (pipeline/surveillance/scorecard.py); the update interval is the radar's scan
    period. Read by the peers stage and by `python -m pipeline score`."""

    association_m: float = positive("an update farther than this from every target goes to none (a false update)")
    miss_tolerance_scans: float = knob("a gap up to (1 + this) update intervals is no miss (a plot's place in the "
                                       "scan moves it by a fraction of one)", -1.0, open_low=True)
    long_gap_scans: float = positive("a long gap is longer than this many update intervals (ED-129C: 3 x 1.1)")
    manoeuvre_mps2: float = positive("an update is manoeuvring where the target's true horizontal acceleration "
                                     "exceeds this")


@dataclass(frozen=True)
class StoneSoupPeer(Section):
    """`peers.stone_soup` (ours, issue 33): Stone Soup's trackers as pipeline/peers/stone_soup.py sets them up: our
    tuned CV model and the chi-square gate of tracker.association.kalman_gate_probability; the rest here."""

    associations: tuple[str, ...] = knob("the Stone Soup trackers run: gnn (GNNWith2DAssignment), jpda (JPDAwithEHM)",
                                         choices=STONE_SOUP_ASSOCIATIONS,
                                         why=f"must list distinct names of {STONE_SOUP_ASSOCIATIONS}")
    min_points: int = knob("updates that confirm a track (MultiMeasurementInitiator; the tutorials' 3)", 1, 100)
    delete_after_s: float = positive("a track without an update for this long is deleted (UpdateTimeDeleter)")
    batch_window_s: float = knob("plots this close in time are one batch, associated at one time (s)", 0.0, 1.0,
                                 open_low=True)
    detection_probability: float = knob("JPDA's probability of detection", 0.0, 1.0, open_low=True,
                                        open_high=True)
    clutter_density_per_m3: float = positive("JPDA's clutter spatial density")

    def check(self, path: str, context: Mapping[str, Any]) -> StoneSoupPeer:
        if len(set(self.associations)) != len(self.associations):
            raise ParamError(f"{path}.associations = {list(self.associations)}: names repeat")
        return self


@dataclass(frozen=True)
class RealTraffic(Section):
    """`peers.real_traffic` (ours, issue 33): real aircraft (OpenSky state vectors, pipeline/recordings/
    opensky_states.py) flown past params' radar moved to a site (pipeline/simulation/real_traffic.py)."""

    states: str = knob("the OpenSky state-vector CSV, relative to the repository ('': no real-traffic scene)")
    latitude_deg: float = knob("the radar's latitude there", -90.0, 90.0)
    longitude_deg: float = knob("... longitude", -180.0, 180.0, open_low=True)
    height_m: float = knob("... antenna height above the WGS-84 ellipsoid", -500.0, 10000.0)


@dataclass(frozen=True)
class Peers(Section):
    """`peers` (ours, issues 32, 33): the peers stage (pipeline/bench/peers.py): Stone Soup's trackers, our runs and
    the oracle on the same plots, scored by GOSPA and the surveillance scorecard, with intervals."""

    scenarios_per_strategy: int = knob("the first this many scenarios of each route strategy of evaluate.split", 1)
    window_s: float = knob("each of them, and the real-traffic scene, from its first plot for this long (s; 0: "
                           "whole): Stone Soup tracks about 100 plots a second", 0.0)
    scenes: int = knob("the first this many many-aircraft scenes of the scenes stage (0: none) ...", 0)
    scene_window_s: float = knob("... each from its first plot for this long (s; 0: whole): a scene holds 30 "
                                 "aircraft, and Stone Soup tracks it at about 10 plots a second", 0.0)
    runs: tuple[str, ...] = knob("our runs (names of evaluate.runs) set beside Stone Soup's ([]: those of "
                                 "evaluate.scene_runs)", why="must be a list of run names")
    stone_soup: StoneSoupPeer = knob("Stone Soup's trackers")
    real_traffic: RealTraffic = knob("the real-traffic scene")

    def runs_of(self, evaluate: Evaluate) -> tuple[EvaluationRun, ...]:
        """Our runs the peers stage scores: those `runs` names, in `evaluate.runs` order, or the scenes' runs."""
        return tuple(run for run in evaluate.runs if run.name in self.runs) if self.runs else evaluate.runs_on_scenes()


@dataclass(frozen=True)
class Params(Section):
    """The whole params.yaml, section by section."""

    radar: Radar = knob("the simulated radar")
    aircraft: Mapping[str, Aircraft] = knob("the aircraft types by name, at least one")
    routes: Routes = knob("the routes of every split")
    scenes: Scenes = knob("the multi-target scenes")
    simulate_seed: int = knob("radar noise, detections and false plots; independent of route seeds", 0,
                              key="simulate.seed")
    example_routes: int = knob("routes per strategy drawn in reports/data_routes.png", 1, key="report.example_routes")
    windows: Windows = knob("the networks' training windows")
    training: Training = knob("the three networks' training")
    tracker: TrackerParams = knob("the tracker")
    kalman: Kalman = knob("the tuned classical filters")
    kalman_net: KalmanNet = knob("the network-scaled Kalman filter")
    association: Association = knob("track-to-track association on the seed's setting")
    lstm_update: LSTMUpdate = knob("the LSTM update")
    confirmation: Confirmation = knob("the learned track confirmation's network")
    evaluate: Evaluate = knob("the evaluation")
    workers: int = knob("processes for independent work (1: all in the stage's process); no result depends on it",
                        1, key="compute.workers")
    associate: Associate = knob("the associate command")
    fusion: Fusion = knob("the fusion stage")
    scorecard: Scorecard = knob("the surveillance scorecard")
    peers: Peers = knob("the peers stage")
    chunk_plots: int = knob("`track` places, tracks and writes this many plots at a time (same output for any "
                            "value; its memory follows this)", 1, key="compute.chunk_plots")
    progress_every_s: float = knob("long work (`track`) logs a progress line at most this often, s (0: after every "
                                   "chunk)", 0.0, key="compute.progress_every_s")

    def check(self, path: str, context: Mapping[str, Any]) -> Params:
        associate, gate = self.associate, self.association.gate_probability
        if associate.keep_probability < gate:
            raise ParamError(f"associate.keep_probability = {associate.keep_probability}: must be at least "
                             f"association.gate_probability = {gate} (a pair is kept on a gate no tighter than the "
                             "one it was formed on)")
        names = [run.name for run in self.evaluate.runs]
        if any(name not in names for name in self.peers.runs) or len(set(self.peers.runs)) != len(self.peers.runs):
            raise ParamError(f"peers.runs = {list(self.peers.runs)!r}: must list distinct names of the runs {names} "
                             "([]: those of evaluate.scene_runs)")
        fastest = max(self.aircraft.values(), key=lambda a: a.speed_max_mps)
        if associate.max_speed_mps <= fastest.speed_max_mps:
            raise ParamError(f"associate.max_speed_mps = {associate.max_speed_mps}: must exceed the fastest "
                             f"aircraft's speed ({fastest.name}: {fastest.speed_max_mps} m/s), or its tracks would "
                             "be refused as two aircraft under one track id")
        return self


def parse_tree(tree: Mapping[str, Any], name_checks: Sequence[Callable[[Params], None]] = ()) -> Params:
    """Validate a params tree (as read from YAML) and return typed params; a key the parser
    never reads is an error, so that a misspelt key cannot leave a run on the old value.

    The names of tracking methods, track management rules, associators and fusion criteria belong to
    their registries, which this ground-floor package does not import: `name_checks` (each raising
    ParamError) check them, before the rules across sections, so that a misspelt method is named as
    such (`pipeline.settings.parse_params` passes every registry's)."""
    tracked = Tracked(tree, "")
    params = build(Params, tracked, "", {"tree": tracked})
    unknown = tracked.unread()
    if unknown:
        raise ParamError("; ".join(unknown))
    for check in name_checks:
        check(params)
    return params.check("", {})

"""The trained and tuned pieces' sections: the three networks' training, the tuned Kalman filters, the
network-scaled filter, the LSTM update and the track-to-track association network (params.yaml
`training`, `kalman`, `kalman_net`, `lstm_update`, `association`). Each is checked before anything trains."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from pipeline.params.declare import ParamError, Section, get, knob, positive
from pipeline.params.world import split_knob

TUNING_COSTS = ("rmse", "nees", "rmse_in_gate")
KALMAN_NET_BASES = ("cv", "ca", "singer")   # base filters the network can scale (one motion model each)
KALMAN_NET_CELLS = ("gru", "mlp")
GRADIENT_KINDS = ("cv", "ca", "singer", "imm")  # filters tuned by gradient descent
FILTER_KINDS = ("cv", "ca", "imm", "imm_ct", "imm_ca_ct")  # the classical filters (pipeline/filters/classical_filters.py)
REQUIRED_FILTERS = ("cv", "ca", "imm")  # tuned always: the oracle, the bound and the fusion's local trackers run them
TRACK_MODELS = ("kalman", "two_point")          # association.tracks: how the synthetic radars make track points
MIN_SCENE_SIZE = 10                             # association.scene_size: the network's convolutions need this much
NETWORKS = ("filter", "predictor", "autoencoder")
SIZES = "must be a list of positive layer sizes"
PATIENCE = {"early_stopping_patience": ", so it could never stop a run (0 turns early stopping off)",
            "lr_decay_patience": " (0 turns the decay off)"}


@dataclass(frozen=True)
class NetworkTraining(Section):
    """`training.<network>`: one network's design and schedule (the thesis's: fixed 500/500/400 epochs, batch
    128/128/64, Adam at 0.001; ours: batches of 512 at a higher rate, halved on plateaus, stopped early)."""

    hidden: tuple[int, ...] = knob("GRU layer sizes (the autoencoder's encoder)", 1, why=SIZES)
    decoder_hidden: tuple[int, ...] = knob("the autoencoder's decoder GRU sizes", 1, why=SIZES, only=("autoencoder",),
                                           otherwise=())
    output_steps: int = knob("the filter's last plots denoised, at most windows.filter_length (the predictor's: "
                             "windows.predictor_inputs - 1; the autoencoder's: windows.autoencoder_length)", 1,
                             only=("filter",))
    epochs: int = knob("upper bound of the epochs", 1)
    batch_size: int = knob("windows per Adam step", 1)
    learning_rate: float = positive("Adam")
    validation_fraction: float = knob("share of the windows kept for validation (ours)", 0.0, 0.9)
    seed: int = knob("initial weights, batch order and validation choice", 0)
    early_stopping_patience: int = knob("epochs without a better validation loss before stopping; 0 = off", 0)
    early_stopping_min_improvement: float = knob("relative: better means below the best so far x (1 - this)", 0.0, 0.5)
    lr_decay_factor: float = knob("the learning rate is multiplied by this ...", 0.0, 1.0, open_low=True)
    lr_decay_patience: int = knob("... after this many epochs without a better validation loss; 0 = off", 0)

    def check(self, path: str, context: Mapping[str, Any]) -> NetworkTraining:
        windows, kind = context["windows"], context["entry"]
        if kind == "filter" and self.output_steps > windows.filter_length:
            raise ParamError(f"{path}.output_steps = {self.output_steps}: above windows.filter_length = "
                             f"{windows.filter_length}")
        for key, why in PATIENCE.items():
            if getattr(self, key) > self.epochs:
                raise ParamError(f"{path}.{key} = {getattr(self, key)}: above {path}.epochs = {self.epochs}{why}")
        for key in PATIENCE:
            if getattr(self, key) and not self.validation_fraction:
                raise ParamError(f"{path}.{key} = {getattr(self, key)}: needs validation windows, but "
                                 f"{path}.validation_fraction = 0")
        derived = {"predictor": windows.predictor_inputs - 1, "autoencoder": windows.autoencoder_length}
        return dataclasses.replace(self, output_steps=derived[kind]) if kind in derived else self


def _devices(tree: Mapping[str, Any], key: str, path: str, context: Mapping[str, Any]) -> int | str:
    devices = get(tree, key, path)
    if not (devices == "auto" or (isinstance(devices, int) and not isinstance(devices, bool) and devices >= 1)):
        raise ParamError(f"{path}.{key} = {devices!r}: must be a positive integer or 'auto'")
    return devices


@dataclass(frozen=True)
class Training(Section):
    """`training`: the three networks (thesis 4.3), one DVC stage and one MLflow run each."""

    tracking_uri: str = knob("MLflow store; the MLFLOW_TRACKING_URI environment variable overrides it")
    experiment: str = knob("MLflow experiment")
    accelerator: str = knob("Lightning Trainer: cpu, gpu, auto ...")
    devices: int | str = knob("a number of devices (>= 1) or auto", 1, read=_devices)
    strategy: str = knob("Lightning strategy, e.g. ddp for several GPUs or nodes")
    num_nodes: int = knob("machines the training runs on (Lightning's cluster launch: docs/team.md)", 1)
    threads: int = knob("torch CPU threads per stage (the stages run one after another)", 1)
    deterministic: bool = knob("Lightning's deterministic algorithms")
    kalman_acceleration_std_mps2: float = positive("hold-out reference: CV Kalman process noise (untuned)")
    kalman_truth_sigma_m: float = positive("measurement sigma when the reference Kalman filter is fed true states")
    networks: Mapping[str, NetworkTraining] = knob("the filter, predictor and autoencoder networks", keys=NETWORKS)


def _noise_starts(tree: Mapping[str, Any], key: str, path: str, context: Mapping[str, Any]) -> dict:
    noise = {}
    for kind, count in zip(FILTER_KINDS, (1, 1, 2, 2, 3)):
        values = get(tree, f"{kind}_noise_std", path)
        if (not isinstance(values, list) or len(values) != count
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in values)):
            raise ParamError(f"{path}.{kind}_noise_std = {values!r}: must list {count} positive number(s)")
        noise[kind] = tuple(float(v) for v in values)
    return noise


@dataclass(frozen=True)
class Kalman(Section):
    """`kalman` (ours): the classical trackers, tuned on the target plots of a split (tune_kalman stage)."""

    split: str = split_knob()
    filters: tuple[str, ...] = knob(
        "the filters tune_kalman tunes into models/kalman_tuned.json, distinct, cv, ca and imm among them (the oracle, "
        "the bound and the fusion's local trackers run them); a run of a filter not listed is refused when "
        "params are read", choices=FILTER_KINDS)
    cost: str = knob("rmse (filtered position error), nees (|ln(ANEES / 3)|) or rmse_in_gate (rmse, raised when more "
                     "target plots miss the gate than tracker.association.kalman_gate_probability allows)",
                     choices=TUNING_COSTS)
    burn_in_updates: int = knob("plots of each (re)start left out of the cost, its first plot included", 0)
    restart_gap_s: float = positive("a longer gap restarts the filter (the tracker deletes a track silent 2 x "
                                    "tracker.management.silence_s)")
    max_iterations: int = knob("Nelder-Mead iterations per tuned value (scipy's default: 200); tuning that has not "
                               "converged by then fails", 1)
    velocity_std_mps: float = positive("a new track's velocity spread (start value; tuned)")
    acceleration_std_mps2: float = positive("a new track's acceleration spread (CA and IMM; not tuned)")
    noise_std: Mapping[str, tuple[float, ...]] = positive(
        "start values of the process noise (tuned): CV white acceleration m/s^2 [one]; CA acceleration increments "
        "m/s^3 [one]; IMM its CV (m/s^2) and its CA model (m/s^3) [two]; IMM with turns its CV model and its two "
        "turns (m/s^2, one for both) [two]; IMM with CA and turns its CV, CA and turns [three]",
        keys=("cv_noise_std", "ca_noise_std", "imm_noise_std", "imm_ct_noise_std", "imm_ca_ct_noise_std"),
        read=_noise_starts)
    imm_switch_probability: float = knob("IMM: chance of changing model between two updates (start value; tuned)",
                                         0.0, 1.0, open_low=True, open_high=True)
    imm_initial_cv_probability: float = knob("IMM: a new track starts as mostly CV", 0.0, 1.0)
    imm_ct_turn_rate_dps: float = positive("IMMs with turns (issue 33): their left and right turns' rate, deg/s "
                                           "(start value; tuned)")

    def check(self, path: str, context: Mapping[str, Any]) -> Kalman:
        lacking = [kind for kind in REQUIRED_FILTERS if kind not in self.filters]
        if lacking or len(set(self.filters)) != len(self.filters):
            raise ParamError(f"{path}.filters = {list(self.filters)}: must list distinct filters, "
                             f"{', '.join(REQUIRED_FILTERS)} among them (the oracle, the bound and the fusion's local "
                             f"trackers run them){f'; {lacking[0]} is missing' if lacking else ''}")
        return self


def _segments(section: Any, path: str, what: str) -> None:
    """Truncation within a training segment, and something of it left after the burn-in."""
    if section.truncation_steps > section.segment_plots:
        raise ParamError(f"{path}.truncation_steps = {section.truncation_steps}: longer than the training {what}s "
                         f"(segment_plots = {section.segment_plots})")
    if section.burn_in_updates >= section.segment_plots:
        raise ParamError(f"{path}.burn_in_updates = {section.burn_in_updates}: leaves nothing of a "
                         f"{section.segment_plots}-plot {what} to score")


Q0 = "Q0 must be positive definite, so this must be a positive number"
ABOVE_1 = "must be above 1 (the largest scale the network can give; it starts at 1)"


@dataclass(frozen=True)
class KalmanNet(Section):
    """`kalman_net` (ours, issue 17): a Kalman filter whose Q, R and manoeuvre frequency a small network scales each
    step (seed 003, pipeline/learning/kalman_net.py), and the same torch filters tuned by gradient descent."""

    split: str = split_knob()
    base: str = knob("the filter the network scales (cv: measured best here)", choices=KALMAN_NET_BASES)
    cell: str = knob("gru (memory of its own) or mlp (one tanh layer: the filter state only)", choices=KALMAN_NET_CELLS)
    hidden: int = knob("units of the cell or layer (the seed: 20)", 1)
    noise_std: float = positive("Q0: the base's process noise (cv m/s^2, ca m/s^3, singer's sigma_m m/s^2)", why=Q0)
    manoeuvre_time_s: float = positive("singer's tau in Q0 and F; the network scales 1 / tau", why=Q0)
    velocity_std_mps: float = positive("a new track's velocity spread")
    acceleration_std_mps2: float = positive("... and acceleration spread (ca, singer)")
    r0_scale: float = positive("R0 = the plot's converted-measurement covariance times this",
                               why=Q0.replace("Q0", "R0"))
    q_amplitude: float = knob("largest Q scale the network can give (sigmoid x amplitude)", 1.0, open_low=True,
                              why=ABOVE_1)
    r_amplitude: float = knob("largest R scale", 1.0, open_low=True, why=ABOVE_1)
    manoeuvre_amplitude: float = knob("largest scale of singer's manoeuvre frequency", 1.0, open_low=True, why=ABOVE_1)
    velocity_scale_mps: float = positive("the seed's normalisation of the state and plot increments")
    nis_scale: float = positive("the seed's: the innovation feature is NIS / this, at most 1")
    restart_gap_s: float = positive("a longer gap restarts the filter (as kalman.restart_gap_s)")
    burn_in_updates: int = knob("plots of each (re)start left out of the loss and the hold-out scores", 0)
    segment_plots: int = knob("the filter restarts every this many plots in training: rows of a batch", 2)
    truncation_steps: int = knob("truncated BPTT: the state is cut from the graph every this many steps", 1)
    batch_segments: int = knob("segments per Adam step", 1)
    epochs: int = knob("learning rate annealed to 0 on a cosine over them (the seed's schedule)", 1)
    learning_rate: float = positive("Adam")
    seed: int = knob("initial weights and batch order", 0)
    baselines: tuple[str, ...] = knob("kinds tuned by gradient descent the same way", choices=GRADIENT_KINDS,
                                      why=f"must list distinct kinds of {GRADIENT_KINDS}")
    baseline_epochs: int = knob("their epochs", 1)
    baseline_learning_rate: float = positive("Adam on their logarithms")
    noise_scales: tuple[float, ...] = positive("compare: the hold-out plots re-noised with the radar's sigmas times "
                                               "each of these (unknown to every filter)")
    noise_seed: int = knob("... drawn from this seed", 0)

    def check(self, path: str, context: Mapping[str, Any]) -> KalmanNet:
        _segments(self, path, "segment")
        return self


@dataclass(frozen=True)
class Confirmation(Section):
    """`confirmation` (ours, issue 34): the learned track confirmation's network, which scores each association of
    a candidate track from its evidence (pipeline/learning/confirmation.py), trained on the candidate tracks that
    `method` makes on `split`'s plots (aircraft and clutter); the train_confirmation stage, one MLflow run."""

    split: str = split_knob()
    method: str = knob("the tracking method whose candidate tracks it learns from (a method with no network)")
    window_m: float = positive("... at this window (m)")
    validation_every: int = knob("every this many-th scenario is held out: the threshold's clutter tracks and the "
                                 "hold-out metrics", 2)
    hidden: int = knob("units of each of its two hidden layers", 1)
    epochs: int = knob("passes over the associations", 1)
    batch_size: int = knob("associations per Adam step", 1)
    learning_rate: float = positive("Adam")
    seed: int = knob("initial weights and batch order", 0)


@dataclass(frozen=True)
class Association(Section):
    """`association` (ours, issue 19): two radars' track-to-track association on the seed's synthetic setting
    (seed 002, section 4.1; pipeline/association/association_scenes.py), the train_association stage."""

    targets: tuple[int, int] = knob("the seed's [lower, upper] targets per scene, at most scene_size", 1, pair=True)
    area_m: float = positive("the seed's: targets start uniformly in a square of this side")
    scan_period_s: float = positive("the seed's: both radars' plot period")
    track_points: int = knob("the seed's: plots per track segment (a history of track_points - 1 states)", 2)
    noise_m: tuple[float, float] = positive("the seed's: position sigma per axis of radar 1 and radar 2", count=2,
                                            why="must be two positive numbers (radar 1's and radar 2's sigma)")
    detection_probability: float = knob("the seed's Pd, per target", 0.0, 1.0, open_low=True)
    speed_mps: tuple[float, float] = positive("[lower, upper] initial speed (ours)", pair=True)
    acceleration_std_mps2: float = knob("white-noise acceleration sigma per axis (ours)", 0.0)
    tracks: str = knob("kalman (CV Kalman filter from a two-point start) or two_point (each point as measured)",
                       choices=TRACK_MODELS)
    train_bias_m: tuple[float, float] = knob("the seed's [lower, upper] radar 2 bias length (direction uniform)", 0.0,
                                             pair=True)
    eval_bias_m: tuple[float, ...] = knob("bias lengths every method is scored at (issue 19)", 0.0)
    eval_scenes: int = knob("scenes per scored bias (ours)", 1)
    eval_seed: int = knob("the scored scenes' seed (training scenes use seed + epoch streams)", 0)
    gate_probability: float = knob("the chi-square gate of the statistical tests (d = 4)", 0.0, 1.0, open_low=True,
                                   open_high=True)
    double_threshold_hits: int = knob("the double-threshold method's passes of the last track_points - 1 times", 1)
    max_bias_m: float = positive("the bias-robust method looks for offsets no longer than this")
    vote_radius_m: float = positive("its vote radius")
    max_iterations: int = knob("its assign / estimate iterations at most", 1)
    max_time_offset_s: float = knob("it also estimates radar 2's clock offset up to this (issue 27; 0: not)", 0.0)
    scene_size: int = knob("the seed's N: scene tensor size, the most tracks per radar", MIN_SCENE_SIZE)
    scene_diameter_m: float = positive("the seed's L_C: scene tensor distances are divided by it")
    feature_hidden: tuple[int, ...] = knob("the seed's feature lifting layers", 1, why=SIZES)
    decision_hidden: int = knob("the seed's decision layer", 1)
    decision_threshold: float = knob("the seed's: a row's largest probability above this is a pair", 0.0, 1.0,
                                     open_low=True, open_high=True)
    epochs: int = knob("the seed's epochs ...", 1)
    scenes_per_epoch: int = knob("... of this many freshly simulated scenes", 1)
    scenes_per_batch: int = knob("scenes per Adam step (ours; the seed: 1)", 1)
    learning_rate: float = positive("Adam (the seed does not give it)")
    seed: int = knob("training scenes (stream seed + epoch) and initial weights", 0)

    def check(self, path: str, context: Mapping[str, Any]) -> Association:
        if self.targets[1] > self.scene_size:
            raise ParamError(f"{path}.targets = {list(self.targets)}: more targets than scene_size = {self.scene_size} "
                             "tracks")
        if self.double_threshold_hits > self.track_points - 1:
            raise ParamError(f"{path}.double_threshold_hits = {self.double_threshold_hits}: above the track history "
                             f"of track_points - 1 = {self.track_points - 1} times")
        return self


@dataclass(frozen=True)
class LSTMUpdate(Section):
    """`lstm_update` (ours, issue 18): the CA Kalman prediction with an LSTM cell in place of the update (seed 001,
    pipeline/learning/lstm_update.py), MC-dropout covariance for the gate; the train_lstm_update stage."""

    split: str = split_knob()
    hidden: int = knob("LSTM units", 1)
    dropout: float = knob("dropout on the output layer's input: training, and MC dropout after", 0.0, 1.0,
                          open_high=True)
    mc_samples: int = knob("MC-dropout copies of each track beside its point estimate, run as one batch", 1)
    detach_prediction: bool = knob("true: the prediction F x is not differentiated through (the seed)")
    position_scale_m: float = positive("normalisation of the innovation, the plot's deviations and the position")
    velocity_scale_mps: float = positive("... of velocities")
    acceleration_scale_mps2: float = positive("... of accelerations")
    time_scale_s: float = positive("... of the time step (the radar's scan)")
    initial_alpha: float = knob("the untrained output layer: an alpha-beta filter, position += alpha innovation",
                                0.0, 1.0)
    initial_beta: float = knob("... velocity += beta innovation / dt", 0.0, 2.0)
    floor_m: float = positive("added to the MC-dropout covariance's diagonal, squared: keeps it invertible")
    start_velocity_std_mps: float = positive("MC copies of a new track start with velocities of this spread")
    restart_gap_s: float = positive("a longer gap restarts the estimator (as kalman.restart_gap_s)")
    burn_in_updates: int = knob("plots of each (re)start left out of the loss", 0)
    segment_plots: int = knob("training sequence length, at least windows.filter_length", 2)
    truncation_steps: int = knob("truncated BPTT: the state is cut from the graph every this many steps", 1)
    batch_segments: int = knob("segments per Adam step", 1)
    epochs: int = knob("learning rate annealed to 0 on a cosine over them", 1)
    learning_rate: float = positive("Adam")
    seed: int = knob("initial weights, batch order and dropout masks", 0)
    validation_fraction: float = knob("share of the split's segments kept out of training: the covariance factors "
                                      "are fitted on their windows ...", 0.0, 1.0, open_low=True, open_high=True)
    calibration_ages: int = knob("... for each track age up to this (older tracks take the last), below "
                                 "segment_plots", 1)
    calibration_gaps: int = knob("the prediction's factor also for each number of scan periods up to this", 1)
    turn_share: float = knob("hold-out: the windows of lowest linearity (this share) scored as turns", 0.0, 1.0,
                             open_low=True, open_high=True)
    range_shares: tuple[float, ...] = positive("hold-out: share of estimates within each share of the range",
                                               high=1.0, why="must list shares of the range, in (0, 1]")

    def check(self, path: str, context: Mapping[str, Any]) -> LSTMUpdate:
        filter_length = context["windows"].filter_length
        if self.segment_plots < filter_length:
            raise ParamError(f"{path}.segment_plots = {self.segment_plots}: shorter than the hold-out windows it is "
                             f"scored on (windows.filter_length = {filter_length})")
        _segments(self, path, "sequence")
        if self.calibration_ages >= self.segment_plots:
            raise ParamError(f"{path}.calibration_ages = {self.calibration_ages}: not younger than the validation "
                             f"windows it is fitted on (segment_plots = {self.segment_plots})")
        return self


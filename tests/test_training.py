"""The three networks: their shapes, training, the model file, the autoencoder's threshold
rule, and the `train` command end to end.

Small synthetic windows (noisy straight lines in scaled units) show training itself; one
tiny run of routes -> simulate -> windows, then `python -m pipeline train` for each network
with 2 epochs and a temporary SQLite MLflow store, shows what a training stage leaves behind.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import mlflow
import numpy as np
import pytest
import torch
import yaml

from pipeline import cli, io
from pipeline.learning import model_eval, runner, training
from pipeline.learning.experiment_tracking import SESSION_TAG, data_hash
from pipeline.learning.mlflow_models import DATASET_DIGEST_CHARS, FILE_DIGEST_TAG, registered_name, versions_used
from pipeline.learning.model_store import load_model, save_network
from pipeline.learning.networks import KINDS, NetworkConfig, build_network
from pipeline.learning.scaling import plot_scaler
from pipeline.learning.training import TrainingConfig, WindowDataModule, network_config, train
from tests.project import REPOSITORY, environment, run_pipeline, tiny_params_tree, write_params

# The networks of params.yaml (thesis 4.3).
CONFIGS = {
    "filter": NetworkConfig(kind="filter", hidden=(8, 16), input_steps=10, input_features=5, output_steps=5,
                            output_features=5),
    "predictor": NetworkConfig(kind="predictor", hidden=(32, 32), input_steps=5, input_features=6,
                               output_steps=4, output_features=5),
    "autoencoder": NetworkConfig(kind="autoencoder", hidden=(12, 10), input_steps=5, input_features=5,
                                 output_steps=5, output_features=5, decoder_hidden=(12, 10)),
}
FEW_EPOCHS = TrainingConfig(epochs=5, batch_size=32, learning_rate=0.01, validation_fraction=0.2, seed=1,
                            early_stopping_patience=0, accelerator="cpu", devices=1, strategy="auto", threads=1,
                            deterministic=True)
SCALER = plot_scaler(dt_max_s=18.0, position_max_diff_m=400.0, range_max_m=400000.0, steps=10, frame="ecef",
                     centre_range=False)
EXPERIMENT = "radar-nn-tracker"
CLI_EPOCHS = 2
HOLDOUT_FRACTION = 0.25  # of the tiny run's 8 training segments; the default 5 % would hold out none

# Third-party deprecation notices (Lightning's pytree use, MLflow's SQLAlchemy mappers), not ours.
pytestmark = pytest.mark.filterwarnings("ignore:.*LeafSpec.* is deprecated", "ignore:The ``noload`` loader")


def smooth_windows(config: NetworkConfig, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Noisy straight lines in, the clean lines' last `output_steps` out: a filter's task in miniature."""
    rng = np.random.default_rng(seed)
    steps = np.linspace(0.0, 1.0, config.input_steps)[None, :, None]
    clean = rng.uniform(-0.5, 0.5, (count, 1, config.input_features)) + rng.uniform(
        -0.5, 0.5, (count, 1, config.input_features)) * steps
    noisy = clean + 0.02 * rng.standard_normal(clean.shape)
    return noisy.astype(np.float32), clean[:, -config.output_steps:, :config.output_features].astype(np.float32)


def weights(network: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {name: tensor.detach().clone() for name, tensor in network.state_dict().items()}


# ----------------------------------------------------------------------------- networks

@pytest.mark.parametrize("kind", KINDS)
def test_network_output_is_batch_by_output_steps_by_features(kind):
    """Each network maps (batch, input_steps, input_features) to (batch, output_steps, output_features)."""
    config = CONFIGS[kind]
    network = build_network(config)
    outputs = network(torch.randn(7, config.input_steps, config.input_features))
    assert outputs.shape == (7, config.output_steps, config.output_features)


def test_default_params_describe_the_thesis_networks(make_params):
    """The training stage builds, from params.yaml, exactly the networks above."""
    params = make_params(1)
    assert {kind: network_config(kind, params) for kind in KINDS} == CONFIGS


@pytest.mark.parametrize("changed", [1, 2, 3, 4])
def test_predictor_outputs_depend_only_on_earlier_inputs(changed):
    """Predictor output k (the state after input k+1) ignores later inputs: changing input step
    `changed` leaves the outputs before it unchanged and changes the one it feeds."""
    torch.manual_seed(0)
    network = build_network(CONFIGS["predictor"]).eval()
    states = torch.randn(3, 5, 6)
    edited = states.clone()
    edited[:, changed] += 1.0
    with torch.no_grad():
        before, after = network(states), network(edited)
    assert torch.equal(before[:, :changed - 1], after[:, :changed - 1])
    assert not torch.allclose(before[:, changed - 1], after[:, changed - 1])


def test_the_onnx_export_of_a_network_with_large_outputs_passes_its_check_to_float32_rounding():
    """The load-time check of the ONNX export is relative to the outputs (real-world case 33: a predictor
    whose outputs reach 1e7 differed by 3.5, float32 rounding, and `track` stopped with a traceback);
    the exported network gives PyTorch's outputs to that rounding."""
    from pipeline.learning.inference import BatchNetwork
    config = CONFIGS["predictor"]
    torch.manual_seed(3)
    network = build_network(config)
    output = [module for module in network.modules() if isinstance(module, torch.nn.Linear)][-1]
    with torch.no_grad():
        output.weight.mul_(1e7)  # a diverged training's output layer: outputs of about 1e7
    run = BatchNetwork(network, config.input_steps, config.input_features, "onnx")
    windows = np.random.default_rng(0).normal(size=(50, config.input_steps, config.input_features))
    expected = BatchNetwork(network, config.input_steps, config.input_features, "torch")(windows)
    assert np.abs(expected).max() > 1e5
    np.testing.assert_allclose(run(windows), expected, rtol=1e-5, atol=1e-4 * np.abs(expected).max())


def test_unknown_network_kind_is_refused():
    """A kind that is not filter, predictor or autoencoder is a ValueError naming the kinds."""
    with pytest.raises(ValueError, match="tracker.*filter"):
        build_network(dataclasses.replace(CONFIGS["filter"], kind="tracker"))


# ----------------------------------------------------------------------------- training

def test_a_few_epochs_lower_the_training_loss():
    """Five epochs on 300 smooth windows: the last epoch's training loss is below the first's."""
    inputs, targets = smooth_windows(CONFIGS["filter"], 300)
    module, history = train(CONFIGS["filter"], inputs, targets, FEW_EPOCHS)
    assert len(history.train_loss) == len(history.validation_loss) == 5
    assert history.train_loss[-1] < history.train_loss[0]
    assert history.validation_loss[-1] < history.validation_loss[0]
    assert not module.training  # handed back ready for inference


def test_a_training_loss_that_goes_nan_stops_the_training_naming_the_network_and_the_epoch():
    """Learning rate 1e30: Adam's first steps overflow the weights and the loss is NaN in epoch 1; the
    training stops there with TrainingDiverged instead of running its 5 epochs on NaN weights."""
    inputs, targets = smooth_windows(CONFIGS["filter"], 100)
    with pytest.raises(io.TrainingDiverged, match=r"training of the filter network stopped: the training loss "
                                                   r"became nan at epoch 1 of 5 \(learning rate 1e\+30\)"):
        train(CONFIGS["filter"], inputs, targets, dataclasses.replace(FEW_EPOCHS, learning_rate=1e30))


def test_a_training_loss_that_diverges_but_stays_finite_stops_the_training():
    """Learning rate 1e6 (real-world case 33): the weights stay finite, the loss grows far past the
    untrained network's: stopped with TrainingDiverged (no model is written, nothing registered)."""
    inputs, targets = smooth_windows(CONFIGS["filter"], 100)
    with pytest.raises(io.TrainingDiverged, match=r"training of the filter network stopped: the training loss "
                                                   r"diverged to .*, over 1000 times the untrained network's"):
        train(CONFIGS["filter"], inputs, targets, dataclasses.replace(FEW_EPOCHS, learning_rate=1e6))


class InfiniteValidationTargets(WindowDataModule):
    """The windows of `WindowDataModule`, the validation windows' targets made infinite."""

    def __init__(self, *arguments, **keywords) -> None:
        super().__init__(*arguments, **keywords)
        self.validation_set.targets[:] = float("inf")


def test_a_validation_loss_that_is_not_finite_stops_the_training(monkeypatch):
    """A finite training loss but an infinite validation loss (infinite validation targets): stopped
    after the first validation, the validation loss named."""
    monkeypatch.setattr(training, "WindowDataModule", InfiniteValidationTargets)
    inputs, targets = smooth_windows(CONFIGS["filter"], 100)
    with pytest.raises(io.TrainingDiverged, match="the validation loss became inf at epoch 1 of 5"):
        train(CONFIGS["filter"], inputs, targets, FEW_EPOCHS)


def test_early_stopping_ends_training_when_validation_loss_stops_improving():
    """With patience 1 and a frozen network (learning rate 0), training stops after the second epoch."""
    inputs, targets = smooth_windows(CONFIGS["filter"], 100)
    frozen = dataclasses.replace(FEW_EPOCHS, epochs=10, learning_rate=0.0, early_stopping_patience=1)
    _, history = train(CONFIGS["filter"], inputs, targets, frozen)
    assert len(history.train_loss) == 2


def test_early_stopping_keeps_the_weights_of_the_best_epoch():
    """Windows whose targets are pure noise: the network can only memorise its training windows,
    so the validation loss is lowest early and then rises. Training stops `patience` epochs after
    the best one, and the network handed back is that epoch's: its loss on the validation
    windows is the one recorded for the epoch, not the last epoch's."""
    rng = np.random.default_rng(3)
    config = CONFIGS["predictor"]
    inputs = rng.standard_normal((200, config.input_steps, config.input_features))
    targets = rng.standard_normal((200, config.output_steps, config.output_features))
    schedule = dataclasses.replace(FEW_EPOCHS, epochs=60, learning_rate=0.03, early_stopping_patience=4)
    module, history = train(config, inputs, targets, schedule)

    best = int(np.argmin(history.validation_loss)) + 1
    assert history.kept_epoch == best
    assert len(history.train_loss) == best + 4 < 60
    assert history.validation_loss[-1] > history.validation_loss[best - 1]
    validation = WindowDataModule(inputs, targets, schedule.batch_size, schedule.validation_fraction,
                                  schedule.seed).validation_set
    with torch.no_grad():
        loss = torch.nn.functional.mse_loss(module(validation.inputs), validation.targets).item()
    assert loss == pytest.approx(history.validation_loss[best - 1], rel=1e-5)


def test_learning_rate_decay_halves_the_rate_on_a_plateau():
    """A learning rate too small to move the network keeps the validation loss on a plateau: with
    decay patience 2, the rate is halved after each second epoch without improvement, twice in 6."""
    inputs, targets = smooth_windows(CONFIGS["filter"], 100)
    schedule = dataclasses.replace(FEW_EPOCHS, epochs=6, learning_rate=1e-12, lr_decay_patience=2,
                                   lr_decay_factor=0.5, early_stopping_min_improvement=0.01)
    module, _ = train(CONFIGS["filter"], inputs, targets, schedule)
    assert module.optimizers().param_groups[0]["lr"] == pytest.approx(1e-12 * 0.5 ** 2)


def test_same_seed_gives_the_same_weights_and_another_seed_other_weights():
    """Training is reproducible: every tensor equal for the same seed, not all equal for another."""
    inputs, targets = smooth_windows(CONFIGS["filter"], 200)
    config = dataclasses.replace(FEW_EPOCHS, epochs=2)
    first = weights(train(CONFIGS["filter"], inputs, targets, config)[0].network)
    again = weights(train(CONFIGS["filter"], inputs, targets, config)[0].network)
    other = weights(train(CONFIGS["filter"], inputs, targets, dataclasses.replace(config, seed=2))[0].network)
    assert first.keys() == again.keys() == other.keys()
    assert all(torch.equal(first[name], again[name]) for name in first)
    assert not all(torch.equal(first[name], other[name]) for name in first)


# ----------------------------------------------------------------------------- the model file

@pytest.mark.parametrize("kind", KINDS)
def test_saved_model_loads_and_gives_the_same_outputs(tmp_path, kind):
    """save_network then load_model: same config, scaler and extras, and bit-identical outputs."""
    config = CONFIGS[kind]
    torch.manual_seed(1)
    network = build_network(config).eval()
    path = tmp_path / f"{kind}.pt"
    save_network(path, network, {"threshold": 1.5}, SCALER)
    model = load_model(path, expected_kind=kind)
    assert (model.config, model.scaler, model.extras) == (config, SCALER, {"threshold": 1.5})
    windows = torch.randn(9, config.input_steps, config.input_features)
    with torch.no_grad():
        assert torch.equal(model.predict(windows), network(windows))


def test_model_of_another_kind_is_refused(tmp_path):
    """Asking for a predictor from a filter's file names the file and both kinds."""
    path = tmp_path / "filter.pt"
    save_network(path, build_network(CONFIGS["filter"]), scaler=SCALER)
    with pytest.raises(io.InputError, match=f"{path}: holds a filter network, expected a predictor"):
        load_model(path, expected_kind="predictor")


def test_weights_that_do_not_fit_the_recorded_architecture_are_refused(tmp_path):
    """A bundle whose recorded hidden sizes were edited no longer fits its weights: the error says so."""
    path = tmp_path / "filter.pt"
    save_network(path, build_network(CONFIGS["filter"]), scaler=SCALER)
    bundle = torch.load(path, weights_only=True)
    bundle["config"]["hidden"] = [4, 16]
    torch.save(bundle, path)
    with pytest.raises(io.InputError, match=f"{path}: weights do not fit the filter architecture"):
        load_model(path)


def test_a_bundle_with_a_non_finite_weight_is_refused_naming_the_file_and_the_tensor(tmp_path):
    """One NaN in a saved predictor's output weights (a training that diverged): load_model refuses the
    file, naming it and the tensor, rather than hand the tracker a network that predicts NaN."""
    network = build_network(CONFIGS["predictor"])
    with torch.no_grad():
        network.head.weight[0, 0] = float("nan")
    path = tmp_path / "predictor.pt"
    save_network(path, network, scaler=SCALER)
    with pytest.raises(io.InputError, match=f"{path}: weight tensor 'head.weight' has 1 non-finite values"):
        load_model(path, expected_kind="predictor")


@pytest.mark.parametrize("content, message", [
    (None, "model file not found"),
    (np.random.default_rng(0).bytes(2000), "not a readable model file"),
    ("plain tensor", "not a model bundle"),
], ids=["missing", "random bytes", "not a bundle"])
def test_missing_or_foreign_model_file_is_named(tmp_path, content, message):
    """A missing file, random bytes or another torch file: an InputError naming the file."""
    path = tmp_path / "model.pt"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        torch.save(torch.zeros(3), path)
    with pytest.raises(io.InputError, match=f"{path}: {message}"):
        load_model(path)


# ----------------------------------------------------------------------------- the autoencoder's threshold

def test_threshold_accepts_every_target_window_and_reports_false_ones_rejected():
    """Targets 0.1, 0.5, 0.3 and false 0.2, 0.6, 0.9: threshold 0.5, two thirds of the false windows rejected."""
    errors = np.array([0.1, 0.5, 0.3, 0.2, 0.6, 0.9])
    labels = np.array([True, True, True, False, False, False])
    threshold, rejected = model_eval.autoencoder_threshold(errors, labels)
    assert threshold == 0.5
    assert rejected == pytest.approx(2 / 3)
    # A false window exactly at the threshold is accepted, not rejected.
    _, rejected = model_eval.autoencoder_threshold(np.append(errors, 0.5), np.append(labels, False))
    assert rejected == pytest.approx(2 / 4)


def test_threshold_needs_target_windows():
    """Calibration material without a target window cannot give a threshold."""
    with pytest.raises(ValueError, match="no target windows"):
        model_eval.autoencoder_threshold(np.array([0.2, 0.6]), np.array([False, False]))


# ----------------------------------------------------------------------------- the train command

@pytest.fixture(scope="module")
def chain(tmp_path_factory) -> Path:
    """routes -> simulate -> windows with 2 routes per strategy and 2 training epochs, in a fresh folder."""
    folder = tmp_path_factory.mktemp("training")
    tree = tiny_params_tree()
    tree["windows"]["holdout_fraction"] = HOLDOUT_FRACTION
    for kind in KINDS:
        tree["training"][kind]["epochs"] = CLI_EPOCHS
    write_params(tree, folder / "params.yaml")
    for command in (("routes", "--out", "routes"), ("simulate", "--routes", "routes", "--out", "simulated"),
                    ("windows", "--simulated", "simulated", "--out", "windows", "--reports", "reports")):
        result = run_pipeline(command[0], "--params", "params.yaml", *command[1:], cwd=folder)
        assert result.returncode == 0, result.stderr
    return folder


@pytest.fixture(scope="module")
def trained(chain) -> mlflow.MlflowClient:
    """`python -m pipeline train` for each network, all logging to one temporary SQLite store."""
    uri = f"sqlite:///{chain / 'mlflow.db'}"
    for kind in KINDS:
        result = subprocess.run(
            [sys.executable, "-m", "pipeline", "train", "--params", "params.yaml", "--kind", kind,
             "--windows", "windows", "--models", "models", "--reports", "reports"],
            cwd=chain, env={**environment(), "MLFLOW_TRACKING_URI": uri}, capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
    return mlflow.MlflowClient(tracking_uri=uri)


def only_run(client: mlflow.MlflowClient, kind: str) -> mlflow.entities.Run:
    runs = client.search_runs([client.get_experiment_by_name(EXPERIMENT).experiment_id])
    named = [run for run in runs if run.info.run_name == f"train_{kind}"]
    assert len(named) == 1, f"{len(named)} runs named train_{kind}"
    return named[0]


HOLDOUT_METRICS = {"filter": ("filter_error_m", "raw_plot_error_m", "kalman_cv_error_m"),
                   "predictor": ("predictor_error_m", "linear_extrapolation_error_m"),
                   "autoencoder": ("threshold", "false_windows_rejected")}


@pytest.mark.parametrize("kind", KINDS)
def test_train_command_logs_one_complete_mlflow_run(chain, trained, kind, tmp_path):
    """One finished run train_<kind>: params, a loss per epoch, hold-out metrics, tags and artifacts."""
    run = only_run(trained, kind)
    assert run.info.status == "FINISHED"
    params = run.data.params
    assert params["network.hidden"] == str(CONFIGS[kind].hidden)
    assert params["network.epochs"] == str(CLI_EPOCHS)
    assert params["training.accelerator"] == "cpu"
    assert params["windows.frame"] == "radial"
    assert params["windows.holdout_fraction"] == str(HOLDOUT_FRACTION)

    # One training and one validation loss per epoch, the same the stage wrote to reports/loss/<kind>.csv.
    history = {name: [m.value for m in sorted(trained.get_metric_history(run.info.run_id, name),
                                              key=lambda m: m.step)] for name in ("train_loss", "val_loss")}
    assert len(history["train_loss"]) == len(history["val_loss"]) == CLI_EPOCHS
    for name in ("train_loss", "val_loss"):  # drawn against the epoch, not the optimiser's step count
        assert sorted(m.step for m in trained.get_metric_history(run.info.run_id, name)) == list(range(CLI_EPOCHS))
    assert "epoch" not in run.data.metrics
    csv = np.loadtxt(chain / "reports" / "loss" / f"{kind}.csv", delimiter=",", skiprows=1, ndmin=2)
    np.testing.assert_allclose(csv[:, 1:], np.column_stack([history["train_loss"], history["val_loss"]]),
                               rtol=1e-6)

    # Hold-out metrics: finite, and the ones the stage wrote to reports/models/<kind>.json.
    reported = json.loads((chain / "reports" / "models" / f"{kind}.json").read_text())
    metrics = run.data.metrics
    for name in HOLDOUT_METRICS[kind]:
        assert np.isfinite(metrics[name]) and metrics[name] >= 0.0, name
    for name, value in reported.items():  # the file keeps six significant digits (`io.write_metrics`)
        assert metrics[name] == pytest.approx(value, rel=1e-5), name
    assert metrics["epochs_trained"] == CLI_EPOCHS
    assert metrics["final_train_loss"] == pytest.approx(history["train_loss"][-1], rel=1e-6)

    material = chain / "windows" / f"{kind}.parquet"
    assert run.data.tags["input_data_sha256"] == hashlib.sha256(
        material.name.encode() + material.read_bytes()).hexdigest()
    assert run.data.tags["git_commit"]

    # Artifacts: the model file (it loads, as the stage's kind) and the loss curve.
    assert {a.path for a in trained.list_artifacts(run.info.run_id)} == {
        f"{kind}.pt", f"loss_{kind}.png", f"{kind}.json"}
    model_file = mlflow.artifacts.download_artifacts(run_id=run.info.run_id, artifact_path=f"{kind}.pt",
                                                     dst_path=str(tmp_path), tracking_uri=trained.tracking_uri)
    model = load_model(model_file, expected_kind=kind)
    assert model.config == CONFIGS[kind]
    if kind == "autoencoder":
        assert model.extras["threshold"] == metrics["threshold"]
    png = mlflow.artifacts.download_artifacts(run_id=run.info.run_id, artifact_path=f"loss_{kind}.png",
                                              dst_path=str(tmp_path), tracking_uri=trained.tracking_uri)
    assert Path(png).read_bytes().startswith(b"\x89PNG\r\n\x1a\n")


@pytest.fixture
def registry(trained, monkeypatch) -> Iterator[mlflow.MlflowClient]:
    """The trained store as the default of MLflow's functions that take a `models:/` URI, for this
    test only: the environment (subprocesses) and the process-wide URI, which an earlier test in
    the same worker may have set (a stage calls `mlflow.set_tracking_uri`)."""
    monkeypatch.setenv("MLFLOW_TRACKING_URI", trained.tracking_uri)
    previous = mlflow.get_tracking_uri()
    mlflow.set_tracking_uri(trained.tracking_uri)
    yield trained
    mlflow.set_tracking_uri(previous)


@pytest.mark.parametrize("kind", KINDS)
def test_train_command_logs_its_windows_and_registers_its_network(chain, registry, kind):
    """The run's input is the training windows (named, with the windows file's digest); its
    network is a logged PyTorch model with a signature and an input example, registered as a
    new version of `radar-nn-tracker-<kind>`, tagged with the bundle's digest and the session."""
    trained = registry
    run = only_run(trained, kind)
    [dataset] = run.inputs.dataset_inputs
    assert dataset.dataset.name == f"{kind} windows"
    assert dataset.dataset.digest == data_hash(chain / "windows" / f"{kind}.parquet")[:DATASET_DIGEST_CHARS]
    assert {tag.key: tag.value for tag in dataset.tags}["mlflow.data.context"] == "training"

    name = registered_name(EXPERIMENT, kind)
    [version] = trained.search_model_versions(f"name = '{name}'")
    assert version.run_id == run.info.run_id and str(version.version) == "1"
    assert version.tags[FILE_DIGEST_TAG] == data_hash(chain / "models" / f"{kind}.pt")
    assert version.tags[SESSION_TAG] == run.data.tags[SESSION_TAG]
    assert trained.get_registered_model(name).description
    info = mlflow.models.get_model_info(f"models:/{name}/1")
    assert "pytorch" in info.flavors and info.signature is not None and info.saved_input_example_info is not None
    steps = CONFIGS[kind].input_steps
    assert info.signature.inputs.to_dict()[0]["tensor-spec"]["shape"] == (-1, steps, CONFIGS[kind].input_features)


def test_every_run_of_the_same_code_and_params_shares_one_session(trained):
    """The three training runs of one params file (no DVC experiment) carry the same session."""
    sessions = {only_run(trained, kind).data.tags[SESSION_TAG] for kind in KINDS}
    assert len(sessions) == 1 and sessions.pop().startswith("repro-")


PREDICT_THROUGH_PYFUNC = """\
import sys

import numpy as np

sys.modules["pipeline"] = None  # the MLflow model must load without this repository's code
import mlflow

for name in sys.argv[1:]:  # <kind>_<batch>: predict <name>.npy with the kind's version 1 into <name>_pyfunc.npy
    model = mlflow.pyfunc.load_model(f"models:/radar-nn-tracker-{name.split('_')[0]}/1")
    np.save(f"{name}_pyfunc.npy", model.predict(np.load(f"{name}.npy")))
"""


def test_a_logged_model_loaded_through_pyfunc_predicts_like_the_projects_loader(chain, registry, tmp_path):
    """`mlflow.pyfunc.load_model` on each registered version, in a Python process that cannot
    import `pipeline`, gives the outputs of `pipeline.learning.model_store.load_model` on the bundle the
    same run wrote (to float32 rounding), for windows it never saw, one window or several."""
    rng = np.random.default_rng(3)
    windows = {f"{kind}_{size}": rng.normal(size=(size, config.input_steps, config.input_features)).astype(np.float32)
               for kind, config in CONFIGS.items() for size in (1, 7)}
    for name, batch in windows.items():
        np.save(tmp_path / f"{name}.npy", batch)
    result = subprocess.run([sys.executable, "-c", PREDICT_THROUGH_PYFUNC, *windows], cwd=tmp_path, capture_output=True,
                            text=True, env={**environment(), "MLFLOW_TRACKING_URI": registry.tracking_uri})
    assert result.returncode == 0, result.stderr[-3000:]
    for name, batch in windows.items():
        kind = name.split("_")[0]
        expected = load_model(chain / "models" / f"{kind}.pt", expected_kind=kind).predict(torch.from_numpy(batch))
        # To float32 rounding: the exported graph and the eager GRU may add in another order, and
        # the two processes may run torch with different numbers of threads.
        np.testing.assert_allclose(np.load(tmp_path / f"{name}_pyfunc.npy"), expected.numpy(), rtol=1e-5, atol=1e-6,
                                   err_msg=name)


def test_the_evaluate_stage_finds_the_registered_versions_of_the_bundles_it_uses(chain, trained, tmp_path):
    """Each bundle in models/ is found as the version its training run registered; a bundle no
    run registered (trained elsewhere) is found as none."""
    found = versions_used(trained, EXPERIMENT, chain / "models")
    assert {kind: (str(version.version), version.run_id) for kind, version in found.items()} == {
        kind: ("1", only_run(trained, kind).info.run_id) for kind in KINDS}
    shutil.copytree(chain / "models", tmp_path / "models")
    model = load_model(tmp_path / "models" / "filter.pt")
    save_network(tmp_path / "models" / "filter.pt", model.network, {"retrained": True}, model.scaler)
    assert versions_used(trained, EXPERIMENT, tmp_path / "models")["filter"] is None
    (tmp_path / "models" / "autoencoder.pt").unlink()  # an evaluation of classical runs needs no network
    assert set(versions_used(trained, EXPERIMENT, tmp_path / "models")) == set(KINDS) - {"autoencoder"}


def test_train_command_prints_each_lightning_line_once_and_no_advertising(chain, tmp_path):
    """Lightning's own lines come once, in the pipeline's log format (its package handler used to
    print each a second time), and its tips for paid services are not printed."""
    result = subprocess.run(
        [sys.executable, "-m", "pipeline", "train", "--params", "params.yaml", "--kind", "predictor",
         "--windows", "windows", "--models", str(tmp_path / "models"), "--reports", str(tmp_path / "reports")],
        cwd=chain, env={**environment(), "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'mlflow.db'}"},
        capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    lines = result.stderr.splitlines()
    lightning = [line.split(" INFO ", 1)[1] for line in lines if " lightning." in line and " INFO " in line]
    assert any("max_epochs=" in message for message in lightning)
    assert len(lightning) == len(set(lightning)), lightning
    assert not [line for line in lines if line.startswith("INFO:")]
    assert "Tip:" not in result.stderr and "litlogger" not in result.stderr


def test_git_commit_tag_names_the_commit_of_the_code_that_ran(trained):
    """The git_commit tag is this repository's HEAD even when the command runs in another folder."""
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPOSITORY, capture_output=True, text=True,
                          check=True).stdout.strip()
    assert only_run(trained, "filter").data.tags["git_commit"].removesuffix("-dirty") == head


# ----------------------------------------------------------------------------- the train command on bad input

def train_command(caplog, params: Path, kind: str, windows: Path, out: Path) -> tuple[int, str]:
    """`python -m pipeline train ...` in this process (what `python -m pipeline` calls): exit code and log."""
    code = cli.main(["train", "--params", str(params), "--kind", kind, "--windows", str(windows),
                     "--models", str(out / "models"), "--reports", str(out / "reports")])
    return code, caplog.text


@pytest.fixture
def no_training(monkeypatch) -> None:
    """Make the train stage fail the test if it gets as far as training."""

    def refuse_to_train(*arguments, **keywords):
        raise AssertionError("training started on bad input")

    monkeypatch.setattr(runner, "fit", refuse_to_train)


@pytest.fixture
def local_store(tmp_path, monkeypatch) -> Path:
    """MLFLOW_TRACKING_URI at a SQLite file in the test's folder; the file exists only if MLflow was used."""
    path = tmp_path / "mlflow.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{path}")
    return path


def test_impossible_schedule_is_refused_before_any_mlflow_run(chain, tmp_path, caplog, local_store, no_training):
    """A patience longer than the run: exit 2 naming the key and value, no MLflow store touched."""
    tree = tiny_params_tree()
    tree["training"]["filter"]["early_stopping_patience"] = 5
    params = write_params(tree, tmp_path / "params.yaml")
    code, log = train_command(caplog, params, "filter", chain / "windows", tmp_path)
    assert code == 2
    assert "training.filter.early_stopping_patience = 5: above training.filter.epochs = 2" in log
    assert not (tmp_path / "models").exists() and not local_store.exists()


def test_missing_windows_file_is_named(chain, tmp_path, caplog, local_store, no_training):
    """No windows stage run yet: exit 2 naming the missing material, before training, nothing written."""
    code, log = train_command(caplog, chain / "params.yaml", "filter", tmp_path / "nowhere", tmp_path)
    assert code == 2
    assert "nowhere/filter.parquet: file not found" in log
    assert not (tmp_path / "models").exists() and not local_store.exists()


def test_windows_of_the_wrong_length_are_refused(chain, tmp_path, caplog, local_store, no_training):
    """Params asking for 8-plot filter windows, material of 10: exit 2 naming the file and the steps."""
    tree = tiny_params_tree()
    tree["windows"]["holdout_fraction"] = HOLDOUT_FRACTION
    tree["windows"]["filter_length"] = tree["tracker"]["networks"]["filter_plots"] = 8  # the tracker must agree
    code, log = train_command(caplog, write_params(tree, tmp_path / "params.yaml"), "filter", chain / "windows",
                              tmp_path)
    assert code == 2
    assert "filter.parquet: windows of 10 steps, params expect 8" in log
    assert not (tmp_path / "models").exists() and not local_store.exists()


def test_windows_scaled_differently_from_params_are_refused(chain, tmp_path, caplog, local_store, no_training):
    """position_max_diff_m changed after the windows were made: exit 2 naming scalers.json."""
    tree = tiny_params_tree()
    tree["windows"]["holdout_fraction"] = HOLDOUT_FRACTION
    tree["windows"]["position_max_diff_m"] = 500.0
    code, log = train_command(caplog, write_params(tree, tmp_path / "params.yaml"), "predictor",
                              chain / "windows", tmp_path)
    assert code == 2
    assert "scalers.json: windows were scaled with" in log and "rerun the windows stage" in log
    assert not (tmp_path / "models").exists() and not local_store.exists()


def test_unreachable_tracking_server_stops_before_training(chain, tmp_path, caplog, monkeypatch, no_training):
    """MLFLOW_TRACKING_URI at a closed port: exit 2 naming the URI, no model written."""
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "http://127.0.0.1:9")
    for name in ("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "MLFLOW_HTTP_REQUEST_TIMEOUT"):
        # Unset for the command to choose its own fail-fast values, and restored afterwards.
        monkeypatch.setenv(name, "")
        monkeypatch.delenv(name)
    code, log = train_command(caplog, chain / "params.yaml", "autoencoder", chain / "windows", tmp_path)
    assert code == 2
    assert "MLflow tracking store 'http://127.0.0.1:9' cannot be used" in log
    assert not (tmp_path / "models").exists() and not (tmp_path / "reports").exists()


def test_missing_holdout_is_found_before_training(chain, trained, tmp_path, caplog, monkeypatch, no_training):
    """Windows without holdout.parquet: exit 2 naming it, before a single epoch is trained."""
    shutil.copytree(chain / "windows", tmp_path / "windows")
    (tmp_path / "windows" / "holdout.parquet").unlink()
    # A copy of the trained chain's store: a reachable one, without the seconds a new SQLite store takes to set up.
    shutil.copy(chain / "mlflow.db", tmp_path / "mlflow.db")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    monkeypatch.chdir(tmp_path)  # MLflow's default artifact folder and the git lookup are relative to it
    code, log = train_command(caplog, chain / "params.yaml", "filter", tmp_path / "windows", tmp_path)
    assert code == 2
    assert "holdout.parquet: file not found" in log
    assert not (tmp_path / "models").exists()


def test_a_stage_that_fails_after_its_run_opened_ends_the_run_failed(chain, tmp_path, caplog, local_store,
                                                                    monkeypatch):
    """Training fails (here: an error of the training loop): the run, opened before training so
    that its duration is the stage's, ends FAILED, not RUNNING or FINISHED; no model is written."""

    def fail_in_training(*arguments, **keywords):
        raise RuntimeError("the training loop failed")

    monkeypatch.setattr(runner, "fit", fail_in_training)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(RuntimeError, match="the training loop failed"):
        train_command(caplog, chain / "params.yaml", "predictor", chain / "windows", tmp_path)
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{local_store}")
    [run] = client.search_runs([client.get_experiment_by_name(EXPERIMENT).experiment_id])
    assert run.info.run_name == "train_predictor" and run.info.status == "FAILED"
    assert not (tmp_path / "models").exists()


def test_a_training_that_goes_nan_exits_2_writes_nothing_and_registers_nothing(chain, tmp_path, caplog,
                                                                                local_store, monkeypatch):
    """The predictor at learning rate 1e30 (its loss NaN in epoch 1): exit 2 naming the network, the epoch
    and the loss; the model file already there is kept as it was, no report is written, the MLflow run
    ends FAILED and no model version is registered."""
    tree = tiny_params_tree()
    tree["windows"]["holdout_fraction"] = HOLDOUT_FRACTION
    tree["training"]["predictor"].update(epochs=CLI_EPOCHS, learning_rate=1e30)
    earlier = tmp_path / "models" / "predictor.pt"
    earlier.parent.mkdir()
    earlier.write_bytes(b"the model of an earlier training")
    monkeypatch.chdir(tmp_path)
    code, log = train_command(caplog, write_params(tree, tmp_path / "params.yaml"), "predictor", chain / "windows",
                              tmp_path)
    assert code == 2
    assert "training of the predictor network stopped: the training loss became nan at epoch 1 of 2" in log
    assert earlier.read_bytes() == b"the model of an earlier training"
    assert list((tmp_path / "models").iterdir()) == [earlier] and not (tmp_path / "reports").exists()
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{local_store}")
    [run] = client.search_runs([client.get_experiment_by_name(EXPERIMENT).experiment_id])
    assert run.info.run_name == "train_predictor" and run.info.status == "FAILED"
    assert client.search_model_versions(f"name = '{registered_name(EXPERIMENT, 'predictor')}'") == []


def test_a_store_removed_during_training_costs_no_model_and_ends_in_a_named_error(chain, tmp_path, caplog,
                                                                                   local_store, monkeypatch):
    """The SQLite store deleted once the run is open (its writes then fail): each write is retried, the
    training goes on and writes its model and reports, and the command exits 2 naming the store, without
    a traceback."""
    real_fit = runner.fit

    def remove_the_store_then_train(*arguments, **keywords):
        local_store.unlink()
        return real_fit(*arguments, **keywords)

    monkeypatch.setattr(runner, "fit", remove_the_store_then_train)
    monkeypatch.setattr("pipeline.learning.experiment_tracking.LOCAL_STORE_BACKOFF_S", 0.01)
    monkeypatch.chdir(tmp_path)
    code, log = train_command(caplog, chain / "params.yaml", "predictor", chain / "windows", tmp_path)
    assert code == 2
    assert f"MLflow tracking store 'sqlite:///{local_store}' failed while logging" in log
    assert f"{tmp_path / 'models' / 'predictor.pt'} and the reports written" in log
    assert load_model(tmp_path / "models" / "predictor.pt", expected_kind="predictor")
    assert (tmp_path / "reports" / "models" / "predictor.json").is_file()
    assert "Traceback" not in log


def test_a_training_on_two_processes_gives_one_run_and_one_model(chain, tmp_path):
    """`strategy: ddp` on two CPU devices (gloo): Lightning runs the train command twice, the two processes fit
    the network together, and rank 0 alone logs, writes and registers (issue 30, deliverable 5)."""
    tree = yaml.safe_load((chain / "params.yaml").read_text())
    tree["training"].update(accelerator="cpu", devices=2, strategy="ddp", num_nodes=1)
    params = write_params(tree, tmp_path / "params.yaml")
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    result = subprocess.run(
        [sys.executable, "-m", "pipeline", "train", "--params", str(params), "--kind", "filter", "--windows", "windows",
         "--models", str(tmp_path / "models"), "--reports", str(tmp_path / "reports")],
        cwd=chain, env={**environment(), "MLFLOW_TRACKING_URI": uri}, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "a further process of a training on several devices" in result.stderr  # rank 1 ran, and wrote nothing
    assert sorted(path.name for path in (tmp_path / "models").iterdir()) == ["filter.pt"]
    client = mlflow.MlflowClient(tracking_uri=uri)
    run = only_run(client, "filter")
    assert run.info.status == "FINISHED" and run.data.params["training.strategy"] == "ddp"
    assert len(client.search_model_versions(f"name = '{registered_name(EXPERIMENT, 'filter')}'")) == 1
    assert load_model(tmp_path / "models" / "filter.pt", expected_kind="filter").config == CONFIGS["filter"]

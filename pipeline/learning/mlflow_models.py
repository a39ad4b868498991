"""The trained networks as MLflow finds them: logged models, registered versions, input datasets.

Our own bundles (`models/<kind>.pt`, `pipeline.learning.model_store`) stay the DVC outputs that the
tracker loads: they carry the window scaler and the autoencoder's threshold, which the tracker
checks. The MLflow model is for MLflow users: each training run logs its network with MLflow's
PyTorch flavour (a signature and an input example taken from the training windows; exported
with torch.export, MLflow's "pt2" format, so that it loads without this repository's code) and
registers it as a new version of one registered model per network, `<training.experiment>-<kind>`. A version is
tagged with the digest of the bundle the same run wrote, which is how the evaluate run finds
the versions of the bundles it tracked with, and with the DVC experiment it came from.

`mlflow.pyfunc.load_model("models:/radar-nn-tracker-filter/<version>")` takes scaled windows
(batch x steps x features, float32) and gives what `load_model(path).predict` gives.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import nn

from pipeline.learning.experiment_tracking import DVC_EXPERIMENT_TAG, SESSION_TAG, data_hash, dvc_experiment, git_commit
from pipeline.learning.networks import KINDS

if TYPE_CHECKING:
    from mlflow import MlflowClient
    from mlflow.entities.model_registry import ModelVersion

log = logging.getLogger("pipeline")

EXAMPLE_WINDOWS = 4  # the input example: the first few training windows
# The dataset table keeps at most 36 characters of a digest; the run's input_data_sha256 tag has all 64.
DATASET_DIGEST_CHARS = 32
FILE_DIGEST_TAG = "pipeline.model_file_digest"  # data_hash of the bundle models/<kind>.pt the same run wrote
DESCRIPTIONS = {
    "filter": "Filter network: the last plots of a track in, the last of them denoised out (thesis 4.3).",
    "predictor": "Predictor network: a track's last states in, its next positions out (thesis 4.3).",
    "autoencoder": "Autoencoder: a window of plots in, reconstructed out; the reconstruction error tells a "
                   "track's plot from clutter (thesis 4.3).",
}


def registered_name(experiment: str, kind: str) -> str:
    """One registered model per network of an MLflow experiment."""
    return f"{experiment}-{kind}"


def log_training_windows(kind: str, material: Path, inputs: np.ndarray, targets: np.ndarray) -> None:
    """The windows the network trains on, as the active run's input dataset: named after the
    network, its digest the windows file's (so two runs on the same windows show the same one)."""
    import mlflow

    with warnings.catch_warnings():
        # MLflow registers its local-file dataset source twice (for "" and "file:" URIs) and
        # warns, for every local path, that it could be either: the same class.
        warnings.filterwarnings("ignore", message="The specified dataset source can be interpreted in multiple ways")
        dataset = mlflow.data.from_numpy(inputs, targets=targets, source=str(material), name=f"{kind} windows",
                                         digest=data_hash(material)[:DATASET_DIGEST_CHARS])
    mlflow.log_input(dataset, context="training")


def log_network(kind: str, network: nn.Module, windows: np.ndarray, experiment: str, bundle: Path,
                session: str) -> ModelVersion:
    """Log `network` to the active run with MLflow's PyTorch flavour and register it as a new
    version of its registered model, tagged so that the evaluate run and a DVC user find it.

    The network is only read: logging happens after the DVC outputs are written, and changes
    neither the weights nor any random state a later stage would draw from."""
    import mlflow
    from mlflow.models import infer_signature

    example = np.ascontiguousarray(windows[:EXAMPLE_WINDOWS], dtype=np.float32)
    with torch.no_grad():
        output = network(torch.from_numpy(example)).numpy()
    name = registered_name(experiment, kind)
    # Requirements given, not inferred: MLflow infers them by loading the model in a new
    # Python process, seconds per network for what these three lines say.
    info = mlflow.pytorch.log_model(
        network, name=kind, signature=infer_signature(example, output), input_example=example,
        registered_model_name=name, serialization_format="pt2",
        pip_requirements=[f"torch=={torch.__version__}", f"numpy=={np.__version__}",
                          f"mlflow=={mlflow.__version__}"])
    client = mlflow.MlflowClient()
    version = str(info.registered_model_version)
    tags = {FILE_DIGEST_TAG: data_hash(bundle), "git_commit": git_commit(), SESSION_TAG: session,
            "stage": f"train_{kind}"}
    named = dvc_experiment()
    if named:
        tags[DVC_EXPERIMENT_TAG] = named
    for key, value in tags.items():
        client.set_model_version_tag(name, version, key, value)
    if not client.get_registered_model(name).description:
        client.update_registered_model(name, DESCRIPTIONS[kind])
    log.info("train %s: MLflow model %s version %s (%s)", kind, name, version, info.model_uri)
    return client.get_model_version(name, version)


def logged_model_id(version: ModelVersion) -> str | None:
    """The id of the logged model a registered version was made from. A SQL store's versions
    leave `model_id` empty and name the logged model in their source, `models:/<model id>`."""
    source = version.source or ""
    return version.model_id or (source.removeprefix("models:/") if source.startswith("models:/m-") else None)


def versions_used(client: MlflowClient, experiment: str, models_dir: Path) -> dict[str, ModelVersion | None]:
    """For each network, the registered version whose training wrote the bundle in `models_dir`
    now (the newest, if the same bundle was registered more than once); None if none did (the
    bundle was trained with another store, or before models were registered). A network whose bundle is not in
    `models_dir` is left out: an evaluation of classical runs alone needs none."""
    found: dict[str, ModelVersion | None] = {}
    for kind in KINDS:
        if not (models_dir / f"{kind}.pt").is_file():
            continue
        digest = data_hash(models_dir / f"{kind}.pt")
        versions = client.search_model_versions(
            f"name = '{registered_name(experiment, kind)}' and tags.`{FILE_DIGEST_TAG}` = '{digest}'")
        found[kind] = max(versions, key=lambda version: int(version.version), default=None)
    return found

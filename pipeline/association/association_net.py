"""The seed's deep track-to-track association network (seed 002, section 3 and figure 1), its training and decision.

Network, per pair of tracks (radar 1's i, radar 2's j) of a scene:
- scene embedding of the (size, size, 3) scene tensor (`scene_tensor`): conv 3x3 to 3 channels, ReLU, max-pool 2,
  conv 4x4 to 1 channel, ReLU, max-pool to 6 x 6, flatten (36): the seed's layers; at the seed's size 32 the
  last pool is its 2 x 2 pool (12 -> 6), and the adaptive pool lets the same weights read larger scenes (ours);
- feature lifting of the pair's 1 x 3 statistical distances: fully connected 8, 16, 36, ReLU each. The
  distances span orders of magnitude (a wrong pair's can be 10⁵), so the network reads log(1 + d) (ours);
- decision: the two concatenated (72), fully connected 8 with ReLU, then 1 with a sigmoid (here a logit:
  the sigmoid is inside the binary cross-entropy, `BCEWithLogitsLoss`, for numerical safety).
Loss: binary cross-entropy against 1 for true pairs, 0 otherwise (section 2.2 (4)); Adam; the seed trains 50
epochs of 1000 freshly simulated scenes, each scene's pairs one batch (here `scenes_per_batch` scenes a batch).

Decision (section 3, last paragraph): each radar 1 track takes the radar 2 track of its row's largest
probability if that is above the threshold (the seed's 0.5); then one-to-one (ours: the seed does not say
what happens when two rows pick one column): candidates are taken by decreasing probability, a column once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from torch import Tensor, nn
from torch.utils.data import DataLoader

from pipeline.association.associator import Decision, TrackSet
from pipeline.association.scene_tensor import pair_features, scene_tensor
from pipeline.learning import model_store
from pipeline.learning.fit import FitConfig, Task
from pipeline.sections import subset

SCENE_EMBEDDING = 36   # the seed's flattened scene embedding (1 channel of 6 x 6)


@dataclass(frozen=True)
class AssociationNetConfig:
    size: int                         # scene tensor size N (the seed: 32), the most tracks a radar may have
    diameter_m: float                 # L_C, the scene diameter distances are divided by
    feature_hidden: tuple[int, ...]   # the feature lifting's layers (the seed: 8, 16, 36)
    decision_hidden: int              # the decision layer before the output (the seed: 8)


@dataclass(frozen=True)
class SceneInputs:
    """One scene for the network: `tensor` (size, size, 3), `features` (n * m, 3) row-major over pairs (i, j),
    `labels` (n * m,) 1.0 for true pairs (zeros when unknown), `shape` (n, m)."""

    tensor: np.ndarray
    features: np.ndarray
    labels: np.ndarray
    shape: tuple[int, int]


class AssociationNet(nn.Module):
    """Scene embedding + feature lifting + decision (module docstring); forward gives one logit per pair."""

    def __init__(self, config: AssociationNetConfig) -> None:
        super().__init__()
        self.config = config
        self.scene = nn.Sequential(nn.Conv2d(3, 3, 3), nn.ReLU(), nn.MaxPool2d(2), nn.Conv2d(3, 1, 4), nn.ReLU(),
                                   nn.AdaptiveMaxPool2d(6), nn.Flatten())
        layers: list[nn.Module] = []
        width = 3
        for hidden in config.feature_hidden:
            layers += [nn.Linear(width, hidden), nn.ReLU()]
            width = hidden
        self.features = nn.Sequential(*layers)
        self.decision = nn.Sequential(nn.Linear(SCENE_EMBEDDING + width, config.decision_hidden), nn.ReLU(),
                                      nn.Linear(config.decision_hidden, 1))

    def forward(self, scenes: Tensor, features: Tensor, scene_index: Tensor) -> Tensor:
        """Logits (P,) of P pairs: scenes (B, size, size, 3), features (P, 3) raw statistical distances,
        scene_index (P,) the scene of each pair."""
        embedded = self.scene(scenes.permute(0, 3, 1, 2))
        lifted = self.features(torch.log1p(features))
        return self.decision(torch.cat([embedded[scene_index], lifted], dim=1))[:, 0]


def scene_inputs(states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray, covariances2: np.ndarray,
                 config: AssociationNetConfig, true_pairs: np.ndarray | None = None) -> SceneInputs:
    """The network's inputs for two radars' tracks at a common time: states (n, d) / (m, d), covariances
    (n, d, d) / (m, d, d), ENU metres; `true_pairs` (K, 2) for training labels. TrackInputError on bad tracks
    or more tracks than `config.size` (`scene_probabilities` reads larger scenes)."""
    features = pair_features(states1, covariances1, states2, covariances2)
    n, m = features.shape[:2]
    labels = np.zeros((n, m), dtype=np.float32)
    if true_pairs is not None and len(true_pairs):
        labels[true_pairs[:, 0], true_pairs[:, 1]] = 1.0
    tensor = scene_tensor(np.asarray(states1)[:, :2], np.asarray(states2)[:, :2], config.size, config.diameter_m)
    return SceneInputs(tensor, features.reshape(n * m, 3).astype(np.float32), labels.reshape(-1), (n, m))


def collate(scenes: list[SceneInputs]) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Scenes as one batch: tensors (B, size, size, 3), features (P, 3), scene index (P,), labels (P,)."""
    counts = [len(scene.labels) for scene in scenes]
    return (torch.as_tensor(np.stack([scene.tensor for scene in scenes])),
            torch.as_tensor(np.concatenate([scene.features for scene in scenes])),
            torch.repeat_interleave(torch.arange(len(scenes)), torch.as_tensor(counts)),
            torch.as_tensor(np.concatenate([scene.labels for scene in scenes])))


def probabilities(model: AssociationNet, inputs: SceneInputs) -> np.ndarray:
    """(n, m) association probabilities of one scene."""
    scenes, features, index, _ = collate([inputs])
    with torch.no_grad():
        return torch.sigmoid(model(scenes, features, index)).numpy().reshape(inputs.shape)


def decide(probability: np.ndarray, threshold: float) -> np.ndarray:
    """Pairs (K, 2) sorted by row from (n, m) probabilities: row-wise maximum above `threshold`, then
    one-to-one by decreasing probability (module docstring)."""
    if not probability.size:
        return np.zeros((0, 2), dtype=np.int64)
    rows = np.arange(probability.shape[0])
    best = probability.argmax(axis=1)
    candidates = np.flatnonzero(probability[rows, best] > threshold)
    order = candidates[np.argsort(-probability[candidates, best[candidates]], kind="stable")]
    _, first = np.unique(best[order], return_index=True)
    kept = np.sort(order[first])
    return np.stack([kept, best[kept]], axis=1).astype(np.int64)


def neighbourhoods(positions1: np.ndarray, positions2: np.ndarray, size: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per radar 1 track i (n,): the rows (at most `size`, i first) of the radar 1 tracks nearest to it and the
    columns (at most `size`) of the radar 2 tracks nearest to it, from horizontal positions (n, 2), (m, 2) m."""
    out = []
    for i, position in enumerate(positions1):
        nearest = np.argsort(np.linalg.norm(positions1 - position, axis=1), kind="stable")
        rows = np.concatenate([[i], nearest[nearest != i]])[:size]
        columns = np.sort(np.argsort(np.linalg.norm(positions2 - position, axis=1), kind="stable")[:size])
        out.append((rows, columns))
    return out


def scene_probabilities(model: AssociationNet, states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                        covariances2: np.ndarray) -> np.ndarray:
    """(n, m) association probabilities of tracks at a common time (shapes as `scene_inputs`), for any n and m.

    Up to `size` tracks per radar the scene is read whole (the seed's). Beyond, it does not fit the scene tensor
    the network was trained on (ours): each radar 1 track i is read in its own scene of the `size` radar 1
    tracks and the `size` radar 2 tracks nearest to it (`neighbourhoods`; a true partner is near i unless the
    bias exceeds the neighbourhood's radius), and row i is taken from that scene; radar 2 tracks outside i's
    neighbourhood get probability 0. All n scenes go through the network as one batch. The decision being
    row-wise, each row still sees the distances to its competitors; what changes is the scene's extent."""
    size = model.config.size
    if len(states1) <= size and len(states2) <= size:
        return probabilities(model, scene_inputs(states1, covariances1, states2, covariances2, model.config))
    parts = neighbourhoods(np.asarray(states1)[:, :2], np.asarray(states2)[:, :2], size)
    scenes = [scene_inputs(states1[rows], covariances1[rows], states2[columns], covariances2[columns], model.config)
              for rows, columns in parts]
    batch, features, index, _ = collate(scenes)
    with torch.no_grad():
        flat = torch.sigmoid(model(batch, features, index)).numpy()
    probability = np.zeros((len(states1), len(states2)))
    begin = 0
    for i, ((_, columns), scene) in enumerate(zip(parts, scenes)):
        probability[i, columns] = flat[begin:begin + scene.shape[1]]  # row 0 of the scene is track i
        begin += len(scene.labels)
    return probability


def associate_network(model: AssociationNet, states1: np.ndarray, covariances1: np.ndarray, states2: np.ndarray,
                      covariances2: np.ndarray, threshold: float) -> np.ndarray:
    """Pairs (K, 2) the trained network decides for tracks at a common time (shapes as `scene_inputs`), any
    number of tracks (`scene_probabilities`)."""
    return decide(scene_probabilities(model, states1, covariances1, states2, covariances2), threshold)


@dataclass(frozen=True)
class NetworkAssociator:
    """`associate_network` at the current common time: the pairs the trained `model` decides at `threshold`."""

    model: AssociationNet
    threshold: float
    common_times = 1

    def associate_tracks(self, tracks1: TrackSet, tracks2: TrackSet) -> Decision:
        return Decision(associate_network(self.model, *tracks1.current, *tracks2.current, self.threshold), None)


class FreshScenes(L.LightningDataModule):
    """Every epoch new scenes from `make_epoch(epoch)` (the seed's fresh simulation per epoch), in batches."""

    def __init__(self, make_epoch: Callable[[int], list[SceneInputs]], scenes_per_batch: int) -> None:
        super().__init__()
        self.make_epoch, self.scenes_per_batch = make_epoch, scenes_per_batch

    def train_dataloader(self) -> DataLoader:
        scenes = self.make_epoch(self.trainer.current_epoch)
        return DataLoader(scenes, batch_size=self.scenes_per_batch, shuffle=False, collate_fn=collate)


class AssociationTraining(L.LightningModule):
    """Binary cross-entropy on every pair of every scene of a batch, with Adam; per-epoch pair accuracy at 0.5
    (`association.pair_accuracy`)."""

    def __init__(self, model: AssociationNet, learning_rate: float) -> None:
        super().__init__()
        self.model, self.learning_rate = model, learning_rate
        self.loss = nn.BCEWithLogitsLoss()

    def on_train_epoch_start(self) -> None:
        self._right, self._pairs = 0, 0

    def training_step(self, batch: tuple[Tensor, ...], batch_index: int) -> dict[str, Any]:
        scenes, features, index, labels = batch
        logits = self.model(scenes, features, index)
        self._right += int(((logits.detach() > 0) == (labels > 0.5)).sum())
        self._pairs += len(labels)
        return {"loss": self.loss(logits, labels), "weight": len(labels)}

    def on_train_epoch_end(self) -> None:
        self.log("association.pair_accuracy", self._right / max(self._pairs, 1))

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(self.model.parameters(), lr=self.learning_rate)


def training_task(model: AssociationNet, make_epoch: Callable[[int], list[SceneInputs]], knobs: Any,
                  deterministic: bool) -> Task:
    """`model` trained on the scenes of `make_epoch`, new ones every epoch, in batches of `scenes_per_batch`
    scenes in order (Lightning, on the CPU), by `knobs`: params' `association` section, or any with its
    `epochs`, `scenes_per_batch`, `learning_rate` and `seed`."""
    config = subset(FitConfig, knobs, label="the association network", loss_name="association.train_loss",
                    deterministic=deterministic, fresh_data_every_epoch=True)
    return Task(AssociationTraining(model, config.learning_rate), FreshScenes(make_epoch, knobs.scenes_per_batch),
                config)


def load(path: Path) -> AssociationNet:
    """A saved association network (`model_store.save_network`), ready to decide (eval mode); InputError naming a
    missing, unreadable or foreign file (`model_store.load_network`)."""
    return model_store.load_network(path, lambda config: AssociationNet(AssociationNetConfig(
        **{**config, "feature_hidden": tuple(config["feature_hidden"])})), "train_association")

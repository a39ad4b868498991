"""The seed's association network: its decision rule, a tiny training that pairs a straight aircraft, saving."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from pipeline import io
from pipeline.association import association_net
from pipeline.association.association_net import AssociationNet, AssociationNetConfig, decide, training_task
from pipeline.association.association_scenes import make_scene
from pipeline.bench.association_report import inputs_of
from pipeline.learning.fit import fit
from pipeline.learning.model_store import save_network
from tests.association_fixtures import SETTING, straight_aircraft

CONFIG = AssociationNetConfig(size=32, diameter_m=14142.0, feature_hidden=(8, 16, 36), decision_hidden=8)
# the training knobs of params' `association` section
SCHEDULE = SimpleNamespace(epochs=4, scenes_per_batch=4, learning_rate=0.01, seed=0)


def test_decision_is_row_maximum_above_threshold_then_one_to_one():
    probability = np.array([[0.9, 0.2, 0.1],    # row 0 takes column 0
                            [0.95, 0.6, 0.0],   # row 1 wants column 0 too, with more: row 1 keeps it, row 0 loses
                            [0.1, 0.3, 0.4]])   # row 2's best is under the threshold
    assert decide(probability, 0.5).tolist() == [[1, 0]]
    assert decide(np.zeros((0, 2)), 0.5).tolist() == []


def train_tiny() -> AssociationNet:
    """A few seconds of training on the seed's setting (4 epochs of 60 scenes)."""
    torch.manual_seed(0)
    model = AssociationNet(CONFIG)

    def make_epoch(epoch: int):
        return [inputs_of(make_scene(SETTING, 11, epoch * 60 + k), CONFIG) for k in range(60)]

    fit(*training_task(model, make_epoch, SCHEDULE, deterministic=True))
    return model


@pytest.fixture(scope="module")
def trained(one_torch_thread) -> AssociationNet:
    return train_tiny()


def test_training_twice_gives_the_same_weights(trained):
    again = train_tiny().state_dict()
    for name, weights in trained.state_dict().items():
        torch.testing.assert_close(again[name], weights, rtol=0, atol=0)


def test_trained_network_pairs_a_straight_aircraft_seen_without_bias(trained):
    x1, p1, x2, p2 = straight_aircraft(np.array([[1000.0, -2000.0]]), np.array([[150.0, 80.0]]), np.zeros(2))
    assert association_net.associate_network(trained, x1[-1], p1[-1], x2[-1], p2[-1], 0.5).tolist() == [[0, 0]]


def test_saved_network_decides_the_same(trained, tmp_path):
    save_network(tmp_path / "association_net.pt", trained)
    loaded = association_net.load(tmp_path / "association_net.pt")
    inputs = inputs_of(make_scene(SETTING, 12, 0), CONFIG)
    np.testing.assert_array_equal(association_net.probabilities(loaded, inputs),
                                  association_net.probabilities(trained, inputs))


def test_a_loss_that_goes_nan_stops_the_training(one_torch_thread):
    """Learning rate 1e30: the cross-entropy is NaN after the first step; stopped at the second batch."""
    torch.manual_seed(0)
    model = AssociationNet(CONFIG)
    scenes = [inputs_of(make_scene(SETTING, 11, k), CONFIG) for k in range(8)]
    with pytest.raises(io.TrainingDiverged, match="training of the association network stopped: the training loss "
                                                  "became nan at epoch 1 of 2, batch 2"):
        fit(*training_task(model, lambda epoch: scenes, SimpleNamespace(epochs=2, scenes_per_batch=4, learning_rate=1e30,
                                                                        seed=0), deterministic=True))


def test_neighbourhoods_hold_the_track_first_and_at_most_size_tracks():
    positions1 = np.array([[0.0, 0.0], [0.0, 0.0], [5000.0, 0.0], [100.0, 0.0]])  # rows 0 and 1 coincide
    positions2 = np.array([[90.0, 0.0], [4900.0, 0.0], [-20.0, 0.0]])
    parts = association_net.neighbourhoods(positions1, positions2, 2)
    assert [rows.tolist() for rows, _ in parts] == [[0, 1], [1, 0], [2, 3], [3, 0]]
    assert [columns.tolist() for _, columns in parts] == [[0, 2], [0, 2], [0, 1], [0, 2]]


def test_network_pairs_more_aircraft_than_its_scene_size(trained):
    grid = np.stack(np.meshgrid(np.arange(8), np.arange(5)), -1).reshape(-1, 2) * 3000.0 - 10000.0  # 40 > 32
    velocities = np.tile([[150.0, 80.0], [-120.0, 60.0]], (20, 1))
    x1, p1, x2, p2 = straight_aircraft(grid, velocities, np.zeros(2))
    pairs = association_net.associate_network(trained, x1[-1], p1[-1], x2[-1], p2[-1], 0.5)
    assert pairs.tolist() == [[k, k] for k in range(40)]
    probability = association_net.scene_probabilities(trained, x1[-1], p1[-1], x2[-1], p2[-1])
    assert probability.shape == (40, 40)

"""Every file the tracker loads, and every trained piece, as one entry each.

A `Piece` is a file of the models folder: its name (what a tracking method `needs`, and
`models[name]` in the tracker), its file, the `dvc repro` stage that makes it and how it is loaded.
A `Kind` is a trained piece: also the command that trains it and its `Recipe`, the code that trains
it (its params section, data, network, Lightning task and hold-out; `pipeline.learning.recipe`),
which `pipeline.learning.runner.run_training` runs the same way for every kind. The loaders and
recipes are imported when a piece is loaded or trained, so naming the pieces loads no network library.

Adding a trained estimator is its model module (the network and its `Recipe`), one entry here, its
params section and its `dvc.yaml` stage, beside its estimator module and registry entry in
`pipeline/tracker` (README "Adding a trained estimator: a worked example"). The association network,
scored by the bench's association methods, has its entry in `pipeline/bench/association_training.py`, and the
learned track confirmation's, trained on the tracker's candidate tracks, in `pipeline/bench/confirmation_training.py`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from pipeline import io
from pipeline.learning.recipe import Recipe

if TYPE_CHECKING:
    from pipeline.params import Params


@dataclass(frozen=True, kw_only=True)
class Piece:
    """A file of the models folder the tracker loads (module docstring): `load(path, params)` gives it ready
    to use (InputError naming the file when it is missing or bad); `network`: a torch network (the tracker
    runs those on one thread)."""

    name: str
    file: str
    stage: str
    load: Callable[[Path, Params], Any]
    network: bool = True

    def load_from(self, models_dir: Path, params: Params) -> Any:
        """The piece in `models_dir`; InputError naming its stage when its file is missing."""
        path = models_dir / self.file
        if not path.is_file():
            raise io.InputError(f"{path}: file not found (run `dvc repro {self.stage}`)")
        return self.load(path, params)


@dataclass(frozen=True, kw_only=True)
class Kind(Piece):
    """A trained piece: `command` (`python -m pipeline <command>`, the run's source), `recipe` (imports and
    gives its `Recipe`), `registers`: its network logged and registered as an MLflow model (the thesis's)."""

    command: str
    recipe: Callable[[], Recipe]
    registers: bool = False


def _windows_network(name: str, scaler: str) -> Kind:
    """The thesis's network `name` (`pipeline.learning.training`), trained by `python -m pipeline train` on
    windows of the `scaler` layout (`materials.scalers`: "plots" or "states"), which it must keep."""
    def load(path: Path, params: Params) -> Any:
        from pipeline.learning import materials
        from pipeline.learning.model_store import load_model
        return load_model(path, name, materials.scalers(params.windows)[scaler])

    def recipe() -> Recipe:
        from pipeline.learning.training import WindowNetworkRecipe
        return WindowNetworkRecipe(name, scaler)
    return Kind(name=name, file=f"{name}.pt", stage=f"train_{name}", command="train", load=load, recipe=recipe,
                registers=True)


def _load_kalman_net(path: Path, params: Params) -> Any:
    from pipeline.learning import kalman_net
    return kalman_net.load(path)


def _kalman_net_recipe() -> Recipe:
    from pipeline.learning.kalman_net_training import KalmanNetRecipe
    return KalmanNetRecipe()


def _load_lstm_update(path: Path, params: Params) -> Any:
    from pipeline.learning import lstm_update
    return lstm_update.load(path)


def _lstm_update_recipe() -> Recipe:
    from pipeline.learning.lstm_update_training import LSTMUpdateRecipe
    return LSTMUpdateRecipe()


def _load_tuned_filters(path: Path, params: Params) -> Any:
    """`models/kalman_tuned.json` (the tune stage's): the tuned classical filters by kind."""
    from pipeline.filters import classical_filters
    try:
        return classical_filters.load_settings(path)
    except ValueError as error:
        raise io.InputError(f"{error}; make it again with `dvc repro tune_kalman`") from None


def _load_confirmation(path: Path, params: Params) -> Any:
    from pipeline.learning import confirmation
    return confirmation.load(path)


TUNED_FILTERS = "kalman_tuned"

KINDS: dict[str, Kind] = {kind.name: kind for kind in [
    *(_windows_network(name, scaler) for name, scaler in (("predictor", "states"), ("filter", "plots"),
                                                          ("autoencoder", "plots"))),
    Kind(name="lstm_update", file="lstm_update.pt", stage="train_lstm_update", command="train-lstm-update",
         load=_load_lstm_update, recipe=_lstm_update_recipe),
    Kind(name="kalman_net", file="kalman_net.pt", stage="train_kalman_net", command="train-kalman-net",
         load=_load_kalman_net, recipe=_kalman_net_recipe),
]}
# the learned confirmation's network: trained on the tracker's candidate tracks, so its `Kind` is the bench's
# (`pipeline.bench.confirmation_training`), and the tracker loads it as a piece of its track management
CONFIRMATION = Piece(name="confirmation", file="confirmation.pt", stage="train_confirmation", load=_load_confirmation)
# every piece, in the order the tracker loads them
PIECES: dict[str, Piece] = {piece.name: piece for piece in [
    *(KINDS[name] for name in ("predictor", "filter", "autoencoder")),
    Piece(name=TUNED_FILTERS, file="kalman_tuned.json", stage="tune_kalman", load=_load_tuned_filters, network=False),
    *(KINDS[name] for name in ("lstm_update", "kalman_net")), CONFIRMATION,
]}

"""Loading what a run's tracking methods need, and nothing else (the pieces each method needs are
in `pipeline.tracker.registry`).

A classical method needs only the tuned filters (`models/kalman_tuned.json`), so `track
--method imm` works in a checkout without trained networks; a neural method needs the
predictor and filter networks, `ae` the autoencoder too, `kalman_net` the network-scaled filter
(`models/kalman_net.pt`). A network whose scaler differs from what params describe is refused
(it would be fed differently scaled windows).

Errors (io.InputError, exit 2 from the command line) name the missing or bad file and the
`dvc repro` stage that makes it.
"""

from __future__ import annotations

from pathlib import Path

from pipeline import io
from pipeline.filters import classical_filters
from pipeline.learning import materials
from pipeline.params import Params
from pipeline.tracker import registry
from pipeline.tracker.models import Models

# piece -> (file in the models folder, the stage that makes it)
PIECES = {"predictor": ("predictor.pt", "train_predictor"), "filter": ("filter.pt", "train_filter"),
          "autoencoder": ("autoencoder.pt", "train_autoencoder"),
          registry.TUNED_FILTERS: ("kalman_tuned.json", "tune_kalman"),
          registry.LSTM_UPDATE: ("lstm_update.pt", "train_lstm_update"),
          registry.KALMAN_NET: ("kalman_net.pt", "train_kalman_net")}
SCALER_OF_NETWORK = {"predictor": "states", "filter": "plots", "autoencoder": "plots"}


def _path(models_dir: Path, piece: str, methods: list[str]) -> Path:
    """The piece's file, which must exist."""
    name, stage = PIECES[piece]
    path = models_dir / name
    if not path.is_file():
        users = sorted({m for m in methods if piece in registry.method(m).needs})
        raise io.InputError(f"{path}: file not found; {', '.join(users)} need{'s' if len(users) == 1 else ''} it "
                            f"(make it with `dvc repro {stage}`)")
    return path


def load_models(models_dir: Path, params: Params, methods: list[str]) -> Models:
    """What `methods` (registered names) need from `models_dir`, checked against params.

    Raises registry.UnknownMethod for a name not registered, io.InputError for a missing or bad file."""
    from_models_dir = {piece: _path(models_dir, piece, methods) for piece in sorted(registry.needs(methods))}
    networks = {}
    if any(piece in SCALER_OF_NETWORK for piece in from_models_dir):
        from pipeline.learning.model_store import load_model  # imports torch: only when a network is needed
        expected = materials.scalers(params.windows)
        for kind, layout in SCALER_OF_NETWORK.items():
            if kind not in from_models_dir:
                continue
            path = from_models_dir[kind]
            model = load_model(path, expected_kind=kind)
            if model.scaler != expected[layout]:
                raise io.InputError(f"{path}: built with the scaler {model.scaler}, but params give "
                                    f"{expected[layout]}; retrain it (dvc repro {PIECES[kind][1]})")
            networks[kind] = model
    filters = {}
    if registry.TUNED_FILTERS in from_models_dir:
        path = from_models_dir[registry.TUNED_FILTERS]
        try:
            filters = classical_filters.load_settings(path)
        except ValueError as error:
            raise io.InputError(f"{error}; make it again with `dvc repro tune_kalman`") from None
        for name in methods:
            kind = registry.method(name).filter_kind
            if kind is not None and kind not in filters:
                raise io.InputError(f"{path}: has no tuned {kind} filter, which {name} runs (make it with "
                                    "`dvc repro tune_kalman`)")
    lstm_update = None
    if registry.LSTM_UPDATE in from_models_dir:
        from pipeline.learning import lstm_update as lstm_update_module  # imports torch: only when the method runs
        lstm_update = lstm_update_module.load(from_models_dir[registry.LSTM_UPDATE])
    kalman_net = None
    if registry.KALMAN_NET in from_models_dir:
        import torch

        from pipeline.learning import kalman_net as kalman_net_module  # imports torch: only when the method runs
        torch.set_num_threads(1)  # as for the networks (`Models`): the tracker steps a few tracks at a time
        kalman_net = kalman_net_module.load(from_models_dir[registry.KALMAN_NET])
    return Models(networks.get("predictor"), networks.get("filter"), networks.get("autoencoder"), filters,
                  params.tracker.inference, lstm_update=lstm_update, kalman_net=kalman_net)

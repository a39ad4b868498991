"""Loading what a run's tracking methods need, and nothing else (the pieces each method needs are
in `pipeline.tracker.registry`; each piece's file, stage and loader in `pipeline.learning.kinds.PIECES`).

A classical method needs only the tuned filters (`models/kalman_tuned.json`), so `track
--method imm` works in a checkout without trained networks; a neural method needs the
predictor and filter networks, `ae` the autoencoder too, `kalman_net` the network-scaled filter
(`models/kalman_net.pt`). A network whose scaler differs from what params describe is refused
(it would be fed differently scaled windows).

Errors (io.InputError, exit 2 from the command line) name the missing or bad file and the
`dvc repro` stage that makes it.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from pipeline import io
from pipeline.learning.kinds import PIECES, TUNED_FILTERS
from pipeline.params import Params
from pipeline.tracker import registry
from pipeline.tracker.models import Models


def _path(models_dir: Path, piece: str, methods: list[str]) -> Path:
    """The piece's file, which must exist."""
    path = models_dir / PIECES[piece].file
    if not path.is_file():
        users = sorted({m for m in methods if piece in registry.method(m).needs})
        raise io.InputError(f"{path}: file not found; {', '.join(users)} need{'s' if len(users) == 1 else ''} it "
                            f"(make it with `dvc repro {PIECES[piece].stage}`)")
    return path


def model_paths(models_dir: Path, methods: list[str]) -> dict[str, Path]:
    """Piece -> the file in `models_dir` that `methods` need of it (registered names; io.InputError naming a
    missing one and the stage that makes it)."""
    return {piece: _path(models_dir, piece, methods) for piece in sorted(registry.needs(methods))}


def load_models(models_dir: Path, params: Params, methods: list[str], rules: Iterable[str | None] = (None,)
                ) -> Models:
    """What `methods` (registered names) and the track management `rules` (None: the tracker's own) need from
    `models_dir`, checked against params, loaded in the order of `PIECES`.

    Raises registry.UnknownMethod for a name not registered, io.InputError for a missing or bad file,
    ParamError for a `tracker.device` this machine lacks when a method runs kalman_net or lstm_update."""
    needed = registry.needs(methods) | registry.rule_needs(
        params.tracker.management.rule if rule is None else rule for rule in rules)
    if needed & {registry.KALMAN_NET, registry.LSTM_UPDATE}:
        from pipeline.learning import devices

        devices.resolve(params.tracker.device)  # ParamError before any file is read when the device is not here
    paths = model_paths(models_dir, methods)
    for piece in needed - set(paths):  # a management rule's
        paths[piece] = models_dir / PIECES[piece].file
        if not paths[piece].is_file():
            raise io.InputError(f"{paths[piece]}: file not found; track management {registry.LEARNED_RULE!r} needs it "
                                f"(make it with `dvc repro {PIECES[piece].stage}`)")
    if any(PIECES[piece].network for piece in needed):
        import torch

        torch.set_num_threads(1)  # the tracker steps a few tracks at a time: threads only add contention
    pieces = {piece: PIECES[piece].load(paths[piece], params) for piece in PIECES if piece in needed}
    for name in methods:
        kind = registry.method(name).filter_kind
        if kind is not None and kind not in pieces[TUNED_FILTERS]:
            raise io.InputError(f"{paths[TUNED_FILTERS]}: has no tuned {kind} filter, which {name} runs (list {kind} "
                                "in kalman.filters and run `dvc repro tune_kalman`)")
    return Models(pieces, params.tracker.inference)

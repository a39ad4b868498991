"""What a trained piece's recipe is (`Recipe`), and what the runner hands it and takes from it.

`pipeline.learning.runner.run_training` trains every kind of `pipeline.learning.kinds` by the same
steps; a kind's `Recipe` (in the module that trains it) gives the steps that differ: its data, its
network, its Lightning task and its hold-out.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import numpy as np
    from torch import nn

    from pipeline.learning.fit import Fitted, Task
    from pipeline.learning.scaling import WindowScaler
    from pipeline.learning.tracking_logger import TrainingLogger
    from pipeline.params import Params


@dataclass(frozen=True)
class Folders:
    """The folders a training reads and writes (the command line's defaults)."""

    simulated: Path = Path("data/simulated")
    windows: Path = Path("data/windows")
    models: Path = Path("models")
    reports: Path = Path("reports")


@dataclass
class Inputs:
    """What a kind trains on, read and checked before its MLflow run opens: `data`, the kind's own;
    `described` for the log line; `source`, the file hashed as the run's `input_data_sha256` (None:
    simulated as it trains); `windows`, (inputs, targets) logged as the run's input dataset, the first
    windows the registered model's input example; `scaler`, the windows' scaler kept in the bundle."""

    data: Any
    described: str
    source: Path | None = None
    windows: tuple[np.ndarray, np.ndarray] | None = None
    scaler: WindowScaler | None = None


@dataclass
class Trained:
    """A kind's network after `fit`, with what its hold-out reads."""

    network: nn.Module
    task: Task
    fitted: Fitted
    inputs: Inputs
    params: Params
    folders: Folders
    logger: TrainingLogger


@dataclass
class Outcome:
    """What a kind's hold-out gives: `extras` kept in the bundle; `files` written after it, in order (bytes,
    text or JSON by their type), those in `artifacts` logged to the run after the bundle; `metrics` logged
    to the run; `summary`, the stage's last log line."""

    extras: dict[str, Any]
    files: dict[Path, bytes | str | dict] = field(default_factory=dict)
    artifacts: tuple[Path, ...] = ()
    metrics: dict[str, float] = field(default_factory=dict)
    summary: str = ""


class Recipe(Protocol):
    """How a kind is trained. The runner calls, in order: `data` (before the store is touched), `build`
    (after seeding with `knobs(params).seed`: the initial weights), `task` (fitted once, `fit(*task)`) and
    `holdout`; `logged` gives the run's params."""

    def knobs(self, params: Params) -> Any: ...

    def logged(self, params: Params) -> dict[str, Any]: ...

    def data(self, params: Params, folders: Folders) -> Inputs: ...

    def build(self, params: Params, inputs: Inputs) -> nn.Module: ...

    def task(self, network: nn.Module, inputs: Inputs, params: Params) -> Task: ...

    def holdout(self, trained: Trained) -> Outcome: ...


class SectionRecipe:
    """The `knobs` and `logged` of a recipe whose knobs are one params section, named by `section`
    (`kalman_net`, `lstm_update`, `association`): the section, logged whole as `<section>.<key>`."""

    section: str

    def knobs(self, params: Params) -> Any:
        return getattr(params, self.section)

    def logged(self, params: Params) -> dict[str, Any]:
        return section_params(self.section, self.knobs(params))


def section_params(prefix: str, section: object) -> dict[str, Any]:
    """A params section's values as an MLflow run logs them: `<prefix>.<key>`."""
    return {f"{prefix}.{key}": value for key, value in asdict(section).items()}

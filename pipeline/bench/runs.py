"""An evaluated run as a record, carried with its metrics through the bench and the reports.

A run is what params declare (`params.EvaluationRun`: a method, its window and its track management rule, or a
reference of `evaluate.references`) and its method's family from the tracker's registry (`neural`,
`classical`; `reference` for every reference). Its name (`via_4000`, `imm_4000_m_of_n`, `oracle_reference`,
`EvaluationRun.name`) is the key of its metrics in the reports' JSON and nothing more: no reader cuts a name
back into its parts. The bench keys its results by the record (`evaluation.evaluate_all`); a stage writes them
by name (`by_name`); a reader that holds only a report keyed by name looks each name up among params' declared
runs (`declared_runs`: `evaluate.runs`, of which the scenes' and the sites' runs are a part, and the
references) and carries the records from there (`with_records`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

from pipeline import io
from pipeline.params import Evaluate, EvaluationRun, Params
from pipeline.tracker import registry

Value = TypeVar("Value")


@dataclass(frozen=True)
class Run:
    """One evaluated run: `declared`, its params record, and `family`, its method's (`registry.NEURAL`,
    `registry.CLASSICAL`) or `registry.REFERENCE` for a reference."""

    declared: EvaluationRun
    family: str

    @property
    def name(self) -> str:
        return self.declared.name

    @property
    def method(self) -> str:
        return self.declared.method

    @property
    def window_m(self) -> float:
        return self.declared.window_m

    @property
    def management(self) -> str | None:
        """The rule the run names (None: the tracker's, `tracker.management.rule`; every reference's)."""
        return self.declared.management

    @property
    def reference(self) -> bool:
        return self.declared.reference

    @property
    def registered(self) -> registry.Method | None:
        """The registry's method of the run; None for the raw-plots reference, which is no tracker."""
        return registry.METHODS.get(self.method)


def record(declared: EvaluationRun) -> Run:
    """The run of a params record, with its family (UnknownMethod for a tracker the registry does not have)."""
    return Run(declared, registry.REFERENCE if declared.reference else registry.method(declared.method).family)


def evaluated(evaluate: Evaluate) -> list[Run]:
    """Every run of `evaluate.runs`, then every reference, in params order: what the evaluate stage scores."""
    return [record(run) for run in (*evaluate.runs, *evaluate.reference_runs())]


def declared_runs(params: Params) -> dict[str, Run]:
    """Params' declared runs and references by name, in params order."""
    return {run.name: run for run in evaluated(params.evaluate)}


def by_name(results: Mapping[Run, Value]) -> dict[str, Value]:
    """`results` keyed by run name, as the reports' JSON keys them, in the same order."""
    return {run.name: value for run, value in results.items()}


def with_records(report: Mapping[str, Value], declared: Mapping[str, Run], source: str | Path) -> dict[Run, Value]:
    """A report's runs, keyed by name, keyed by their records (`declared`, by name), in the report's order;
    InputError naming `source` when it holds a run params do not declare."""
    unknown = [name for name in report if name not in declared]
    if unknown:
        raise io.InputError(f"{source}: runs {unknown} are not runs of params evaluate ({list(declared)}); "
                            "run `dvc repro evaluate`")
    return {declared[name]: value for name, value in report.items()}

"""Config classes taken from params sections by field name.

A config class that holds part of a params section (a network's design values, a training's
schedule) is filled from the section by its fields' names: `subset(LSTMUpdateConfig,
params.lstm_update)`. A knob added to both is then read without a third list that copies the
section's values by position, and a field the section does not have is named at once.
"""

from __future__ import annotations

from dataclasses import MISSING, fields
from typing import Any, TypeVar

T = TypeVar("T")


def subset(cls: type[T], *sections: object, **given: Any) -> T:
    """The dataclass `cls` with each field from `given`, else from the first of `sections` that has an
    attribute of the field's name, else the field's default. TypeError naming `cls` and the field when
    none gives it."""
    values = {}
    for field in fields(cls):
        if field.name in given:
            values[field.name] = given[field.name]
            continue
        source = next((section for section in sections if hasattr(section, field.name)), None)
        if source is not None:
            values[field.name] = getattr(source, field.name)
        elif field.default is MISSING and field.default_factory is MISSING:
            raise TypeError(f"{cls.__name__}.{field.name}: no section given has it, and it has no default")
    unknown = set(given) - {field.name for field in fields(cls)}
    if unknown:
        raise TypeError(f"{cls.__name__} has no field {sorted(unknown)}")
    return cls(**values)

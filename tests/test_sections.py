"""`sections.subset`: a config class filled from params sections by its fields' names."""

from __future__ import annotations

from dataclasses import dataclass, fields

import pytest

from pipeline.learning.lstm_update import LSTMUpdateConfig
from pipeline.sections import subset


@dataclass(frozen=True)
class Schedule:
    epochs: int
    learning_rate: float
    deterministic: bool
    label: str = "a schedule"


def test_each_field_comes_from_what_is_given_else_the_first_section_that_has_it_else_its_default(make_params):
    params = make_params(1)
    schedule = subset(Schedule, params.kalman_net, params.training, learning_rate=0.5)
    assert schedule == Schedule(params.kalman_net.epochs, 0.5, params.training.deterministic, "a schedule")


def test_a_model_config_is_its_section_by_name(make_params):
    """The LSTM update's config: every one of its fields is the `lstm_update` section's of that name."""
    section = make_params(1).lstm_update
    config = subset(LSTMUpdateConfig, section)
    assert all(getattr(config, field.name) == getattr(section, field.name) for field in fields(LSTMUpdateConfig))


def test_a_field_no_section_gives_and_an_unknown_given_field_are_named(make_params):
    with pytest.raises(TypeError, match=r"Schedule.deterministic: no section given has it"):
        subset(Schedule, make_params(1).kalman_net)
    with pytest.raises(TypeError, match=r"Schedule has no field \['epochz'\]"):
        subset(Schedule, make_params(1).training, epochz=3, epochs=1, learning_rate=0.1)

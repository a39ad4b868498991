"""The worked example of adding an estimator (docs/architecture.md), run as written: its module and its
registry entry, taken from the page's code blocks, give a method that tracks a straight target."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import numpy as np

from pipeline.tracker import registry
from pipeline.tracker.loading import load_models
from pipeline.tracker.run import track
from tests import tracker_fixtures as tf
from tests.project import REPOSITORY

PAGE = REPOSITORY / "docs" / "architecture.md"


def example(marker: str) -> str:
    """The Python block after `<!-- example: marker -->` in docs/architecture.md."""
    after = PAGE.read_text().split(f"<!-- example: {marker} -->", 1)[1]
    return re.search(r"```python\n(.*?)```", after, re.S).group(1)


def test_the_alpha_beta_example_is_one_module_and_one_entry_and_tracks(monkeypatch, tmp_path: Path):
    """The example's module, importable as pipeline.tracker.alpha_beta, and its registry entry, added
    to the registry: loading its needs reads no file, and on 20 plots of a straight 216 m/s flight it
    gives one track holding them all, confirmed from the fourth plot, within 100 m of the flight from
    the tenth plot on."""
    module = types.ModuleType("pipeline.tracker.alpha_beta")
    exec(compile(example("estimator module"), "docs/architecture.md: pipeline/tracker/alpha_beta.py", "exec"), module.__dict__)
    monkeypatch.setitem(sys.modules, "pipeline.tracker.alpha_beta", module)
    definition, entry = example("registry entry").strip().rsplit("\n\n", 1)
    namespace = dict(vars(registry))
    exec(compile(definition, "docs/architecture.md: registry entry", "exec"), namespace)
    method = eval(entry, namespace)
    monkeypatch.setitem(registry.METHODS, method.name, method)

    params = tf.make_params()
    models = load_models(tmp_path, params, ["alpha_beta"])
    features = tf.straight_features(params.radar, (50e3, 80e3, 9000.0), (-180.0, 120.0, 0.0), 20)
    updates = track(tf.plots_of(features, np.arange(20), params.radar),
                    registry.compose("alpha_beta", models, params.tracker, 4000.0, params.tracker.seed))
    assert updates["track_id"].tolist() == [0] * 20
    assert updates["association"].tolist() == ["start", "radius"] + ["alpha_beta"] * 18
    np.testing.assert_allclose(updates["weight"][3:], 1.0)
    estimates = np.column_stack([updates[f"{axis}_ecef_m"] for axis in "xyz"])
    assert np.linalg.norm(estimates[9:] - features[9:, 1:4], axis=1).max() < 100.0

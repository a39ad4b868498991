"""models/kalman_tuned.json as the tracker reads it: a hand-edited or damaged file is refused by name.

A negative probability or spread does not make a filter fail, it changes every track silently,
so the reader checks each value and names the file, the filter, the key and the value."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from pipeline import io
from pipeline.filters.classical_filters import FilterSettings, load_settings

TUNED = {
    "cv": FilterSettings("cv", (1.5,), 110.0, 10.0, 0.05, 0.9),
    "ca": FilterSettings("ca", (0.3,), 400.0, 10.0, 0.05, 0.9),
    "imm": FilterSettings("imm", (0.8, 0.47), 122.0, 10.0, 0.05, 0.9),
    "imm_ct": FilterSettings("imm_ct", (0.8, 1.9), 122.0, 10.0, 0.05, 0.9, 4.2),
    "imm_ca_ct": FilterSettings("imm_ca_ct", (0.8, 0.47, 1.9), 122.0, 10.0, 0.05, 0.9, 4.2),
}


def tuned_file(folder: Path, **changes: dict) -> Path:
    """A tuned-filter file like the tune stage's, with some filters' entries changed as a hand
    edit would (`imm={"switch_probability": -0.05}`, NaN too); an entry changed to None is left out."""
    filters = {kind: settings.to_dict() for kind, settings in TUNED.items()}
    for kind, entries in changes.items():
        filters[kind].update(entries)
        filters[kind] = {key: value for key, value in filters[kind].items() if value is not None}
    path = folder / "kalman_tuned.json"
    path.write_text(json.dumps({"cost": "rmse", "filters": filters}))
    return path


def test_the_tune_stages_file_loads_as_its_five_filters(tmp_path):
    assert load_settings(tuned_file(tmp_path)) == TUNED


def test_probabilities_at_their_bounds_are_accepted(tmp_path):
    """0 and 1 are probabilities: a new IMM track may start as surely CV, and never switch."""
    filters = load_settings(tuned_file(tmp_path, imm={"switch_probability": 0.0, "initial_cv_probability": 1}))
    assert (filters["imm"].switch_probability, filters["imm"].initial_cv_probability) == (0.0, 1)


@pytest.mark.parametrize(("kind", "entries", "named"), [
    ("imm", {"switch_probability": -0.05}, "filter 'imm', switch_probability = -0.05: must be a probability in [0, 1]"),
    ("imm", {"initial_cv_probability": 1.5}, "filter 'imm', initial_cv_probability = 1.5: must be a probability"),
    ("cv", {"switch_probability": "0.05"}, "filter 'cv', switch_probability = '0.05': must be a probability"),
    ("cv", {"velocity_std_mps": -110.4}, "filter 'cv', velocity_std_mps = -110.4: must be a finite standard deviation"),
    ("ca", {"acceleration_std_mps2": 0.0}, "filter 'ca', acceleration_std_mps2 = 0.0: must be a finite standard"),
    ("ca", {"velocity_std_mps": True}, "filter 'ca', velocity_std_mps = True: must be a finite standard"),
    ("imm", {"noise_std": [0.8, -0.47]}, "filter 'imm', noise_std[1] = -0.47: must be a finite standard"),
    ("cv", {"noise_std": [float("inf")]}, "filter 'cv', noise_std[0] = inf: must be a finite standard"),
    ("cv", {"noise_std": [float("nan")]}, "filter 'cv', noise_std[0] = nan: must be a finite standard"),
    ("imm", {"noise_std": [0.8]}, "filter 'imm', noise_std = [0.8]: must list 2 standard deviation(s)"),
    ("imm", {"kind": "cv"}, "filter 'imm', kind = 'cv': must be 'imm'"),
    ("imm", {"switch_probability": None}, "filter 'imm': key 'switch_probability' missing"),
    ("cv", {"noise": [1.0]}, "filter 'cv': key 'noise': unknown"),
    ("imm_ct", {"turn_rate_dps": 0.0}, "filter 'imm_ct', turn_rate_dps = 0.0: must be a finite standard deviation"),
    ("imm_ct", {"turn_rate_dps": float("nan")}, "filter 'imm_ct', turn_rate_dps = nan: must be a finite"),
    ("imm_ct", {"noise_std": [0.8, 1.9, 1.9]}, "filter 'imm_ct', noise_std = [0.8, 1.9, 1.9]: must list 2 standard "
                                               "deviation(s), one per motion model ('cv9', 'ct')"),
    ("imm", {"turn_rate_dps": 3.0}, "filter 'imm', turn_rate_dps = 3.0: must be 0, imm has no turning model"),
    ("imm_ca_ct", {"noise_std": [0.8, 1.9]}, "filter 'imm_ca_ct', noise_std = [0.8, 1.9]: must list 3 standard "
                                             "deviation(s), one per motion model ('cv9', 'ca', 'ct')"),
    ("cv", {"turn_rate_dps": None}, "filter 'cv': key 'turn_rate_dps' missing"),
])
def test_a_value_out_of_range_is_refused_naming_file_filter_key_and_value(tmp_path, kind, entries, named):
    path = tuned_file(tmp_path, **{kind: entries})
    with pytest.raises(io.InputError, match=re.escape(f"{path}: {named}")):
        load_settings(path)


def test_a_file_without_one_of_the_filters_is_refused_naming_it(tmp_path):
    path = tmp_path / "kalman_tuned.json"
    path.write_text(json.dumps({"filters": {kind: TUNED[kind].to_dict() for kind in ("cv", "imm")}}))
    with pytest.raises(io.InputError, match=re.escape(f"{path}: filter 'ca': missing")):
        load_settings(path)


def test_the_filters_kalman_filters_may_add_may_be_absent(tmp_path):
    """kalman.filters leaves the IMM with CA and turns out by default: a file without it loads, without it."""
    path = tmp_path / "kalman_tuned.json"
    path.write_text(json.dumps({"filters": {kind: TUNED[kind].to_dict() for kind in ("cv", "ca", "imm", "imm_ct")}}))
    assert list(load_settings(path)) == ["cv", "ca", "imm", "imm_ct"]


def test_a_missing_file_says_which_stage_makes_it(tmp_path):
    with pytest.raises(io.InputError, match=r"kalman_tuned.json: no tuned Kalman filters; run `dvc repro tune_kalman`"):
        load_settings(tmp_path / "kalman_tuned.json")

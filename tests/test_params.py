"""params.yaml: the defaults load, and a bad value stops with a ParamError naming the key and the value."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from pipeline.bench.runs import declared_runs
from pipeline.params import STRATEGIES, ParamError
from pipeline.settings import load_params, parse_params
from tests.project import run_pipeline, write_params

PARAMS_YAML = Path(__file__).resolve().parents[1] / "params.yaml"


def set_key(tree, dotted, value):
    *parents, key = dotted.split(".")
    for parent in parents:
        tree = tree[parent]
    tree[key] = value


def test_default_params_load():
    """The committed params.yaml is valid and holds the thesis's radar and three independent splits."""
    params = load_params(PARAMS_YAML)
    assert params.radar.scan_period_s == pytest.approx(6.0)
    assert params.radar.range_max_m == 400e3
    assert [split.name for split in params.routes.splits] == ["train", "test", "calibration"]
    assert len({split.seed for split in params.routes.splits}) == 3
    for split in params.routes.splits:
        assert set(split.counts) == set(STRATEGIES) and all(count > 0 for count in split.counts.values())
        assert set(split.aircraft_mix) <= set(params.aircraft)
    assert (params.routes.random_turns.length_min_m, params.routes.random_turns.length_max_m) == (300e3, 500e3)


@pytest.mark.parametrize("key, value, fragments", [
    ("routes.splits.train.constant_jerk", -1, ["routes.splits.train.constant_jerk", "-1"]),
    ("aircraft.airliner.speed_mps", [300, 200], ["aircraft.airliner.speed_mps", "[300, 200]", "above"]),
    ("routes.splits.test.aircraft_mix.zeppelin", 0.1, ["routes.splits.test.aircraft_mix.zeppelin", "unknown"]),
    ("radar.latitude_deg", 95, ["radar.latitude_deg", "95"]),
    ("routes.splits.calibration.seed", 1001, ["routes.splits", "seed", "1001"]),
    ("radar.rotation_rpm", 0.0, ["radar.rotation_rpm", "0.0"]),
    ("radar.range_min_m", 500e3, ["radar.range_min_m", "500000.0"]),
    ("routes.start_time_utc", "tomorrow", ["routes.start_time_utc", "tomorrow"]),
    ("aircraft.fighter.altitude_m", [1000.0, 16000.0], ["aircraft.fighter.altitude_m", "16000.0"]),
    # the sustained_turns and climb_dive strategies and the envelope keys only they read
    ("routes.splits.train.climb_dive", -1, ["routes.splits.train.climb_dive", "-1"]),
    ("routes.sustained_turns.turn_rate_dps", [3.0, 1.5], ["routes.sustained_turns.turn_rate_dps", "above"]),
    ("routes.sustained_turns.turn_rate_dps", [0.0, 3.0], ["routes.sustained_turns.turn_rate_dps", "(0, inf]"]),
    ("routes.sustained_turns.holding_probability", 1.5, ["routes.sustained_turns.holding_probability", "1.5"]),
    ("routes.sustained_turns.straight_s", [-60.0, 300.0], ["routes.sustained_turns.straight_s", "-60.0"]),
    ("routes.climb_dive.vertical_rate_fraction", [0.5, 1.5], ["routes.climb_dive.vertical_rate_fraction", "1.5"]),
    ("routes.climb_dive.vertical_acceleration_fraction", 0.0, ["routes.climb_dive.vertical_acceleration_fraction"]),
    ("routes.climb_dive.altitude_change_m", [2000.0, 4000.0], ["routes.climb_dive.altitude_change_m",
                                                               "aircraft.light"]),
    ("routes.climb_dive.turn_rate_dps", -1.0, ["routes.climb_dive.turn_rate_dps", "-1.0"]),
    ("aircraft.light.max_vertical_rate_mps", 80.0, ["aircraft.light.max_vertical_rate_mps", "80.0"]),
    ("aircraft.airliner.holding_speed_mps", [0.0, 120.0], ["aircraft.airliner.holding_speed_mps", "positive"]),
    # impossible training schedules
    ("training.predictor.early_stopping_min_improvement", -0.01,
     ["training.predictor.early_stopping_min_improvement", "-0.01"]),
    ("training.autoencoder.lr_decay_factor", 0.0, ["training.autoencoder.lr_decay_factor", "0.0"]),
    ("compute.workers", 0, ["compute.workers", "0"]),
    ("compute.chunk_plots", 0, ["compute.chunk_plots", "0"]),
    # track management
    ("tracker.management.rule", "mofn", ["tracker.management.rule", "'mofn'", "m_of_n"]),
    ("tracker.management.confirm_m", 6, ["tracker.management.confirm_m = 6", "tracker.management.confirm_n = 5"]),
    ("tracker.management.confirm_n", 0, ["tracker.management.confirm_n", "0"]),
    ("tracker.management.confirm_n", 53, ["tracker.management.confirm_n = 53", "at most 52"]),
    ("tracker.management.delete_after_s", 0.0, ["tracker.management.delete_after_s", "0.0"]),
    # learned gates (issue 27): a switch, and a share of the plots in the window
    ("tracker.lstm_update.young_window_fallback", "yes",
     ["tracker.lstm_update.young_window_fallback = 'yes'", "true or false"]),
    ("tracker.refusal_warning_share", 0.0, ["tracker.refusal_warning_share = 0.0", "(0.0, 1.0]"]),
    ("tracker.refusal_warning_share", 1.5, ["tracker.refusal_warning_share = 1.5", "(0.0, 1.0]"]),
    # GOSPA: a positive cutoff, and an order for which it is a metric
    ("evaluate.gospa_cutoff_m", 0.0, ["evaluate.gospa_cutoff_m", "0.0"]),
    ("evaluate.gospa_order", 0.5, ["evaluate.gospa_order = 0.5", "[1.0, inf]"]),
    # the bench's draws and intervals (issue 30): at least one draw, an interval narrower than all
    ("evaluate.seeds", 0, ["evaluate.seeds", "0"]),
    ("evaluate.confidence", 1.0, ["evaluate.confidence", "1.0"]),
    ("evaluate.bootstrap_replicates", 5, ["evaluate.bootstrap_replicates", "5"]),
    # the fusion stage's local tracker must give covariances (a network's tracks would stop it after a scene)
    ("fusion.tracker", "via", ["fusion.tracker = 'via'", "'imm_gnn'", "radius, via, mia, ae give none"]),
    ("fusion.methods", ["statistical", "statistical"], ["fusion.methods", "distinct"]),
    # a share of the range is at most all of it
    ("lstm_update.range_shares", [0.05, 1.5], ["lstm_update.range_shares = [0.05, 1.5]", "(0, 1]"]),
])
def test_invalid_value_names_key_and_value(params_tree, key, value, fragments):
    """An invalid value raises ParamError whose message names the key and the value."""
    set_key(params_tree, key, value)
    with pytest.raises(ParamError) as error:
        parse_params(params_tree)
    for fragment in fragments:
        assert fragment in str(error.value)


def test_a_run_of_a_filter_not_tuned_stops_at_the_params_naming_the_run_and_the_knob(params_tree):
    """kalman.filters without imm_ct while evaluate.runs holds imm_ct_gnn: refused when params are read (the
    first stage), not when the evaluation loads the tuned filters an hour later."""
    params_tree["kalman"]["filters"] = ["cv", "ca", "imm"]
    index = [run["method"] for run in params_tree["evaluate"]["runs"]].index("imm_ct_gnn")
    with pytest.raises(ParamError, match=re.escape(
            f"evaluate.runs[{index}].method = 'imm_ct_gnn': runs the imm_ct filter, which kalman.filters = "
            "['cv', 'ca', 'imm'] does not tune (list imm_ct there)")):
        parse_params(params_tree)


@pytest.mark.parametrize("section, key", [("radar", "sigma_range_m"), ("routes", "sample_interval_s"),
                                          ("simulate", "seed"), ("routes", "climb_dive")])
def test_missing_key_is_named(params_tree, section, key):
    """A missing key raises ParamError naming its full path."""
    del params_tree[section][key]
    with pytest.raises(ParamError, match=f"{section}.{key}: missing"):
        parse_params(params_tree)


@pytest.mark.parametrize("key", ["early_stopping_patience", "lr_decay_patience"])
def test_patience_longer_than_the_run_is_refused(params_tree, key):
    """A patience above the epochs could never act: it is an error naming both keys."""
    set_key(params_tree, "training.autoencoder.epochs", 40)
    set_key(params_tree, f"training.autoencoder.{key}", 41)
    with pytest.raises(ParamError, match=rf"training.autoencoder.{key} = 41: above training.autoencoder.epochs = 40"):
        parse_params(params_tree)


def test_early_stopping_without_validation_windows_is_refused(params_tree):
    """Early stopping watches the validation loss, so it needs a validation share."""
    set_key(params_tree, "training.filter.validation_fraction", 0.0)
    set_key(params_tree, "training.filter.early_stopping_patience", 5)
    with pytest.raises(ParamError, match=r"training.filter.early_stopping_patience = 5.*validation_fraction = 0"):
        parse_params(params_tree)


def test_load_params_names_the_file(params_tree, tmp_path):
    """load_params reports the file as well as the key and value of a bad setting."""
    params_tree["radar"]["latitude_deg"] = 95
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params_tree))
    with pytest.raises(ParamError, match=r"params\.yaml: radar\.latitude_deg = 95"):
        load_params(path)
    with pytest.raises(ParamError, match="not found"):
        load_params(tmp_path / "missing.yaml")


@pytest.mark.parametrize("given", ["folder", "binary"])
def test_a_params_path_that_is_not_a_text_file_is_named(tmp_path, given):
    """`--params` naming a folder or a Parquet file (a slip of the shell's completion) was a traceback (exit 1)."""
    path = tmp_path / "params.yaml"
    if given == "folder":
        path.mkdir()
    else:
        path.write_bytes(b"PAR1\x15\x04\xff\xfe")
    with pytest.raises(ParamError, match=re.escape(f"{path}: not a readable params file")):
        load_params(path)


def test_learning_rate_as_dvc_writes_it_is_a_float(params_tree, tmp_path):
    """`dvc exp run -S training.predictor.learning_rate=0.000001` writes `learning_rate: 1e-06`
    (YAML 1.2: no point before the exponent), which YAML 1.1 would read as a string."""
    text = yaml.safe_dump(params_tree, sort_keys=False).replace("learning_rate: 0.005", "learning_rate: 1e-06")
    path = tmp_path / "params.yaml"
    path.write_text(text)
    assert load_params(path).training.networks["predictor"].learning_rate == 1e-06


@pytest.mark.parametrize("written, value", [("1e-06", 1e-06), ("2e-3", 0.002), ("1E-4", 1e-4), (".5", 0.5),
                                            ("-1.5e+3", -1500.0), ("-.5", -0.5)])
def test_yaml_1_2_floats_are_floats(params_tree, tmp_path, written, value):
    """Every way YAML 1.2 (DVC's YAML) writes a float is read as that float."""
    text = yaml.safe_dump(params_tree, sort_keys=False).replace("reference_snr_db: 16.0", f"reference_snr_db: {written}")
    path = tmp_path / "params.yaml"
    path.write_text(text)
    assert load_params(path).radar.reference_snr_db == value


@pytest.mark.parametrize("key, near", [("radar.sigma_rnage_m", "sigma_range_m"),
                                       ("training.predictor.learning_rte", "learning_rate"),
                                       ("routes.splits.test.sede", "seed")])
def test_misspelt_key_beside_the_real_one_is_named_with_the_nearest_known_key(params_tree, key, near):
    """A misspelt key left beside the real one would leave the run on the real key's value without a
    word: it is an error that names the key, its value and the key the user probably meant."""
    set_key(params_tree, key, 400.0)
    with pytest.raises(ParamError, match=rf"^{re.escape(key)} = 400.0: unknown key \(did you mean {near}\?\)$"):
        parse_params(params_tree)


def test_user_named_entries_are_not_unknown_keys(params_tree):
    """Aircraft types, splits and their mixes are named by the user: a new one is read, not refused."""
    params_tree["aircraft"]["glider"] = dict(params_tree["aircraft"]["light"])
    params_tree["routes"]["splits"]["extra"] = {**params_tree["routes"]["splits"]["test"], "seed": 9009}
    params_tree["routes"]["splits"]["extra"]["aircraft_mix"] = {"glider": 1.0}
    params = parse_params(params_tree)
    assert "glider" in params.aircraft and params.routes.split("extra").aircraft_mix == {"glider": 1.0}


def test_unknown_key_stops_the_command_with_exit_2(params_tree, tmp_path):
    """From the command line an unknown key is exit 2 and one line naming the file and the key,
    before anything is written."""
    params_tree["radar"]["sigma_rnage_m"] = 400.0
    path = write_params(params_tree, tmp_path / "params.yaml")
    result = run_pipeline("routes", "--params", str(path), "--out", str(tmp_path / "routes"))
    assert result.returncode == 2
    assert f"{path}: radar.sigma_rnage_m = 400.0: unknown key (did you mean sigma_range_m?)" in result.stderr
    assert not (tmp_path / "routes").exists()


def test_a_run_may_name_its_track_management_rule_and_its_name_then_says_it(params_tree):
    """`evaluate.runs` entries without `management` keep their names (the tracker's rule); one
    naming its rule is `<method>_<window>_<rule>`, and by that name its record, with the registry's
    method, is found among params' runs; a rule that does not exist is named with its run."""
    params_tree["evaluate"]["site_runs"] = params_tree["evaluate"]["scene_runs"] = params_tree["peers"]["runs"] = []
    params_tree["evaluate"]["runs"] = [{"method": "via", "window_m": 4000.0}, {"method": "imm", "window_m": 4000.0},
                                       {"method": "imm", "window_m": 4000.0, "management": "m_of_n"}]
    runs = parse_params(params_tree).evaluate.runs
    assert [run.name for run in runs] == ["via_4000", "imm_4000", "imm_4000_m_of_n"]
    assert runs[-1].management == "m_of_n" and all(run.management is None for run in runs[:-1])
    assert declared_runs(parse_params(params_tree))["imm_4000_m_of_n"].registered.name == "imm"
    params_tree["evaluate"]["runs"][-1]["management"] = "weights"
    with pytest.raises(ParamError, match=rf"evaluate.runs\[{len(runs) - 1}\].management = 'weights': must be one of"):
        parse_params(params_tree)


def test_default_sites_cover_the_earth(params_tree):
    """The default `evaluate.sites`: at least three besides the training site, between them both
    hemispheres, both sides of the antimeridian, the equator and above 65 N."""
    sites = parse_params(params_tree).evaluate.sites
    assert len(sites) >= 3
    assert any(s.latitude_deg < 0 for s in sites) and any(s.latitude_deg > 65 for s in sites)
    assert any(s.latitude_deg == 0 for s in sites)
    assert any(s.longitude_deg > 179 for s in sites) and any(s.longitude_deg < -179 for s in sites)
    params_tree["evaluate"]["sites"] = []
    assert parse_params(params_tree).evaluate.sites == ()


def test_site_runs_choose_the_runs_scored_at_the_sites(params_tree):
    """`evaluate.site_runs` names runs of `evaluate.runs` (in runs order at the sites); [] scores
    them all; a name that is not a run is refused with the runs listed."""
    evaluate = parse_params(params_tree).evaluate
    assert [run.name for run in evaluate.runs_at_sites()] == [
        name for name in (run.name for run in evaluate.runs) if name in evaluate.site_runs]
    assert len(evaluate.runs_at_sites()) == len(evaluate.site_runs) < len(evaluate.runs)
    params_tree["evaluate"]["site_runs"] = []
    assert parse_params(params_tree).evaluate.runs_at_sites() == parse_params(params_tree).evaluate.runs
    params_tree["evaluate"]["site_runs"] = ["via_4000", "imm_400"]
    with pytest.raises(ParamError, match=r"evaluate.site_runs = \['via_4000', 'imm_400'\]: must list distinct names"):
        parse_params(params_tree)


SITE = {"name": "tromso", "latitude_deg": 69.68, "longitude_deg": 18.94, "height_m": 100.0}


@pytest.mark.parametrize("sites, fragments", [
    ({"tromso": SITE}, ["evaluate.sites = ", "must be a list"]),
    ([{**SITE, "latitude_deg": -90.5}], ["evaluate.sites[0].latitude_deg = -90.5", "[-90.0, 90.0]"]),
    ([{**SITE, "longitude_deg": -180.0}], ["evaluate.sites[0].longitude_deg = -180.0", "(-180.0, 180.0]"]),
    ([{**SITE, "longitude_deg": 180.5}], ["evaluate.sites[0].longitude_deg = 180.5"]),
    ([{**SITE, "height_m": float("nan")}], ["evaluate.sites[0].height_m = nan", "finite"]),
    ([{**SITE, "name": "north cape"}], ["evaluate.sites[0].name = 'north cape'", "identifier"]),
    ([{**SITE, "name": "7th"}], ["evaluate.sites[0].name = '7th'"]),
    ([SITE, {**SITE, "latitude_deg": 0.0}], ["evaluate.sites", "['tromso', 'tromso']", "repeat"]),
    ([{k: v for k, v in SITE.items() if k != "height_m"}], ["evaluate.sites[0].height_m: missing"]),
    (["tromso"], ["evaluate.sites[0] = 'tromso'", "mapping"]),
    ([{**SITE, "altitude_m": 3.0}], ["evaluate.sites[0].altitude_m = 3.0", "unknown key"]),
])
def test_invalid_site_names_key_and_value(params_tree, sites, fragments):
    """A bad `evaluate.sites` entry raises ParamError naming the entry's key and the value."""
    params_tree["evaluate"]["sites"] = sites
    with pytest.raises(ParamError) as error:
        parse_params(params_tree)
    for fragment in fragments:
        assert fragment in str(error.value)


def test_a_site_at_the_antimeridian_is_plus_180(params_tree):
    """+180 and -180 are one meridian: written once, as +180."""
    params_tree["evaluate"]["sites"] = [{**SITE, "longitude_deg": 180}]
    assert parse_params(params_tree).evaluate.sites[0].longitude_deg == 180.0


@pytest.mark.parametrize("key, value, message", [
    ("double_threshold_hits", 5, "association.double_threshold_hits = 5: above the track history"),
    ("tracks", "smoothed", "association.tracks = 'smoothed': must be one of"),
    ("noise_m", [50.0, 0.0], "association.noise_m = [50.0, 0.0]: must be two positive numbers"),
    ("scene_size", 8, "association.scene_size = 8: must be an integer >= 10"),
    ("eval_bias_m", [], "association.eval_bias_m = []: must list non-negative numbers"),
])
def test_bad_association_value_is_named(params_tree, key, value, message):
    params_tree["association"][key] = value
    with pytest.raises(ParamError, match=re.escape(message)):
        parse_params(params_tree)


def test_the_peers_runs_are_runs_of_the_evaluation(params_tree):
    """`peers.runs` names runs of `evaluate.runs` (a name that is none is an error naming the key); [] takes the
    scenes' runs."""
    params_tree["peers"]["runs"] = ["imm_gnn_4000", "kalman_ukf_4000"]
    with pytest.raises(ParamError, match=r"peers.runs = \['imm_gnn_4000', 'kalman_ukf_4000'\]: must list distinct"):
        parse_params(params_tree)
    params_tree["peers"]["runs"] = []
    params = parse_params(params_tree)
    assert params.peers.runs_of(params.evaluate) == params.evaluate.runs_on_scenes()
    params_tree["peers"]["stone_soup"]["associations"] = ["gnn", "mht"]
    with pytest.raises(ParamError, match="peers.stone_soup.associations"):
        parse_params(params_tree)

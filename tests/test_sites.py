"""The evaluated routes at other radar sites (`pipeline.bench.sites`, stage `evaluate_sites`).

The same route placed past a radar anywhere on Earth is the same tracking problem: the
classical trackers, which filter in ECEF with isotropic process noise, must score the same
at every site, the poles' neighbourhood and both sides of the antimeridian included. The
stage runs on the shared tiny pipeline, whose params put one site at the training site (it
must reproduce `evaluate`'s metrics exactly) and one at 60 S, just west of the antimeridian.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline import io
from pipeline.bench import sites
from pipeline.params import Site
from pipeline.reports import comparison_tables, site_report
from pipeline.simulation import routes
from pipeline.stages.evaluate_sites_stage import training_runs
from pipeline.surveillance import scorecard
from tests import tracker_fixtures as tf
from tests.project import environment

TRAINING = Site("training", 60.3172, 24.9633, 60.0)  # params.yaml's radar
SITES = [TRAINING, *(Site(name, latitude, longitude, TRAINING.height_m) for name, latitude, longitude in (
    ("south", -60.0, 10.0), ("dateline_east", 10.0, 179.9), ("dateline_west", 0.0, -179.9),
    ("far_north", 69.7, 18.9)))]
INVARIANT = ("MAE", "OSPA", "OSPA_p90", "ROCA", "NOMT", "NOPA")


@pytest.fixture(scope="module")
def one_route(tmp_path_factory: pytest.TempPathFactory):
    """Params with one test route, the classical trackers and both references, and a models
    folder with the filters at their start values (no network needed)."""
    params = tf.make_params({"routes.splits.test.constant_jerk": 0, "routes.splits.test.random_turns": 1,
                             "routes.splits.test.sustained_turns": 0, "routes.splits.test.climb_dive": 0,
                             "evaluate.site_runs": [], "evaluate.scene_runs": [],
                             "evaluate.runs": [{"method": "kalman_cv", "window_m": 4000.0},
                                               {"method": "imm", "window_m": 4000.0}],
                             "evaluate.example_run": "kalman_cv_4000", "compute.workers": 1})
    models = tmp_path_factory.mktemp("models")
    io.write_json({"cost": "rmse", "filters": {kind: settings.to_dict()
                                               for kind, settings in tf.untuned_filters(params).items()}},
                  models / "kalman_tuned.json")
    return params, models


def test_classical_trackers_score_the_same_at_every_site(one_route):
    """One route at five sites (60 N, 60 S, either side of the antimeridian, the equator, 70 N),
    the antenna at the same height: the same plots, and each classical tracker's metrics within 1 % of the training site's.
    ANEES is not compared: the plots' covariance ignores the error of the thesis's conversion
    (one earth radius for every direction, eq. 4.2), which is largest at the equator."""
    params, models = one_route
    entries = [sites.evaluate_site(params, site, models) for site in SITES]
    home = entries[0]
    assert home["runs"]["kalman_cv_4000"]["NOPA"] > 0
    for entry in entries[1:]:
        assert entry["plots"] == home["plots"]
        for name in ("kalman_cv_4000", "imm_4000", "oracle_reference"):
            for metric in INVARIANT:
                assert entry["runs"][name][metric] == pytest.approx(home["runs"][name][metric], rel=0.01), \
                    (entry["name"], name, metric)


def test_routes_are_the_same_manoeuvres_at_every_site():
    """Moving the radar moves the routes, not their shape: the same times, east-north tracks and
    altitudes; on the antimeridian the longitudes wrap into (-180, 180] on both sides, and the
    ECEF tracks stay as smooth as at home (no jump where the longitude does)."""
    params = tf.make_params({"routes.splits.test.constant_jerk": 3, "routes.splits.test.random_turns": 3})
    split = params.routes.split(params.evaluate.split)
    home = routes.generate_split(sites.at_site(params, TRAINING), split)
    away = routes.generate_split(sites.at_site(params, Site("dateline", 0.0, 180.0, TRAINING.height_m)), split)
    for column in ("time_unix_s", "east_m", "north_m", "altitude_m"):
        np.testing.assert_array_equal(away.column(column).to_numpy(), home.column(column).to_numpy())
    longitude = away.column("longitude_deg").to_numpy()
    assert (longitude > -180).all() and (longitude <= 180).all()
    assert (longitude > 179).any() and (longitude < -179).any()

    def steps(table):
        ecef = np.column_stack([table.column(f"{axis}_ecef_m").to_numpy() for axis in "xyz"])
        return np.linalg.norm(np.diff(ecef, axis=0), axis=1)
    np.testing.assert_allclose(steps(away), steps(home), rtol=0.01)


def evaluate_sites(repository: Path, reports: Path, workers: int) -> dict:
    """`python -m pipeline evaluate-sites` over the tiny pipeline's models, with `workers`,
    writing to `reports` (which gets a copy of its `evaluate` metrics)."""
    tree = yaml.safe_load((repository / "params.yaml").read_text())
    tree["compute"]["workers"] = workers
    reports.mkdir()
    (reports / "params.yaml").write_text(yaml.safe_dump(tree, sort_keys=False))
    shutil.copy(repository / "reports" / "tracker_metrics.json", reports)
    result = subprocess.run([sys.executable, "-m", "pipeline", "evaluate-sites", "--params",
                             str(reports / "params.yaml"), "--models", str(repository / "models"),
                             "--reports", str(reports)], cwd=reports, env=environment(), capture_output=True,
                            text=True)
    assert result.returncode == 0, result.stderr[-5000:]
    assert "site south_dateline kalman_cv_4000:" in result.stderr  # a line per run and site, as evaluate logs
    return json.loads((reports / "site_metrics.json").read_text())


@pytest.mark.slow
def test_stage_on_the_tiny_pipeline(tiny_pipeline: Path, tmp_path: Path):
    """The stage on the tiny pipeline: the same bytes with one worker as with two; the site at
    the training site gives `evaluate`'s metrics exactly; the other has every run, and the
    comparison puts both in its table."""
    alone = evaluate_sites(tiny_pipeline, tmp_path / "one", 1)
    evaluate_sites(tiny_pipeline, tmp_path / "two", 2)
    assert (tmp_path / "one" / "site_metrics.json").read_bytes() == (tmp_path / "two" / "site_metrics.json").read_bytes()
    assert [site["name"] for site in alone["sites"]] == ["home", "south_dateline"]
    home, away = alone["sites"]
    assert home["runs"] == alone["training"]["runs"] and home["plots"] == alone["training"]["plots"]
    assert home["pcrb_horizontal_rms_m"] == alone["training"]["pcrb_horizontal_rms_m"]  # the bound where evaluate's is
    assert set(away["pcrb_horizontal_rms_m"]) == {"cv", "ca"}
    assert sorted(away["runs"]) == sorted(alone["training"]["runs"])
    assert all("plots_per_second" not in values for values in away["runs"].values())
    comparison = site_report.site_comparison(alone)
    assert comparison["runs"]["kalman_cv_4000"]["sites"]["home"]["ratio"] == 1.0
    table = site_report.site_table(comparison, sorted(comparison["runs"]))
    assert "south_dateline (60.0° S, 179.9° E)" in table and "| via_4000 |" in table


def test_site_comparison_marks_what_moves_more_than_the_tolerance():
    """Ratios to the training site's MAE, `within` at most 10 % away, n/a without an MAE."""
    def entry(name, via, kalman):
        return {"name": name, "latitude_deg": 1.0, "longitude_deg": -2.0, "height_m": 0.0,
                "runs": {"via_4000": {"MAE": via}, "kalman_cv_4000": {"MAE": kalman}}}
    report = {"training": entry("training", 200.0, 100.0),
              "sites": [entry("a", 219.0, 100.0), entry("b", 230.0, None)]}
    comparison = site_report.site_comparison(report)
    via, kalman = comparison["runs"]["via_4000"], comparison["runs"]["kalman_cv_4000"]
    assert via["sites"]["a"] == {"MAE": 219.0, "ratio": pytest.approx(1.095), "within": True}
    assert via["sites"]["b"]["within"] is False and not via["within_everywhere"]
    assert kalman["sites"]["b"] == {"MAE": None, "ratio": None, "within": False}
    table = site_report.site_table(comparison, ["via_4000", "kalman_cv_4000"])
    assert "| via_4000 | 200 | 219, 1.095 | 230, 1.150 **off** | no |" in table
    assert "| kalman_cv_4000 | 100 | 100, 1.000 | n/a | no |" in table
    assert site_report.site_sentence(comparison, ["via_4000"]) == (
        "- Radar sites: 0 of 1 neural trackers keep their position error (MAE) within 10% of the training "
        "site's at all 2 other sites; the largest change: via_4000 at b, ratio 1.150.")
    runs = {"via_4000": {"OSPA": 2.0}, "kalman_cv_4000": {"OSPA": 1.0}, "via_4000_m_of_n": {"OSPA": 3.0}}
    sentence, table = comparison_tables.sites_section(comparison, tf.run_records(runs))  # one not at the sites: left out
    assert "via_4000_m_of_n" not in table and table.index("kalman_cv_4000") < table.index("| via_4000")


def test_stale_evaluate_metrics_are_refused(tmp_path: Path):
    """The training site's row must be of params' runs: metrics of other runs name the stage to rerun."""
    params = tf.make_params({"evaluate.site_runs": [], "evaluate.scene_runs": [], "evaluate.runs": [{"method": "kalman_cv", "window_m": 4000.0}],
                             "evaluate.example_run": "kalman_cv_4000"})
    io.write_json({"runs": {"via_4000": {"MAE": 1.0}}}, tmp_path / "tracker_metrics.json")
    with pytest.raises(io.InputError, match=r"runs \['via_4000'\], but params evaluate \['kalman_cv_4000', "
                                            r"'oracle_reference', 'plots_reference'\]; run `dvc repro evaluate`"):
        training_runs(params, tmp_path / "tracker_metrics.json")


def test_no_other_sites_no_section():
    """With `evaluate.sites: []` the comparison has no radar-sites section."""
    training = {"name": "training", "latitude_deg": 60.0, "longitude_deg": 25.0, "height_m": 60.0,
                "runs": {"via_4000": {"MAE": 200.0}}}
    comparison = site_report.site_comparison({"training": training, "sites": []})
    assert comparison_tables.sites_section(comparison, tf.run_records({"via_4000": {"OSPA": 1.0}})) == []


def test_every_other_site_gets_its_scorecard_with_the_bound_there():
    """The comparison's radar sites section: a scorecard table per site but the training one, with the PCRB's
    horizontal RMS at that site beside it; runs in the order given, the ones not scored there left out."""
    card = {name: 1.0 for name in (*scorecard.INDICATORS, *scorecard.COUNTS)}
    runs = {"via_4000": {**card, "GOSPA": 300.0}, "oracle_reference": {**card, "GOSPA": 200.0}}
    report = {"split": "test", "training": {"name": "training", "runs": runs},
              "sites": [{"name": "tromso", "runs": runs, "pcrb_horizontal_rms_m": {"cv": 281.0, "ca": 293.0}}]}
    blocks = comparison_tables.site_scorecards(report, ["oracle_reference", "kalman_cv_4000"])
    assert blocks[0].startswith("The surveillance scorecard on the test routes at site tromso")
    assert "| oracle_reference |" in blocks[1] and "via_4000" not in blocks[1]
    assert "281 m under the tuned CV model, 293 m under the tuned CA model" in blocks[2]

"""`python -m pipeline associate`: two users' track tables, each made by `track` from one radar's plots,
associated at common times by every method and fused; and the bad input it refuses (exit 2, no output).

The two radars (the default site and one about 120 km away, their scans 3 s apart) see one straight
aircraft; each user tracks only its own radar's plots with the best classical method (imm_gnn), which
needs only the tuned filters (`tracker_fixtures.write_tuned_filters`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from scipy.stats import chi2

from pipeline import cli
from pipeline.association import association_net
from pipeline.association.registry import ASSOCIATORS
from pipeline.bench import association_report
from pipeline.geometry import geodesy
from pipeline.learning.fit import fit
from pipeline.learning.model_store import save_network
from pipeline.params import ParamError
from tests import tracker_fixtures as tf
from tests.project import write_params

SECOND_SITE = (61.2, 23.1, 120.0)  # about 120 km from the default radar
SCANS = 20
NOISE_M = 40.0  # position noise of the plots, per ECEF axis
SITE_ERROR_M = 400.0  # the biased second user's site error, east: beyond the chi-square gate of its tracks


@pytest.fixture(scope="module")
def params():
    return tf.make_params()


@pytest.fixture(scope="module")
def models(tmp_path_factory, params) -> Path:
    """The tuned filters and an association network trained briefly on the seed's setting (a few epochs of
    small scenes: enough to pair one aircraft whose tracks agree)."""
    folder = tf.write_tuned_filters(tmp_path_factory.mktemp("models"), params)
    association = tf.make_params({"association.epochs": 4, "association.scenes_per_epoch": 100}).association
    torch.manual_seed(association.seed)
    model = association_net.AssociationNet(association_report.network_config(association))
    fit(*association_net.training_task(model, association_report.training_epoch(association), association,
                                        deterministic=True))
    save_network(folder / "association_net.pt", model)
    return folder


def track_user(folder: Path, params, params_path: Path, models: Path, radar_id: int,
               site: tuple[float, float, float] | None, site_error_east_m: float = 0.0) -> tuple[Path, Path]:
    """One user's track table (`track --method imm_gnn` on its own radar's noisy plots of the aircraft) and its
    radar description, whose site may be wrong by `site_error_east_m` (a registration bias: the user's tracks
    are then that far off)."""
    velocity = np.array([180.0, 90.0, 0.0])
    offset = {1: 0.0, 2: 3.0}[radar_id]  # the second radar's scans 3 s after the first's
    radar = params.radar if site is None else tf.radar_at(params.radar, *site)
    start = np.array([40e3, 60e3, 9000.0]) + velocity * offset
    features = tf.straight_features(params.radar, tuple(start), tuple(velocity), SCANS, t_offset=offset)
    features[:, 1:4] += np.random.default_rng(radar_id).normal(0.0, NOISE_M, (len(features), 3))
    plots = tf.measurement_table(features, 1000 * radar_id + np.arange(len(features)), radar, radar_id,
                                 scenario_id=7)
    east = geodesy.enu_rotation(radar.latitude_deg, radar.longitude_deg)[0]
    latitude, longitude, height = geodesy.ecef_to_geodetic(geodesy.radar_site_ecef(radar) + site_error_east_m * east)
    described = tf.radar_at(radar, float(latitude), float(longitude), float(height))
    plots_path, radar_path = tf.write_recording(folder, plots, tf.radar_table(radar_id, described))
    tracks = folder / "tracks.parquet"
    assert cli.main(["track", "--params", str(params_path), "--plots", str(plots_path), "--radar",
                     str(radar_path), "--models", str(models), "--method", "imm_gnn", "--out", str(tracks)]) == 0
    return tracks, radar_path


@pytest.fixture(scope="module")
def users(tmp_path_factory, params, models) -> dict[str, Path]:
    """Each user's track table and radar description, and the second user's again with its site wrong."""
    folder = tmp_path_factory.mktemp("users")
    out = {"params": write_params(tf.params_tree(), folder / "params.yaml")}
    for radar_id, site in ((1, None), (2, SECOND_SITE)):
        out[f"tracks{radar_id}"], out[f"radar{radar_id}"] = track_user(folder / f"user{radar_id}", params,
                                                                       out["params"], models, radar_id, site)
    out["biased_tracks2"], out["biased_radar2"] = track_user(folder / "biased", params, out["params"], models, 2,
                                                             SECOND_SITE, SITE_ERROR_M)
    return out


def associate(users: dict[str, Path], models: Path, out: Path, method: str = "statistical",
              tracks: tuple[Path, Path] | None = None, radars: tuple[Path, Path] | None = None) -> int:
    tracks = tracks or (users["tracks1"], users["tracks2"])
    radars = radars or (users["radar1"], users["radar2"])
    return cli.main(["associate", "--params", str(users["params"]), "--tracks", *map(str, tracks),
                     "--radar", *map(str, radars), "--method", method, "--models", str(models),
                     "--pairs", str(out / "pairs.parquet"), "--fused", str(out / "fused.parquet")])


@pytest.mark.parametrize("method", ASSOCIATORS)
def test_every_method_pairs_the_two_radars_tracks_of_one_aircraft(users, models, tmp_path, method):
    """One confirmed track per user, the same aircraft: at every common time where both have a state, the
    one pair; the fused picture holds one fused row per pair, between the two tracks, and no unpaired rows
    at those times (double threshold: from its history's length on)."""
    assert associate(users, models, tmp_path, method) == 0
    pairs = pq.read_table(tmp_path / "pairs.parquet").to_pydict()
    fused = pq.read_table(tmp_path / "fused.parquet").to_pydict()
    assert len(pairs["time_unix_s"]) >= 5
    assert len(set(pairs["track_id_1"])) == len(set(pairs["track_id_2"])) == 1
    assert len(set(pairs["time_unix_s"])) == len(pairs["time_unix_s"])
    assert set(pairs["scenario_id"]) == {7}
    paired_times = set(pairs["time_unix_s"])
    rows = [k for k, t in enumerate(fused["time_unix_s"]) if t in paired_times]
    assert [fused["source"][k] for k in rows] == ["fused"] * len(pairs["time_unix_s"])
    assert (np.asarray(pairs["statistic"]) < 30.0).all()
    if method == "bias_robust":
        assert np.hypot(pairs["bias_east_m"], pairs["bias_north_m"]).max() < 300.0
    else:
        assert set(pairs["bias_east_m"]) == {None}


def test_the_fused_track_lies_on_the_aircraft(users, models, tmp_path, params):
    """The fused position is within a few plot sigmas of the true straight flight at every common time, and
    each pair's covariance intersection weight is a weight."""
    assert associate(users, models, tmp_path) == 0
    fused = pq.read_table(tmp_path / "fused.parquet").to_pydict()
    rows = [k for k, s in enumerate(fused["source"]) if s == "fused"]
    times = np.asarray(fused["time_unix_s"])[rows]
    truth = np.array([40e3, 60e3, 9000.0]) + (times - tf.T0)[:, None] * np.array([180.0, 90.0, 0.0])
    truth_ecef = tf.enu_to_features(times, truth, params.radar)[:, 1:4]
    position = np.column_stack([np.asarray(fused[f"{a}_ecef_m"])[rows] for a in "xyz"])
    assert np.linalg.norm(position - truth_ecef, axis=1).max() < 5 * NOISE_M
    assert all(0.0 <= fused["weight_1"][k] <= 1.0 for k in rows)


def test_the_same_tables_give_the_same_bytes_and_keep_the_users_file_mode(users, models, tmp_path):
    """Run twice, once over outputs the user made group-writable: identical files, the mode kept."""
    assert associate(users, models, tmp_path / "one", "bias_robust") == 0
    (tmp_path / "one" / "fused.parquet").chmod(0o664)
    first = {name: (tmp_path / "one" / name).read_bytes() for name in ("pairs.parquet", "fused.parquet")}
    assert associate(users, models, tmp_path / "one", "bias_robust") == 0
    assert {name: (tmp_path / "one" / name).read_bytes() for name in first} == first
    assert (tmp_path / "one" / "fused.parquet").stat().st_mode & 0o777 == 0o664


def test_a_registration_bias_is_estimated_by_bias_robust_and_defeats_the_statistical_test(users, models, tmp_path):
    """The second user believes its radar 400 m east of where it is, so it places its plots, and its track, 400 m
    east of the aircraft. The statistical test's gate refuses the pair (only the looser keep gate of association
    with memory takes it, at some common times, over the forming gate); bias_robust pairs the tracks at more
    common times and estimates the offset (second minus first, in the common frame: about 400 m east) at every
    one within three plot sigmas (one pair's estimate is the difference of two tracks' errors), on average
    within one."""
    biased = (users["tracks1"], users["biased_tracks2"]), (users["radar1"], users["biased_radar2"])
    assert associate(users, models, tmp_path / "statistical", "statistical", *biased) == 0
    statistical = pq.read_table(tmp_path / "statistical" / "pairs.parquet").to_pydict()
    params = tf.make_params()
    assert min(statistical["statistic"], default=np.inf) > chi2.ppf(params.association.gate_probability, 4)
    assert associate(users, models, tmp_path / "robust", "bias_robust", *biased) == 0
    pairs = pq.read_table(tmp_path / "robust" / "pairs.parquet").to_pydict()
    assert len(pairs["time_unix_s"]) >= max(5, len(statistical["time_unix_s"]) + 1)
    offset = np.column_stack([pairs["bias_east_m"], pairs["bias_north_m"]])
    assert np.linalg.norm(offset - [SITE_ERROR_M, 0.0], axis=1).max() < 3 * NOISE_M
    assert np.linalg.norm(offset.mean(axis=0) - [SITE_ERROR_M, 0.0]) < NOISE_M


def rewritten(source: Path, folder: Path, column: str, change) -> Path:
    """A copy of the Parquet file `source` in `folder` with `column`'s values replaced by change(values)."""
    table = pq.read_table(source)
    index = table.schema.get_field_index(column)
    field = table.schema.field(index).with_nullable(True)  # a user's file may hold nulls anywhere
    values = change(np.asarray(table.column(column).to_pylist(), dtype=object))
    table = table.set_column(index, field, pa.array(values.tolist(), field.type))
    folder.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, folder / source.name)
    return folder / source.name


def first_confirmed(values: np.ndarray, status: list[str], value) -> np.ndarray:
    """`values` with the first confirmed update's replaced by `value`."""
    out = values.copy()
    out[status.index("confirmed")] = value
    return out


@pytest.mark.parametrize("case, which, column, change, named", [
    ("another day", "tracks2", "time_unix_s", lambda v: v + 86400.0, "different days"),
    ("another frame", "tracks2", "x_ecef_m", lambda v: v + 1000.0, "not WGS-84 ECEF"),
    ("a radar without a site", "radar2", "latitude_deg", lambda v: np.array([None] * len(v)),
     "column 'latitude_deg' has 1 missing values"),
    ("an unknown radar id", "tracks1", "radar_id", lambda v: np.full(len(v), 9), "has radar 9 (row 0)"),
    ("a NaN covariance", "tracks1", "covariance_yy_m2", float("nan"),
     "column 'covariance_yy_m2' must be finite: row 3"),
    ("an infinite time", "tracks2", "time_unix_s", float("inf"), "column 'time_unix_s' must be finite: row 3 is inf"),
    ("an infinite position", "tracks1", "y_ecef_m", float("-inf"), "column 'y_ecef_m' must be finite: row 3 is -inf"),
    ("no covariance (a network's tracks)", "tracks2", "covariance_xx_m2", lambda v: np.array([None] * len(v)),
     "column 'covariance_xx_m2' is missing in"),
])
def test_bad_input_is_named_exits_2_and_writes_nothing(users, models, tmp_path, caplog, case, which, column, change,
                                                        named):
    """Each bad input stops the command before any output, with a message naming the file and what is wrong.
    A float `change` is the value of the first confirmed update (row 3: the tracks confirm at their 4th plot)."""
    if isinstance(change, float):
        status, value = pq.read_table(users[which]).column("status").to_pylist(), change

        def change(values: np.ndarray) -> np.ndarray:
            return first_confirmed(values, status, value)
    bad = rewritten(users[which], tmp_path / "bad", column, change)
    changed = {**users, which: bad}
    out = tmp_path / "out"
    code = associate(changed, models, out, tracks=(changed["tracks1"], changed["tracks2"]),
                     radars=(changed["radar1"], changed["radar2"]))
    assert code == 2, case
    assert str(bad) in caplog.text and named in caplog.text, caplog.text
    assert not out.exists() or not any(out.iterdir())


def test_an_output_named_like_an_input_or_the_other_output_is_refused(users, models, tmp_path, caplog):
    """`--pairs` naming one of the user's track tables (a slip of the shell's history) would replace it with the
    pairs; `--pairs` and `--fused` naming one file would keep only the fused picture. Both exit 2 before
    anything is read or written, naming the options, and the user's table keeps its bytes."""
    table = tmp_path / "north.parquet"
    table.write_bytes(users["tracks1"].read_bytes())
    code = cli.main(["associate", "--params", str(users["params"]), "--tracks", str(table), str(users["tracks2"]),
                     "--radar", str(users["radar1"]), str(users["radar2"]), "--models", str(models),
                     "--pairs", str(table), "--fused", str(tmp_path / "fused.parquet")])
    assert code == 2 and "--pairs names the same file as --tracks" in caplog.text, caplog.text
    assert table.read_bytes() == users["tracks1"].read_bytes() and not (tmp_path / "fused.parquet").exists()
    code = cli.main(["associate", "--params", str(users["params"]), "--tracks", str(users["tracks1"]),
                     str(users["tracks2"]), "--radar", str(users["radar1"]), str(users["radar2"]), "--models",
                     str(models), "--pairs", str(tmp_path / "out.parquet"), "--fused", str(tmp_path / "out.parquet")])
    assert code == 2 and "--fused names the same file as --pairs" in caplog.text
    assert not (tmp_path / "out.parquet").exists()


@pytest.mark.parametrize("key, value, named", [
    ("associate.fusion_criterion", "volume", "associate.fusion_criterion = 'volume': must be one of ('trace'"),
    ("associate.step_s", 0.0, "associate.step_s = 0.0: must be in (0.0, inf]"),
    ("associate.acceleration_std_mps2", -1.0, "associate.acceleration_std_mps2 = -1.0"),
    ("associate.keep_probability", 0.99, "associate.keep_probability = 0.99: must be at least "
                                         "association.gate_probability"),
    ("associate.max_speed_mps", 400.0, "associate.max_speed_mps = 400.0: must exceed the fastest aircraft's speed "
                                       "(fighter: 400.0 m/s)"),
    ("association.max_time_offset_s", -1.0, "association.max_time_offset_s = -1.0: must be in [0.0, inf]"),
])
def test_a_bad_associate_param_names_the_key_and_value(key, value, named):
    with pytest.raises(ParamError, match=re.escape(named)):
        tf.make_params({key: value})


def test_a_clock_offset_between_the_users_is_warned_of_naming_the_radar(users, models, tmp_path, caplog):
    """The second user's time stamps 4 s late (its table's times + 4 s) place its track 800 m back along the
    aircraft's 201 m/s: beyond the statistical gate and the keep gate (2 s, 400 m, stays under the keep gate of
    these young tracks). The pair the method leaves is reported as a probable clock offset of the second table's
    radar, of about 4 s; the outputs are written (exit 0)."""
    late = rewritten(users["tracks2"], tmp_path / "late", "time_unix_s", lambda v: v + 4.0)
    assert associate(users, models, tmp_path / "out", "statistical", (users["tracks1"], late)) == 0
    warning = re.search(rf"{re.escape(str(late))} \(radars \[2\]\) against .* track pairs with matching velocities "
                        r"stay unpaired at (\d+) common times.* time stamps about ([0-9.]+) s late", caplog.text)
    assert warning, caplog.text
    assert int(warning.group(1)) >= 3 and abs(float(warning.group(2)) - 4.0) < 0.3

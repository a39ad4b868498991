"""Real aircraft past our radar (`python -m pipeline real-traffic`): the shipped OpenSky recording becomes a
recording `track` reads and a truth `score` reads, the same bytes on every run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from pipeline import cli
from pipeline.simulation import real_traffic
from tests import tracker_fixtures as tf
from tests.project import REPOSITORY, write_params

SHIPPED = REPOSITORY / "external" / "opensky" / "plane_states_2021-07-12.csv"


def test_the_shipped_aircraft_past_a_radar_in_england_give_plots_truth_and_the_same_bytes_twice(tmp_path: Path) -> None:
    params = str(write_params(tf.params_tree(None), tmp_path / "params.yaml"))
    for out in ("a", "b"):
        assert cli.main(["real-traffic", "--params", params, "--states", str(SHIPPED), "--out", str(tmp_path / out)]) == 0
    for name in ("plots.parquet", "truth.parquet", "radar.parquet"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    plots, truth = pq.read_table(tmp_path / "a" / "plots.parquet"), pq.read_table(tmp_path / "a" / "truth.parquet")
    radar = pq.read_table(tmp_path / "a" / "radar.parquet").to_pylist()[0]
    assert (radar["latitude_deg"], radar["longitude_deg"]) == (52.5, -1.5)
    assert np.all(np.diff(plots.column("time_unix_s").to_numpy()) >= 0)
    covered = truth.column("in_coverage").to_numpy()
    assert 50 < len(set(truth.column("target_id").to_numpy()[covered].tolist())) <= 84
    target = plots.column("is_target").to_numpy()
    assert target.sum() > 5000 and (~target).sum() > 0
    error = np.linalg.norm(np.stack([plots.column(f"{a}_ecef_m").to_numpy() - plots.column(f"true_{a}_ecef_m").to_numpy()
                                     for a in "xyz"], axis=1)[target], axis=1)
    assert np.median(error) < 2000.0  # each target plot near its aircraft's real position


def test_a_gap_in_an_aircrafts_reports_splits_it_into_two_routes_of_one_target() -> None:
    import pyarrow as pa

    times = np.concatenate([np.arange(0.0, 100.0, 10.0), np.arange(300.0, 400.0, 10.0)])
    count = len(times)
    truth = pa.table({"target_id": pa.array(np.full(count, 3, np.int32)), "time_unix_s": pa.array(times),
                      **{f"{a}_ecef_m": pa.array(np.full(count, 1e6) + 100.0 * times * (a == "x")) for a in "xyz"}})
    routes = real_traffic.routes_of(truth)
    assert [int(r["route_id"][0]) for r in routes] == [0, 1] and [int(r["target_id"][0]) for r in routes] == [3, 3]
    assert np.allclose(routes[0]["vx_ecef_mps"], 100.0) and np.allclose(routes[1]["vy_ecef_mps"], 0.0)

"""A user's track table as `associate` reads it: one aircraft per track id (two aircraft under one id are refused,
naming the file, the track and the rows), and a huge but finite covariance is a legal state that pairs nothing.

Tables are built here in the track-update schema from straight aircraft near one radar site: every update is
confirmed, its position exact, its covariance diagonal.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from pipeline.association import table_association
from pipeline.association.common_time_states import common_frame, common_snapshots
from pipeline.association.track_association import positive_definite
from pipeline.association.track_tables import COVARIANCE_CEILING_M2, track_table
from pipeline.geometry import geodesy
from pipeline.io import InputError
from pipeline.tracker.recording import (COVARIANCE_COLUMNS, TRACK_SCHEMA, VELOCITY_COLUMNS,
                                       VELOCITY_COVARIANCE_COLUMNS)
from tests import tracker_fixtures as tf

SITE = (60.3, 25.0, 60.0)
SITE_ECEF = geodesy.site_ecef(*SITE)
EAST, NORTH, UP = geodesy.enu_rotation(SITE[0], SITE[1])
PATH = Path("north.parquet")
T0 = 1.7e9
MAX_SPEED_MPS = 1000.0


def updates(track_id: int, start_enu: tuple[float, float], velocity_enu: tuple[float, float], times: np.ndarray,
            variance_m2: float = 100.0) -> dict[str, np.ndarray]:
    """One aircraft's confirmed updates at 9 km, as columns."""
    east = start_enu[0] + velocity_enu[0] * times
    north = start_enu[1] + velocity_enu[1] * times
    ecef = SITE_ECEF + east[:, None] * EAST + north[:, None] * NORTH + 9000.0 * UP
    latitude, longitude, altitude = geodesy.ecef_to_geodetic(ecef)
    count = len(times)
    covariance = {name: np.full(count, variance_m2 if name[-5] == name[-4] else 0.0) for name in COVARIANCE_COLUMNS}
    return {"radar_id": np.ones(count, np.int32), "scenario_id": np.zeros(count, np.int32),
            "track_id": np.full(count, track_id), "time_unix_s": T0 + times, "plot_id": np.arange(count),
            "x_ecef_m": ecef[:, 0], "y_ecef_m": ecef[:, 1], "z_ecef_m": ecef[:, 2], "latitude_deg": latitude,
            "longitude_deg": longitude, "altitude_m": altitude,
            "range_m": np.linalg.norm(ecef - SITE_ECEF, axis=1), "weight": np.ones(count),
            "status": np.full(count, "confirmed"), "association": np.full(count, "gnn"),
            "association_error": np.zeros(count), **covariance,
            **{name: np.full(count, np.nan) for name in (*VELOCITY_COLUMNS, *VELOCITY_COVARIANCE_COLUMNS)}}


def table(*parts: dict[str, np.ndarray]) -> pa.Table:
    """The parts one after the other (as two `track` outputs concatenated)."""
    return pa.Table.from_pydict({name: np.concatenate([part[name] for part in parts]) for name in TRACK_SCHEMA.names},
                                schema=TRACK_SCHEMA)


def read(tracks: pa.Table, scan_s: float | None = 10.0):
    return track_table(tracks, {1: SITE_ECEF}, PATH, MAX_SPEED_MPS, {} if scan_s is None else {1: scan_s})


SCANS = np.arange(10) * 10.0  # a 10 s scan


def test_two_aircraft_far_apart_under_one_track_id_are_refused_naming_the_track_and_rows():
    """Ids restarting at 0 in each of two concatenated outputs: aircraft 30 km apart, seen 3 s apart each scan,
    both track 4. Rows 0-9 are the first, 10-19 the second; in time order the first jump to the first aircraft
    again, from row 10 (second aircraft at 3 s, 40 km east, 20.6 km north) to row 1 (first at 10 s, 12 km east,
    20 km north), is the first row of the file that jumps."""
    first = updates(4, (10e3, 20e3), (200.0, 0.0), SCANS)
    second = updates(4, (40e3, 20e3), (0.0, 200.0), SCANS + 3.0)
    with pytest.raises(InputError) as error:
        read(table(first, second))
    message = str(error.value)
    assert message.startswith("north.parquet: track 4, rows 10 and 1: 28006 m apart in 7 s")
    assert "faster than associate.max_speed_mps = 1000 m/s" in message and "19 of 19 consecutive updates" in message


def test_two_aircraft_near_each_other_under_one_id_are_refused_by_the_revisit_of_their_radar():
    """2 km apart, 3 s apart (667 m/s: under the speed bound); the radar of 10 s scan updates the track twice
    within 3 s: two aircraft. Without the scan period in the description only the speed is tested."""
    first = updates(4, (10e3, 20e3), (200.0, 0.0), SCANS)
    second = updates(4, (12e3, 20e3), (200.0, 0.0), SCANS + 3.0)
    with pytest.raises(InputError, match=r"track 4, rows 0 and 10: radar 1 updates it twice in 3 s, less than 0.5 "
                                         r"of its 10 s scan \(10 of 19 consecutive"):
        read(table(first, second))
    assert len(read(table(first, second), scan_s=None).time) == 20


def test_a_fast_noisy_track_and_two_aircraft_with_their_own_ids_are_accepted():
    """A fighter at 400 m/s, its positions 300 m off (sigma 300 m): no jump beyond the bound; and a jump of 3 km
    in 1 s (3000 m/s) within a covariance of sigma 1 km is position error, not a second aircraft."""
    fighter = updates(4, (10e3, 20e3), (400.0, 0.0), np.arange(20) * 4.0, variance_m2=300.0 ** 2)
    fighter["x_ecef_m"] = fighter["x_ecef_m"] + np.random.default_rng(1).normal(0.0, 300.0, 20)
    fighter["latitude_deg"], fighter["longitude_deg"], fighter["altitude_m"] = geodesy.ecef_to_geodetic(
        np.column_stack([fighter[f"{a}_ecef_m"] for a in "xyz"]))
    fighter["range_m"] = np.linalg.norm(np.column_stack([fighter[f"{a}_ecef_m"] for a in "xyz"]) - SITE_ECEF, axis=1)
    other = updates(5, (40e3, 20e3), (0.0, 200.0), SCANS + 3.0)
    coasting = updates(6, (10e3, 50e3), (3000.0, 0.0), np.array([0.0, 1.0]) * 10.0, variance_m2=1e4 ** 2)
    tracks = read(table(fighter, other, coasting), scan_s=4.0)
    assert sorted(set(tracks.track_id.tolist())) == [4, 5, 6]


def test_positive_definiteness_is_judged_whatever_the_scale():
    """Variances 1, 1, 1e20, 1e20 m² with every correlation 0.5: positive definite (its correlation matrix's
    eigenvalues are 0.5 and 2.5), though its own eigenvalues are good to 1e20·ε only (NumPy's smallest came out
    near -8000, the old test's verdict); with correlations -0.9 of the first two and 0.99 of the last two:
    indefinite (-0.33), though its smallest eigenvalue came out positive (0.75)."""
    correlation = np.full((4, 4), 0.5)
    np.fill_diagonal(correlation, 1.0)
    indefinite = correlation.copy()
    indefinite[0, 1] = indefinite[1, 0] = -0.9
    indefinite[2, 3] = indefinite[3, 2] = 0.99
    sigma = np.sqrt([1.0, 1.0, 1e20, 1e20])
    covariances = np.stack([correlation, indefinite]) * sigma[:, None] * sigma[None, :]
    assert positive_definite(covariances).tolist() == [True, False]
    assert positive_definite(-covariances[:1]).tolist() == [False]


def test_a_huge_covariance_is_kept_pairs_nothing_and_is_named_in_a_warning(caplog):
    """Two users' tracks of one aircraft; the second's update at 50 s (row 5) has variance 1e20 m²: a legal
    state that knows nothing. A warning names the file, row, track, column and value; the common times that read
    row 5 (as last update, or as the velocity's earlier one) leave the track out, and every other is paired."""
    params = tf.make_params()
    one = read(table(updates(1, (10e3, 20e3), (200.0, 0.0), SCANS)))
    second = updates(7, (10e3, 20e3), (200.0, 0.0), SCANS + 2.0)
    for name in ("covariance_xx_m2", "covariance_yy_m2", "covariance_zz_m2"):
        second[name][5] = 1e20
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        two = track_table(table(second), {1: SITE_ECEF}, Path("south.parquet"), MAX_SPEED_MPS, {1: 10.0})
    assert (f"south.parquet: row 5 (track 7) has covariance_xx_m2 = 1e+20 m², above {COVARIANCE_CEILING_M2:.6g}"
            in caplog.text)
    assert two.informative.tolist() == [True] * 5 + [False] + [True] * 4
    snapshots = common_snapshots(one, two, common_frame(one, two), params.associate)
    decisions = table_association.decide(snapshots, "statistical", params.association, None,
                                         params.associate.keep_probability)
    # common times every 4 s from 2 s; the second track has no velocity before 12 s (its baseline is 8 s), and
    # row 5 is at 52 s: the states at 54 and 58 s read it as their last update, those at 62-70 s (last update 62 s,
    # the latest one 8 s before that: 52 s) as their velocity's earlier one
    left_out = [s.time - T0 for s in snapshots if not len(s.ids[1])]
    assert left_out == [2.0, 6.0, 10.0, 54.0, 58.0, 62.0, 66.0, 70.0]
    assert all(len(d.pairs) == (len(s.ids[1]) > 0) for s, d in zip(snapshots, decisions))

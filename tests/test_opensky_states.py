"""Real trajectories (`pipeline.recordings.opensky_states`): the shipped OpenSky recording read as a truth table,
and a hand-made CSV's reports on the ground or without altitude left out and counted."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.geometry import geodesy
from pipeline.io import InputError
from pipeline.recordings import opensky_states
from tests.project import REPOSITORY

SHIPPED = REPOSITORY / "external" / "opensky" / "plane_states_2021-07-12.csv"
HEADER = "time,icao24,lat,lon,velocity,heading,vertrate,callsign,onground,alert,spi,squawk,baroaltitude,geoaltitude\n"


def test_the_shipped_recording_is_84_aircraft_over_the_uk_for_20_minutes() -> None:
    truth, skipped = opensky_states.read_states(SHIPPED)
    assert skipped == {"repeated (no new position since the last report)": 645}
    assert truth.num_rows == 6052 - 645
    assert len(set(truth.column("icao24").to_pylist())) == 84 == len(set(truth.column("target_id").to_pylist()))
    time = truth.column("time_unix_s").to_numpy()  # each position's own time (lastposupdate)
    assert 1626098100.0 < time.min() and time.max() <= 1626099600.0  # 2021-07-12 to 14:20 UTC
    latitude = truth.column("latitude_deg").to_numpy()
    assert 49.0 < latitude.min() and latitude.max() < 61.0
    position = np.stack([truth.column(f"{a}_ecef_m").to_numpy() for a in "xyz"], axis=1)
    back, _, height = geodesy.ecef_to_geodetic(position)
    np.testing.assert_allclose(back, latitude, atol=1e-9)
    assert height.max() < 14000.0
    target = truth.column("target_id").to_numpy()
    assert np.all(np.diff(target) >= 0) and np.all(np.diff(time)[np.diff(target) == 0] > 0)


def test_reports_on_the_ground_or_without_altitude_are_counted_and_baro_altitude_fills_in(tmp_path: Path) -> None:
    path = tmp_path / "states.csv"
    path.write_text(HEADER
                    + "100,aaaaaa,51.0,-1.0,200,90,0,X,False,False,False,1000,9000,9100\n"
                    + "110,aaaaaa,51.0,-0.97,200,90,0,X,False,False,False,1000,9000,\n"

                    + "100,bbbbbb,51.5,0.1,5,0,0,Y,True,False,False,2000,100,110\n"
                    + "100,cccccc,52.0,0.2,200,0,0,Z,False,False,False,3000,,\n")
    truth, skipped = opensky_states.read_states(path)
    assert skipped == {"on the ground": 1, "without an altitude": 1}  # no lastposupdate column: each row is new
    assert truth.column("icao24").to_pylist() == ["aaaaaa", "aaaaaa"]
    assert truth.column("altitude_m").to_pylist() == [9100.0, 9000.0]  # GNSS height, else barometric


def test_reports_without_a_time_or_an_address_are_counted_not_tracked(tmp_path: Path) -> None:
    """A row whose time (and position time) is empty, or whose aircraft address is, cannot be placed on any
    aircraft's trajectory: left out and counted by reason, the others read."""
    path = tmp_path / "states.csv"
    path.write_text(HEADER.strip() + ",lastposupdate\n"
                    + "100,aaaaaa,51.0,-1.0,200,90,0,X,False,False,False,1000,9000,9100,99.5\n"
                    + ",aaaaaa,51.0,-0.98,200,90,0,X,False,False,False,1000,9000,9100,\n"
                    + "110,,51.0,-0.97,200,90,0,X,False,False,False,1000,9000,9100,109.7\n"
                    + "120,aaaaaa,51.0,-0.96,200,90,0,X,False,False,False,1000,9000,9100,119.6\n")
    truth, skipped = opensky_states.read_states(path)
    assert skipped == {"without a time": 1, "without an aircraft address": 1}
    assert truth.column("time_unix_s").to_pylist() == [99.5, 119.6]


def test_a_position_repeated_without_a_new_update_is_left_out_and_positions_take_their_own_time(tmp_path: Path
                                                                                             ) -> None:
    path = tmp_path / "states.csv"
    path.write_text(HEADER.strip() + ",lastposupdate\n"
                    + "100,aaaaaa,51.0,-1.0,200,90,0,X,False,False,False,1000,9000,9100,99.5\n"
                    + "110,aaaaaa,51.0,-0.97,200,90,0,X,False,False,False,1000,9000,9100,109.7\n"
                    + "120,aaaaaa,51.0,-0.97,200,90,0,X,False,False,False,1000,9000,9100,109.7\n")
    truth, skipped = opensky_states.read_states(path)
    assert skipped == {"repeated (no new position since the last report)": 1}
    assert truth.column("time_unix_s").to_pylist() == [99.5, 109.7]


def test_a_missing_column_or_an_impossible_value_names_the_file_and_column(tmp_path: Path) -> None:
    path = tmp_path / "states.csv"
    path.write_text("time,icao24,lat,lon\n100,aaaaaa,51.0,-1.0\n")
    with pytest.raises(InputError, match="states.csv: not an OpenSky state-vector CSV"):
        opensky_states.read_states(path)
    path.write_text(HEADER + "100,aaaaaa,91.0,-1.0,200,90,0,X,False,False,False,1000,9000,9100\n")
    with pytest.raises(InputError, match=r"states.csv: column lat: 91.0 at row 0, outside \[-90, 90\]"):
        opensky_states.read_states(path)

"""Window scaling: centre on the first sample, divide by the thesis's scale vector, invert exactly."""

from __future__ import annotations

import json

import numpy as np
import pymap3d
import pytest

from pipeline.geometry import geodesy
from pipeline.learning import materials, scaling

# The thesis's scale values (params.yaml `windows:`): dT_max, X/Y/Z maxDiff, R_max.
DT_MAX_S, MAX_DIFF_M, R_MAX_M = 18.0, 400.0, 400000.0
SCAN_S = 6.0
T0 = 1.78e9  # an instant in 2026, in Unix seconds

# (latitude, longitude, height) of radar sites; the last two put the windows in octants
# where some ECEF coordinates are negative, which the thesis's centring did not allow for.
FINLAND = (60.3172, 24.9633, 60.0)
CHILE = (-33.0, -70.0, 500.0)      # x > 0, y < 0, z < 0
AUSTRALIA = (-35.0, 150.0, 20.0)   # x < 0, y > 0, z < 0
SITES = (FINLAND, CHILE, AUSTRALIA)

SCALERS = {"plots": scaling.plot_scaler, "states": scaling.state_scaler}
STEPS = {"plots": 10, "states": 5}


def flight(site, east_m, north_m, up_m, start_s=T0):
    """Plot window [t, x, y, z, R] (1 x N x 5) of positions given in the site's east-north-up axes."""
    x, y, z = pymap3d.enu2ecef(east_m, north_m, up_m, *site)
    position = np.stack([x, y, z], axis=-1)
    slant_range = np.linalg.norm(position - geodesy.site_ecef(*site), axis=1)
    time = start_s + SCAN_S * np.arange(len(position))
    return np.column_stack([time, position, slant_range])[None]


def straight_flight(site, steps, speed_mps=250.0, heading_deg=40.0, offset_m=(60000.0, -30000.0, 9000.0)):
    """A window of an aircraft flying straight and level at `speed_mps`, one plot per scan."""
    travelled = speed_mps * SCAN_S * np.arange(steps)
    heading = np.radians(heading_deg)
    return flight(site, offset_m[0] + travelled * np.sin(heading), offset_m[1] + travelled * np.cos(heading),
                  np.full(steps, offset_m[2]))


def coordinated_turn(site, start_s=T0):
    """Ten plots of a 3 deg/s level turn at 250 m/s that starts 9 km above the site."""
    rate, speed = np.radians(3.0), 250.0
    angle = rate * SCAN_S * np.arange(10)
    return flight(site, speed / rate * np.sin(angle), speed / rate * (1.0 - np.cos(angle)), np.full(10, 9000.0),
                  start_s)


def as_states(plots):
    """Plot windows [t, x, y, z, R] as state windows [t, dt, x, y, z, R] (dt 0 at the last step)."""
    dt = np.zeros(plots.shape[:2])
    dt[:, :-1] = np.diff(plots[:, :, 0], axis=1)
    return np.concatenate([plots[:, :, :1], dt[..., None], plots[:, :, 1:]], axis=2)


def raw_windows(layout, steps):
    """One window per site, in the layout's features."""
    plots = np.concatenate([straight_flight(site, steps) for site in SITES])
    return plots if layout == "plots" else as_states(plots)


def origin_of(raw, scaler, sites=SITES):
    """(t0, x0, y0, z0, r0) of each window's first sample and the ECEF of its radar (one site per window)."""
    return scaler.origin(raw, np.array([geodesy.site_ecef(*site) for site in sites]))


def test_scale_vectors_follow_the_thesis():
    """Scale_plots = [dT*N_u, X*N_u, Y*N_u, Z*N_u, R_max] and Scale_state = [dT*N_p, dT, X*N_p, ..., R_max]."""
    plots = scaling.plot_scaler(DT_MAX_S, MAX_DIFF_M, R_MAX_M, 10, "ecef", False)
    states = scaling.state_scaler(DT_MAX_S, MAX_DIFF_M, R_MAX_M, 5, "ecef", False)
    assert plots.features == ("t", "x", "y", "z", "r")
    assert plots.scale == (180.0, 4000.0, 4000.0, 4000.0, 400000.0)
    assert states.features == ("t", "dt", "x", "y", "z", "r")
    assert states.scale == (90.0, 18.0, 2000.0, 2000.0, 2000.0, 400000.0)


def test_sample_windows_include_negative_ecef_octants():
    """The Chilean and Australian windows have negative ECEF coordinates (a precondition of the tests below)."""
    origin = raw_windows("plots", 10)[:, 0, 1:4]
    assert (origin[0] > 0).all()
    assert np.sign(origin[1]).tolist() == [1, -1, -1]
    assert np.sign(origin[2]).tolist() == [-1, 1, -1]


@pytest.mark.parametrize("centre_range", [False, True])
@pytest.mark.parametrize("frame", scaling.FRAMES)
@pytest.mark.parametrize("layout", sorted(SCALERS))
def test_inverse_returns_the_raw_windows_anywhere_on_earth(layout, frame, centre_range):
    """transform then inverse gives back metres and seconds within 1e-6, in every octant."""
    scaler = SCALERS[layout](DT_MAX_S, MAX_DIFF_M, R_MAX_M, STEPS[layout], frame, centre_range)
    raw = raw_windows(layout, 10)
    origin = origin_of(raw, scaler)
    scaled = scaler.transform(raw, origin)
    np.testing.assert_allclose(scaler.inverse(scaled, origin), raw, rtol=0.0, atol=1e-6)


@pytest.mark.parametrize("frame", scaling.FRAMES)
def test_first_sample_is_centred_on_zero_in_every_octant(frame):
    """After scaling, every window starts at t = x = y = z = 0, whatever the signs of its ECEF coordinates."""
    scaler = scaling.plot_scaler(DT_MAX_S, MAX_DIFF_M, R_MAX_M, 10, frame, False)
    raw = raw_windows("plots", 10)
    scaled = scaler.transform(raw, origin_of(raw, scaler))
    np.testing.assert_allclose(scaled[:, 0, :4], 0.0, atol=1e-12)
    np.testing.assert_allclose(scaled[:, :, 4], raw[:, :, 4] / R_MAX_M)


def test_state_dt_is_divided_but_never_centred():
    """The dt feature is the time to the next state over dT_max, whatever the window's start time."""
    scaler = scaling.state_scaler(DT_MAX_S, MAX_DIFF_M, R_MAX_M, 5, "ecef", True)
    raw = raw_windows("states", 6)
    scaled = scaler.transform(raw, origin_of(raw, scaler))
    np.testing.assert_allclose(scaled[:, :, 1], np.r_[[SCAN_S / DT_MAX_S] * 5, 0.0][None].repeat(3, axis=0))


def test_centred_range_is_centred_on_the_first_input_range():
    """With centre_range, R is relative to the origin's range, so targets share the inputs' centring."""
    scaler = scaling.plot_scaler(DT_MAX_S, MAX_DIFF_M, R_MAX_M, 10, "ecef", True)
    raw = raw_windows("plots", 10)
    origin = origin_of(raw, scaler)
    scaled = scaler.transform(raw, origin)
    np.testing.assert_allclose(scaled[:, 0, 4], 0.0, atol=1e-12)
    np.testing.assert_allclose(scaled[:, :, 4] * R_MAX_M, raw[:, :, 4] - raw[:, :1, 4], atol=1e-6)


def test_default_scale_vectors_are_the_thesis(make_params):
    """Default params give the thesis's vectors: plots [18*10, 400*10 x3, 400 km], states [18*5, 18, 400*5 x3, 400 km].

    The thesis's position scale (400 m per step) is smaller than what an aircraft flies in a
    window (a 10-plot window at 250 m/s spans 13.5 km), so its scaled positions reach about
    +-3.4: harmless for linear output layers, and `windows.position_max_diff_m` changes it.
    """
    scalers = materials.scalers(make_params(1).windows)
    assert scalers["plots"].scale == (180.0, 4000.0, 4000.0, 4000.0, 400000.0)
    assert scalers["states"].scale == (90.0, 18.0, 2000.0, 2000.0, 2000.0, 400000.0)
    raw = np.concatenate([straight_flight(site, 10, heading_deg=45.0) for site in SITES])
    scaled = scalers["plots"].transform(raw, origin_of(raw, scalers["plots"]))
    assert 2.0 < np.abs(scaled[:, :, 1:4]).max() < 5.0


def test_local_frames_give_the_same_window_for_the_same_manoeuvre_at_two_radars():
    """A turn flown over a Finnish and over an Australian radar scales alike in ENU and radial axes, not in ECEF."""
    # The ENU axes are those at the window's first plot. The turn starts straight above each
    # radar, so those axes are the radar's. A turn laid out in the radar's axes but starting
    # 100 km east would not be the same manoeuvre at both sites: local north there is turned
    # from the radar's by the meridian convergence (1.6 deg at 60 N, 0.6 deg at 34 S); in the
    # radial frame it would be (tests/test_site_independence.py). Straight above the radar the
    # radial frame's down-range is north, so here it is ENU but for its up, the ellipsoid's normal
    # through the point rather than the geodetic vertical (at most 0.1 m apart across this window: 2.5e-5).
    sites = {"finland": (60.3, 24.9, 60.0), "australia": (-33.9, 151.2, 20.0)}
    windows = {"finland": coordinated_turn(sites["finland"]),
               "australia": coordinated_turn(sites["australia"], start_s=T0 + 3600.0)}
    scaled = {}
    for frame in scaling.FRAMES:
        scaler = scaling.plot_scaler(DT_MAX_S, MAX_DIFF_M, R_MAX_M, 10, frame, False)
        scaled[frame] = [scaler.transform(raw, origin_of(raw, scaler, [sites[name]])) for name, raw in windows.items()]
    np.testing.assert_allclose(scaled["enu"][0], scaled["enu"][1], rtol=0.0, atol=1e-4)
    np.testing.assert_allclose(scaled["radial"][0], scaled["enu"][0], rtol=0.0, atol=2.5e-5)
    np.testing.assert_allclose(scaled["radial"][1], scaled["enu"][1], rtol=0.0, atol=2.5e-5)
    assert np.abs(scaled["ecef"][0] - scaled["ecef"][1]).max() > 0.1


def test_scaler_survives_a_json_round_trip():
    """to_dict / JSON / from_dict gives back an equal scaler that scales identically."""
    scaler = scaling.state_scaler(DT_MAX_S, MAX_DIFF_M, R_MAX_M, 5, "enu", True)
    again = scaling.WindowScaler.from_dict(json.loads(json.dumps(scaler.to_dict())))
    assert again == scaler
    raw = raw_windows("states", 6)
    origin = origin_of(raw, scaler)
    np.testing.assert_array_equal(again.transform(raw, origin), scaler.transform(raw, origin))


def test_unknown_frame_or_bad_scale_is_rejected():
    """A frame other than ecef/enu, or a non-positive scale, is refused when the scaler is built."""
    with pytest.raises(ValueError, match="frame = 'ned'"):
        scaling.plot_scaler(DT_MAX_S, MAX_DIFF_M, R_MAX_M, 10, "ned", False)
    with pytest.raises(ValueError, match="scale"):
        scaling.plot_scaler(DT_MAX_S, 0.0, R_MAX_M, 10, "ecef", False)

"""The same flight seen from radars anywhere on Earth gives the networks the same windows.

Routes are planned on the radar's tangent plane and the radar measures in its own polar
coordinates, so one route, seed and radar placed at five sites (both hemispheres, both sides
of the antimeridian, the equator, the Arctic) gives the same plots relative to the radar, but
for two things that are physics, not bugs: the earth's curvature differs with latitude, so the
horizon hides a plot more or less at the edge of coverage, and the measurements are quantised
(1/256 NM, 360/2^16 degrees), so a few land one quantum apart. In the default `radial` window
frame (cross-range, down-range, up) the windows are then the same; in the thesis's `ecef`
frame they are not, which is why the networks did not carry to other sites, and in `enu` they
are not quite (north at the aircraft turns by the meridian convergence: hundreds of metres
across a window).
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.learning import materials, windows
from pipeline.simulation import routes, simulate

SITES = [(60.3172, 24.9633), (-60.0, -60.0), (0.0, 179.9), (35.0, -179.9), (69.65, 18.96)]


def site_windows(make_params, latitude_deg: float, longitude_deg: float, frame: str | None = None
                 ) -> dict[tuple[float, ...], np.ndarray]:
    """The filter's scaled input windows of the tiny test split flown past a radar at this site, by plot times."""
    changes = {"radar.latitude_deg": latitude_deg, "radar.longitude_deg": longitude_deg}
    if frame is not None:
        changes["windows.frame"] = frame
    params = make_params(1, changes)
    split = params.routes.split("test")
    route_table = routes.generate_split(params, split)
    plots, _ = simulate.simulate_split(params, split, route_table)
    targets = windows.target_plots(plots, params.radar, params.windows.segment_gap_s, "test")
    length = params.windows.filter_length
    starts = windows.window_starts(targets.segment_id, length)
    raw = windows.gather(targets.plot_features(), starts, length)
    scaler = materials.scalers(params.windows)["plots"]
    scaled = scaler.transform(raw, scaler.origin(raw, targets.radar_position[starts]))
    return {tuple(np.round(times, 3)): window for times, window in zip(raw[..., 0], scaled)}


def differences(site: dict[tuple[float, ...], np.ndarray], reference: dict[tuple[float, ...], np.ndarray]
                ) -> tuple[float, np.ndarray]:
    """(share of the reference's windows the site also has, |scaled difference| of those windows)."""
    common = [key for key in reference if key in site]
    return len(common) / len(reference), np.abs(np.stack([site[key] - reference[key] for key in common]))


def test_default_frame_gives_the_same_windows_at_five_sites(make_params):
    """At least 99 % of the windows exist at every site. Half of their values agree to 5e-5 of the
    4 km scale (0.2 m), 99 % to 2.5e-3 (10 m: the range quantum is 7.2 m), every one to 0.01
    (the azimuth quantum, 38 m at 400 km)."""
    reference = site_windows(make_params, *SITES[0])
    assert len(reference) > 100
    for site in SITES[1:]:
        share, difference = differences(site_windows(make_params, *site), reference)
        assert share >= 0.99, site
        assert np.quantile(difference, 0.5) <= 5e-5, site
        assert np.quantile(difference, 0.99) <= 2.5e-3, site
        assert difference.max() <= 0.01, site


@pytest.mark.parametrize("frame", ["ecef", "enu"])
def test_other_frames_give_other_windows_elsewhere(make_params, frame):
    """The check above can fail: in ECEF axes, and in ENU axes (north turns with the meridian
    convergence), the same flight relative to a radar 60 degrees away is a different window."""
    reference = site_windows(make_params, *SITES[0], frame=frame)
    _, difference = differences(site_windows(make_params, *SITES[1], frame=frame), reference)
    assert np.quantile(difference[..., 1:4], 0.5) > 1e-3

"""Scaling of network windows: one object used by training and by the tracker, with an exact inverse.

A window is a short sequence of samples, features last. Two layouts (thesis 4.2.4):

- plots:  [T, x, y, z, R]      (time, position, range from the radar)
- states: [T, dT, x, y, z, R]  (dT: time to the next known state)

Scaling centres a window on an origin (its first input sample: time and position) and divides
by the thesis's scale vector, e.g. for plots [dT_max*N_u, X*N_u, Y*N_u, Z*N_u, R_max]. dT
is never centred. Whether R is centred is the `centre_range` choice (the thesis is
ambiguous; by default it is not: dividing a raw range by R_max already gives [0, 1]).

The `frame` choice says in which axes the centred positions are expressed:

- `ecef`: ECEF differences, as the thesis does. Centring by subtraction does not depend on
  the routes lying in the positive ECEF octant (the thesis's caveat), but the same
  manoeuvre looks different at different places on Earth.
- `enu`: east-north-up axes at the window's origin. The same flight relative to north gives
  the same window anywhere, but the same flight relative to the radar does not quite: north at
  the aircraft turns from north at the radar by the meridian convergence (3 degrees 200 km east
  of a radar at 60 degrees latitude, the opposite way in the southern hemisphere, none at the
  equator).
- `radial` (default, ours): cross-range, down-range and up axes at the window's origin
  (`geodesy.radial_rotations`): down-range is the horizontal direction away from the radar. A
  window is then a function of the radar's own measurements only, so the same flight relative
  to the radar gives the same window at any site, and the radar's error ellipse (narrow in
  range, wide in azimuth) lies along the axes wherever the aircraft is. It needs the radar's
  position: `origin` takes it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from pipeline.geometry import geodesy

FRAMES = ("ecef", "enu", "radial")
PLOT_FEATURES = ("t", "x", "y", "z", "r")
STATE_FEATURES = ("t", "dt", "x", "y", "z", "r")


@dataclass(frozen=True)
class WindowScaler:
    """Centre-and-scale for one window layout. `origin` rows are (t0, x0, y0, z0, r0, sx, sy, sz):
    time, ECEF position and range of the window's first input sample and the ECEF position of the
    radar that measured it (see `origin`)."""

    features: tuple[str, ...]
    scale: tuple[float, ...]
    frame: str = "ecef"
    centre_range: bool = False

    def __post_init__(self) -> None:
        if self.frame not in FRAMES:
            raise ValueError(f"frame = {self.frame!r}: must be one of {FRAMES}")
        if len(self.scale) != len(self.features) or min(self.scale) <= 0.0:
            raise ValueError(f"scale = {self.scale}: need one positive value per feature {self.features}")

    @property
    def _position(self) -> list[int]:
        return [self.features.index(axis) for axis in ("x", "y", "z")]

    def origin(self, windows: np.ndarray, radar_ecef: np.ndarray | None = None) -> np.ndarray:
        """(t0, x0, y0, z0, r0, sx, sy, sz) of each window (N x L x F): its first sample, what it is
        centred on, and the radar's ECEF position ((3,) or (N, 3) metres; NaN when not given).

        Raises ValueError in the `radial` frame without the radar's position."""
        first = np.asarray(windows)[:, 0, [self.features.index(name) for name in ("t", "x", "y", "z", "r")]]
        if radar_ecef is None:
            if self.frame == "radial":
                raise ValueError("the radial window frame needs the radar's position (radar_ecef)")
            radar_ecef = np.full(3, np.nan)
        return np.column_stack([first, np.broadcast_to(np.asarray(radar_ecef, dtype=float), (len(first), 3))])

    def _rotations(self, origin: np.ndarray) -> np.ndarray | None:
        """Per-window ECEF -> frame rotations (N x 3 x 3) at the origin, or None in the ECEF frame."""
        if self.frame == "ecef":
            return None
        if self.frame == "radial":
            return geodesy.radial_rotations(origin[:, 1:4], origin[:, 5:8])
        lat, lon, _ = geodesy.ecef_to_geodetic(origin[:, 1:4])
        return geodesy.enu_rotations(lat, lon)

    def transform(self, windows: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """Raw windows (N x L x F, metres and seconds, ECEF) to network features."""
        windows = np.asarray(windows, dtype=float)
        out = windows.copy()
        t = self.features.index("t")
        out[..., t] -= origin[:, None, 0]
        position = windows[..., self._position] - origin[:, None, 1:4]
        rotations = self._rotations(origin)
        if rotations is not None:
            position = np.einsum("nij,nlj->nli", rotations, position)
        out[..., self._position] = position
        if self.centre_range:
            out[..., self.features.index("r")] -= origin[:, None, 4]
        return out / np.asarray(self.scale)

    def inverse(self, scaled: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """Network features back to raw windows, for the same origins they were scaled with."""
        out = np.asarray(scaled, dtype=float) * np.asarray(self.scale)
        t = self.features.index("t")
        out[..., t] += origin[:, None, 0]
        position = out[..., self._position]
        rotations = self._rotations(origin)
        if rotations is not None:
            position = np.einsum("nji,nlj->nli", rotations, position)
        out[..., self._position] = position + origin[:, None, 1:4]
        if self.centre_range:
            out[..., self.features.index("r")] += origin[:, None, 4]
        return out

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "WindowScaler":
        return cls(features=tuple(data["features"]), scale=tuple(float(v) for v in data["scale"]),
                   frame=data["frame"], centre_range=bool(data["centre_range"]))


def plot_scaler(dt_max_s: float, position_max_diff_m: float, range_max_m: float, steps: int, frame: str,
                centre_range: bool) -> WindowScaler:
    """Scale_plots = [dT_max*N_u, X*N_u, Y*N_u, Z*N_u, R_max] with N_u = steps (10 in the thesis)."""
    span = position_max_diff_m * steps
    return WindowScaler(PLOT_FEATURES, (dt_max_s * steps, span, span, span, range_max_m), frame, centre_range)


def state_scaler(dt_max_s: float, position_max_diff_m: float, range_max_m: float, steps: int, frame: str,
                 centre_range: bool) -> WindowScaler:
    """Scale_state = [dT_max*N_p, dT_max, X*N_p, Y*N_p, Z*N_p, R_max] with N_p = steps (5 in the thesis)."""
    span = position_max_diff_m * steps
    return WindowScaler(STATE_FEATURES, (dt_max_s * steps, dt_max_s, span, span, span, range_max_m), frame,
                        centre_range)

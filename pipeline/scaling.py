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
- `enu`: east-north-up axes at the window's origin, so the same manoeuvre gives the same
  window wherever the radar stands.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from pipeline import geodesy

FRAMES = ("ecef", "enu")
PLOT_FEATURES = ("t", "x", "y", "z", "r")
STATE_FEATURES = ("t", "dt", "x", "y", "z", "r")


@dataclass(frozen=True)
class WindowScaler:
    """Centre-and-scale for one window layout. `origin` rows are (t0, x0, y0, z0, r0): time, ECEF
    position and range of the window's first input sample (see `origin`)."""

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

    def origin(self, windows: np.ndarray) -> np.ndarray:
        """(t0, x0, y0, z0, r0) of each window's first sample: what it is centred on."""
        return np.asarray(windows)[:, 0, [self.features.index(name) for name in ("t", "x", "y", "z", "r")]]

    def _rotations(self, origin: np.ndarray) -> np.ndarray | None:
        """Per-window ECEF -> ENU rotations (N x 3 x 3) at the origin, or None in the ECEF frame."""
        if self.frame == "ecef":
            return None
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

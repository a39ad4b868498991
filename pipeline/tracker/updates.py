"""The track-update table: what a tracker run gives, one row per track update.

A track's start counts as its first update (association `start`). Columns, each an array of
the table's length U:

| column | shape, unit | meaning |
|---|---|---|
| `track_id` | (U,) int64 | unique within the run |
| `time_unix_s` | (U,) s | the plot's time |
| `plot_id` | (U,) int64 | the plot's id |
| `radar_id` | (U,) int32 | the plot's radar |
| `x_ecef_m`, `y_ecef_m`, `z_ecef_m` | (U,) m | the track's position after the update (a start's is its plot's) |
| `weight` | (U,) | the track's weight after the update |
| `association` | (U,) str | `start`, or the label of the gate that won (`radius` for young tracks, else the method) |
| `association_error` | (U,) | the normalised error of the association, NaN for a start |
| `position_covariance` | (U, 3, 3) m^2 | of the position; a start's is its plot's measurement covariance; NaN for estimators that give none |
| `velocity` | (U, 3) m/s | only where the run records velocities (`Updates.with_velocity`): the track's ECEF velocity after the update; NaN for a start (unknown from one plot) |
| `velocity_covariance` | (U, 3, 3) m^2/s^2 | with `velocity`: its covariance; NaN for a start, or where the estimator gives none |

An *association to a confirmed track* (`confirmed_associations`) is an update that is not a start
and after which the track's weight is confirmed by the track management rule; the metrics, OSPA,
the pictures and the `track` command's `status` all read it from here.
"""

from __future__ import annotations

import numpy as np

from pipeline.recordings.plot_table import Plots
from pipeline.tracker.management import TrackManagement

START = "start"
COLUMNS = ("track_id", "time_unix_s", "plot_id", "radar_id", "x_ecef_m", "y_ecef_m", "z_ecef_m", "weight",
           "association", "association_error", "position_covariance")  # every run's; `velocity` and its
VELOCITY_COLUMNS = ("velocity", "velocity_covariance")                  # covariance where it records them
UNKNOWN_COVARIANCE = np.full((3, 3), np.nan)
UNKNOWN_VELOCITY = np.full(3, np.nan)


class Updates:
    """The update table of one run, collected row by row (`add`) and given as arrays (`table`);
    covariances are kept only when the estimator gives them (`with_covariance`), velocities only when
    the run records them (`with_velocity`)."""

    def __init__(self, with_covariance: bool, with_velocity: bool = False) -> None:
        self.with_covariance, self.with_velocity = with_covariance, with_velocity
        self._velocity: list[np.ndarray] = []
        self._velocity_covariance: list[np.ndarray] = []
        self._track_id: list[int] = []
        self._row: list[int] = []
        self._position: list[np.ndarray] = []
        self._weight: list[float] = []
        self._association: list[str] = []
        self._error: list[float] = []
        self._covariance: list[np.ndarray] = []

    def add(self, track_id: int, row: int, position: np.ndarray, weight: float, association: str, error: float,
            covariance: np.ndarray | None, velocity: tuple[np.ndarray, np.ndarray | None] | None = None) -> None:
        """One update of track `track_id` with plot `row`: its position (3,) after it, weight,
        association label and normalised error, the position's covariance (3, 3), and, when velocities
        are recorded, the velocity (3,) and its covariance (3, 3) or None (None: unknown)."""
        if self.with_velocity:
            value, spread = velocity if velocity is not None else (UNKNOWN_VELOCITY, None)
            self._velocity.append(value)
            self._velocity_covariance.append(UNKNOWN_COVARIANCE if spread is None else spread)
        self._track_id.append(track_id)
        self._row.append(row)
        self._position.append(position)
        self._weight.append(weight)
        self._association.append(association)
        self._error.append(error)
        if self.with_covariance:
            self._covariance.append(covariance)

    def table(self, plots: Plots) -> dict[str, np.ndarray]:
        """The columns (see the module docstring) for the rows added, `plots` being the plots tracked."""
        rows = np.asarray(self._row, dtype=np.int64)
        position = np.asarray(self._position, dtype=float).reshape(-1, 3)
        covariance = (np.asarray(self._covariance, dtype=float).reshape(-1, 3, 3) if self.with_covariance
                      else np.broadcast_to(UNKNOWN_COVARIANCE, (len(rows), 3, 3)).copy())
        velocities = {"velocity": np.asarray(self._velocity, dtype=float).reshape(-1, 3),
                      "velocity_covariance": np.asarray(self._velocity_covariance, dtype=float).reshape(-1, 3, 3)
                      } if self.with_velocity else {}
        return {"track_id": np.asarray(self._track_id, dtype=np.int64), "time_unix_s": plots.time[rows],
                "plot_id": plots.plot_id[rows], "radar_id": plots.radar_id[rows], "x_ecef_m": position[:, 0],
                "y_ecef_m": position[:, 1], "z_ecef_m": position[:, 2], "weight": np.asarray(self._weight, dtype=float),
                "association": np.asarray(self._association, dtype=str), "association_error": np.asarray(self._error, dtype=float),
                "position_covariance": covariance, **velocities}


def confirmed_associations(updates: dict[str, np.ndarray], management: TrackManagement) -> np.ndarray:
    """Which updates (U,) are associations to a confirmed track."""
    return (updates["association"] != START) & management.confirmed(updates["weight"])


def positions(updates: dict[str, np.ndarray]) -> np.ndarray:
    """The updates' positions (U, 3), ECEF metres."""
    return np.column_stack([updates["x_ecef_m"], updates["y_ecef_m"], updates["z_ecef_m"]])

"""Two users' tracks at common times: what track-to-track association compares.

Two radars update a target at different times (their antennas turn independently), so their tracks are
compared at common times: every `step_s` seconds from the later of the two tables' first confirmed updates
to the earlier of their last ones, per scenario both tables hold (scenario ids are separate recordings).

A track's state at a common time t (ours; the track table keeps positions only, no velocity):
- its last update k at or before t, no older than `max_age_s` (else the track is left out at t: it has
  stopped being updated, or has not started);
- its velocity by two-point differencing (Bar-Shalom, Li & Kirubarajan (2001), "Estimation with
  Applications to Tracking and Navigation", section 5.5.3) between k and the track's latest update j at
  least `velocity_baseline_s` before it (a shorter baseline amplifies the position errors): v = (p_k - p_j) / Δ,
  Δ = t_k - t_j (the track is left out at t when it has no such update);
- extrapolated at constant velocity over τ = t - t_k: x = [p_k + τ v, v].
Its covariance is that linear map applied to the two positions' covariances taken as independent, plus the
discrete white-noise acceleration of the extrapolation (ibid., eq. 6.3.2-4, `acceleration_std_mps2` per axis):
    P = A diag(P_k, P_j) Aᵀ + Q(τ),   A = [[(1 + τ/Δ) I, -(τ/Δ) I], [I/Δ, -I/Δ]].
Filtered positions of one track are positively correlated, so treating them as independent overstates the
velocity's variance: the statistical tests then gate more widely, not more tightly.
A track is also left out at t when k or j is not informative (a covariance above the track table's ceiling,
`track_tables.COVARIANCE_CEILING_M2`): it pairs nothing there. A state whose covariance still is not positive
definite (`track_association.positive_definite`) is refused with an InputError naming the file, the track and
both rows.

States are [east, north, up, v_east, v_north, v_up] (m, m/s) in one east-north-up frame for both tables,
at the ellipsoid point under the mean of all described radar sites (so that neither user's frame is
favoured and both radars are near its origin).

InputError naming both files when the tables share no scenario or no common time (tables of different
days, or of different recordings).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np

from pipeline import io
from pipeline.association.track_association import positive_definite
from pipeline.association.track_tables import TrackTable
from pipeline.geometry import geodesy
from pipeline.params import Associate
from pipeline.recordings.plot_table import NO_SCENARIO

STATE_SIZE = 6


@dataclass(frozen=True)
class Frame:
    """The common east-north-up frame: `origin` (3,) ECEF m, `rotation` (3, 3) ECEF -> ENU (rows e, n, u)."""

    origin: np.ndarray
    rotation: np.ndarray


@dataclass(frozen=True)
class Snapshot:
    """Both users' tracks at one common time `time` (Unix s) of `scenario_id`: per user i in (1, 2) the track
    ids `ids[i]` (N_i,), states `states[i]` (N_i, 6) and covariances `covariances[i]` (N_i, 6, 6) in the frame."""

    scenario_id: int
    time: float
    ids: tuple[np.ndarray, np.ndarray]
    states: tuple[np.ndarray, np.ndarray]
    covariances: tuple[np.ndarray, np.ndarray]


def common_frame(first: TrackTable, second: TrackTable) -> Frame:
    """The ENU frame at the ellipsoid point under the mean of both tables' described radar sites."""
    mean = np.mean([*first.sites.values(), *second.sites.values()], axis=0)
    latitude, longitude, _ = geodesy.ecef_to_geodetic(mean)
    origin = geodesy.geodetic_to_ecef(latitude, longitude, np.zeros_like(latitude))
    return Frame(np.asarray(origin, dtype=float), geodesy.enu_rotation(float(latitude), float(longitude)))


def _extrapolation_noise(tau: np.ndarray, acceleration_std_mps2: float) -> np.ndarray:
    """Q(τ) (K, 6, 6) of the discrete white-noise acceleration model over τ (K,) s, per axis."""
    q = np.zeros((len(tau), STATE_SIZE, STATE_SIZE))
    blocks = np.stack([np.stack([tau ** 4 / 4, tau ** 3 / 2], -1), np.stack([tau ** 3 / 2, tau ** 2], -1)], -2)
    for axis in range(3):
        q[np.ix_(np.arange(len(tau)), [axis, axis + 3], [axis, axis + 3])] = blocks * acceleration_std_mps2 ** 2
    return q


def track_states(time: np.ndarray, position: np.ndarray, covariance: np.ndarray, informative: np.ndarray,
                 at: np.ndarray, settings: Associate) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One track's states at the times `at` (T,) (module docstring) from its updates: times (U,) sorted, ENU
    positions (U, 3), covariances (U, 3, 3) and which are informative (U,). Which times have a state (T,) bool,
    states (K, 6), covariances (K, 6, 6) for those K and the updates (K, 2) [k, j] each is made of."""
    last = np.searchsorted(time, at, side="right") - 1
    valid = (last >= 0) & (at - time[np.maximum(last, 0)] <= settings.max_age_s)
    earlier = np.searchsorted(time, time[np.maximum(last, 0)] - settings.velocity_baseline_s, side="right") - 1
    valid &= (earlier >= 0) & informative[np.maximum(last, 0)] & informative[np.maximum(earlier, 0)]
    k, j = last[valid], earlier[valid]
    delta = time[k] - time[j]
    tau = at[valid] - time[k]
    velocity = (position[k] - position[j]) / delta[:, None]
    states = np.concatenate([position[k] + tau[:, None] * velocity, velocity], axis=1)
    eye = np.eye(3)
    a = np.zeros((len(k), STATE_SIZE, STATE_SIZE))
    a[:, :3, :3] = (1 + tau / delta)[:, None, None] * eye
    a[:, :3, 3:] = -(tau / delta)[:, None, None] * eye
    a[:, 3:, :3] = eye / delta[:, None, None]
    a[:, 3:, 3:] = -eye / delta[:, None, None]
    joint = np.zeros((len(k), STATE_SIZE, STATE_SIZE))
    joint[:, :3, :3], joint[:, 3:, 3:] = covariance[k], covariance[j]
    covariances = a @ joint @ a.transpose(0, 2, 1) + _extrapolation_noise(tau, settings.acceleration_std_mps2)
    return valid, states, (covariances + covariances.transpose(0, 2, 1)) / 2, np.stack([k, j], axis=1)


def _check_definite(table: TrackTable, rows: np.ndarray, covariances: np.ndarray, updates: np.ndarray) -> None:
    """InputError naming the file, track and both file rows of the first state whose covariance is not positive
    definite; `rows` (U,) the track's rows of `table`, `updates` (K, 2) indices into them."""
    definite = positive_definite(covariances)
    if not definite.all():
        k, j = rows[updates[int(np.argmin(definite))]]
        raise io.InputError(f"{table.path}: track {int(table.track_id[k])}: the covariances (columns "
                            f"'covariance_*_m2') of rows {int(table.row[k])} and {int(table.row[j])} give a state "
                            f"covariance that is not positive definite ({int((~definite).sum())} of "
                            f"{len(definite)} common times); their ECEF variances "
                            f"{np.diagonal(table.covariance[k]).tolist()} and "
                            f"{np.diagonal(table.covariance[j]).tolist()} m²")


def _table_states(table: TrackTable, scenario_id: int, at: np.ndarray, frame: Frame,
                  settings: Associate) -> list[tuple[list[int], list[np.ndarray], list[np.ndarray]]]:
    """Per common time: the table's track ids, states and covariances there."""
    per_time: list[tuple[list[int], list[np.ndarray], list[np.ndarray]]] = [([], [], []) for _ in at]
    rows = table.scenario_id == scenario_id
    position = (table.position[rows] - frame.origin) @ frame.rotation.T
    covariance = frame.rotation @ table.covariance[rows] @ frame.rotation.T
    track_ids, time, informative = table.track_id[rows], table.time[rows], table.informative[rows]
    for track_id in np.unique(track_ids):
        own = track_ids == track_id
        valid, states, covariances, updates = track_states(time[own], position[own], covariance[own],
                                                           informative[own], at, settings)
        _check_definite(table, np.flatnonzero(rows)[own], covariances, updates)
        for index, state, state_covariance in zip(np.flatnonzero(valid), states, covariances):
            per_time[index][0].append(int(track_id))
            per_time[index][1].append(state)
            per_time[index][2].append(state_covariance)
    return per_time


def _stacked(ids: list[int], states: list[np.ndarray], covariances: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    return (np.asarray(ids, dtype=np.int64), np.asarray(states, dtype=float).reshape(-1, STATE_SIZE),
            np.asarray(covariances, dtype=float).reshape(-1, STATE_SIZE, STATE_SIZE))


def _span(table: TrackTable) -> str:
    if not len(table.time):
        return "no confirmed update"
    first, last = (datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%d %H:%M:%S") for t in
                   (table.time.min(), table.time.max()))
    return f"{first} to {last} UTC, scenarios {sorted(set(table.scenario_id.tolist()) - {NO_SCENARIO}) or 'none'}"


def common_snapshots(first: TrackTable, second: TrackTable, frame: Frame, settings: Associate) -> list[Snapshot]:
    """Both tables' tracks at every common time of every scenario both hold, in (scenario, time) order.
    InputError naming both files and their spans when there is no common time."""
    snapshots = []
    for scenario_id in sorted(set(first.scenario_id.tolist()) & set(second.scenario_id.tolist())):
        times = [table.time[table.scenario_id == scenario_id] for table in (first, second)]
        begin, end = max(t.min() for t in times), min(t.max() for t in times)
        if begin > end:
            continue
        at = begin + settings.step_s * np.arange(int(np.floor((end - begin) / settings.step_s)) + 1)
        one, two = (_table_states(table, scenario_id, at, frame, settings) for table in (first, second))
        for time, a, b in zip(at, one, two):
            (ids1, x1, p1), (ids2, x2, p2) = _stacked(*a), _stacked(*b)
            snapshots.append(Snapshot(scenario_id, float(time), (ids1, ids2), (x1, x2), (p1, p2)))
    if not snapshots:
        raise io.InputError(f"{first.path} ({_span(first)}) and {second.path} ({_span(second)}) have no common "
                            "time in a common scenario: tables of different days or recordings?")
    return snapshots

"""Shared helpers for the tracker tests: synthetic flights and clutter near a radar, and tiny real models.

The models are the thesis's three networks (sizes from params.yaml) trained for a few seconds on
synthetic straight and gently turning flights sampled every 6 s in the radar's local ENU frame,
scaled exactly as the `windows` stage scales material (`materials.scalers(params.windows)`), saved
with `model_store.save_network` and loaded back with `model_store.load_model`, so the tracker gets
what `dvc repro` would give it, only less well trained. The predictor also sees windows padded
the way the tracker pads the states of young tracks (thesis 4.6).

Training happens once per test process and frame (`trained_models`), whichever test module asks first.
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pymap3d

from pipeline import io
from pipeline.bench.runs import Run, declared_runs, with_records
from pipeline.filters.classical_filters import KINDS, FilterSettings
from pipeline.geometry import geodesy
from pipeline.learning import materials, model_eval
from pipeline.learning.model_eval import output_scaler
from pipeline.learning.model_store import LoadedModel, load_model, save_network
from pipeline.learning.training import TrainingConfig, network_config, train
from pipeline.params import Params, Radar
from pipeline.settings import parse_params
from pipeline.recordings.plot_table import NO_SCENARIO, NO_TARGET, PLOT_INPUT_SCHEMA, RADAR_INPUT_SCHEMA, Plots
from pipeline.stages.tune_stage import start_settings
from pipeline.tracker.models import Models
from tests.project import default_params_tree

SCAN_S = 6.0
T0 = 1.78e9  # an instant in 2026, in Unix seconds
EPOCHS = {"predictor": 30, "filter": 25, "autoencoder": 20}
TRAJECTORIES = 600
PREDICTOR_WINDOWS = 6000
SAMPLES = 16            # states per synthetic flight
NOISE_M = (50.0, 50.0, 30.0)  # synthetic plot noise in east, north, up


# ----------------------------------------------------------------------------- params

def params_tree(changes: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The default params.yaml tree with dotted keys changed, e.g. {"windows.frame": "enu"}; evaluations
    on one draw of each scenario (`evaluate.seeds`: the tests that need more say so); a test that gives its own
    `evaluate.runs` and no `peers.runs` sets all its scene runs beside the peers (`peers.runs: []`)."""
    tree = copy.deepcopy(default_params_tree())
    tree["evaluate"]["seeds"] = 1
    if "evaluate.runs" in (changes or {}) and "peers.runs" not in changes:
        tree["peers"]["runs"] = []
    for dotted, value in (changes or {}).items():
        *parents, key = dotted.split(".")
        node = tree
        for parent in parents:
            node = node[parent]
        node[key] = value
    return tree


def make_params(changes: Mapping[str, Any] | None = None) -> Params:
    return parse_params(params_tree(changes))


def run_records(report: Mapping[str, dict]) -> dict[Run, dict]:
    """A report's runs (metrics by run name) with their records, looked up among the default params' runs, as
    the comparison and the README read them."""
    return with_records(report, declared_runs(make_params()), "report")


def radar_at(radar: Radar, latitude_deg: float, longitude_deg: float, height_m: float) -> Radar:
    return dataclasses.replace(radar, latitude_deg=latitude_deg, longitude_deg=longitude_deg, height_m=height_m)


# ----------------------------------------------------------------------------- flights and clutter

def enu_to_features(times: np.ndarray, enu: np.ndarray, radar: Radar) -> np.ndarray:
    """Rows [t, x, y, z, r]: ENU points of the radar's local frame in ECEF, r the distance to the radar."""
    x, y, z = pymap3d.enu2ecef(enu[:, 0], enu[:, 1], enu[:, 2], radar.latitude_deg, radar.longitude_deg,
                               radar.height_m, ell=geodesy.WGS84_ELLIPSOID)
    ecef = np.column_stack([x, y, z])
    return np.column_stack([times, ecef, np.linalg.norm(ecef - geodesy.radar_site_ecef(radar), axis=1)])


def ecef_to_enu(ecef: np.ndarray, radar: Radar) -> np.ndarray:
    e, n, u = pymap3d.ecef2enu(ecef[:, 0], ecef[:, 1], ecef[:, 2], radar.latitude_deg, radar.longitude_deg,
                               radar.height_m, ell=geodesy.WGS84_ELLIPSOID)
    return np.column_stack([e, n, u])


def straight_enu(start_enu: tuple[float, float, float], velocity_enu: tuple[float, float, float],
                 scans: int, dt: float = SCAN_S) -> tuple[np.ndarray, np.ndarray]:
    """Times (from T0) and ENU positions of a constant-velocity flight, one plot per scan."""
    elapsed = np.arange(scans) * dt
    return T0 + elapsed, np.asarray(start_enu, float) + elapsed[:, None] * np.asarray(velocity_enu, float)


def straight_features(radar: Radar, start_enu: tuple[float, float, float], velocity_enu: tuple[float, float, float],
                      scans: int, t_offset: float = 0.0) -> np.ndarray:
    times, enu = straight_enu(start_enu, velocity_enu, scans)
    return enu_to_features(times + t_offset, enu, radar)


def clutter_features(radar: Radar, scans: int, per_scan: float, rng: np.random.Generator,
                     half_width_m: float = 200000.0) -> np.ndarray:
    """Uniform random plots in a (2 * half_width)^2 box around the radar at 1-12 km, Poisson per scan,
    each at a uniform time within its 6 s scan."""
    counts = rng.poisson(per_scan, scans)
    scan = np.repeat(np.arange(scans), counts)
    n = len(scan)
    times = T0 + (scan + rng.uniform(0.0, 1.0, n)) * SCAN_S
    enu = np.column_stack([rng.uniform(-half_width_m, half_width_m, (n, 2)), rng.uniform(1000.0, 12000.0, n)])
    return enu_to_features(times, enu, radar)


def merge(*parts: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(features, plot_ids) parts merged in time order (stable)."""
    features = np.concatenate([p[0] for p in parts])
    ids = np.concatenate([p[1] for p in parts])
    order = np.argsort(features[:, 0], kind="stable")
    return features[order], ids[order]


def synthetic_flights(rng: np.random.Generator, radar: Radar, count: int = TRAJECTORIES, samples: int = SAMPLES
                      ) -> tuple[np.ndarray, np.ndarray]:
    """True and noisy [t, x, y, z, r] of `count` flights (count x samples x 5).

    Half fly straight, half turn gently (up to 3 deg/s); speeds 60-400 m/s; a scan is
    occasionally missed (12 s step); some climb or descend slowly.
    """
    steps = np.where(rng.uniform(size=(count, samples - 1)) < 0.1, 2 * SCAN_S, SCAN_S)
    elapsed = np.concatenate([np.zeros((count, 1)), np.cumsum(steps, axis=1)], axis=1)
    distance = rng.uniform(20000.0, 330000.0, count)
    bearing = rng.uniform(0.0, 2 * np.pi, count)
    start = np.column_stack([distance * np.sin(bearing), distance * np.cos(bearing),
                             rng.uniform(1000.0, 12000.0, count)])
    speed = rng.uniform(60.0, 400.0, count)
    heading = rng.uniform(0.0, 2 * np.pi, count)
    rate = np.where(rng.uniform(size=count) < 0.5, 0.0, np.radians(rng.uniform(-3.0, 3.0, count)))
    climb = np.where(rng.uniform(size=count) < 0.7, 0.0, rng.uniform(-15.0, 15.0, count))
    t = elapsed
    turning = np.abs(rate) > 1e-9
    safe = np.where(turning, rate, 1.0)[:, None]
    h0 = heading[:, None]
    east = np.where(turning[:, None], speed[:, None] / safe * (np.cos(h0) - np.cos(h0 + safe * t)),
                    speed[:, None] * np.sin(h0) * t)
    north = np.where(turning[:, None], speed[:, None] / safe * (np.sin(h0 + safe * t) - np.sin(h0)),
                     speed[:, None] * np.cos(h0) * t)
    enu = start[:, None, :] + np.stack([east, north, climb[:, None] * t], axis=-1)
    times = T0 + rng.uniform(0.0, 86400.0, count)[:, None] + t
    true = enu_to_features(times.reshape(-1), enu.reshape(-1, 3), radar).reshape(count, samples, 5)
    noisy_enu = enu + rng.normal(0.0, 1.0, enu.shape) * np.asarray(NOISE_M)
    noisy = enu_to_features(times.reshape(-1), noisy_enu.reshape(-1, 3), radar).reshape(count, samples, 5)
    return true, noisy


def state_window(states: np.ndarray, indices: list[int], target_time: float) -> np.ndarray:
    """A predictor input window [t, dt, x, y, z, r] over `indices` of one flight, as the tracker builds it."""
    rows = states[indices]
    times = np.append(rows[:, 0], target_time)
    return np.column_stack([rows[:, :1], np.diff(times), rows[:, 1:]])


def predictor_pairs(true: np.ndarray, inputs: int) -> tuple[np.ndarray, np.ndarray]:
    """Unscaled (windows, targets): 5 states in (some padded as for young tracks), the next states out."""
    windows, targets = [], []
    for flight in true:
        for start in range(0, len(flight) - inputs):
            for real in (inputs, inputs, 4, 3, 2):  # unpadded windows twice as often
                if start + real >= len(flight):
                    continue
                indices = [start] * (inputs - real) + list(range(start, start + real))
                following = indices[1:] + [start + real]
                windows.append(state_window(flight, indices, flight[start + real, 0]))
                targets.append(flight[following[-(inputs - 1):]])
    return np.asarray(windows), np.asarray(targets)


def _training(kind: str, params: Params, epochs: int) -> TrainingConfig:
    return TrainingConfig(epochs=epochs, batch_size=256, learning_rate=0.005, validation_fraction=0.1,
                          seed=params.training.networks[kind].seed, early_stopping_patience=0, accelerator="cpu",
                          devices=1, strategy="auto", threads=1, deterministic=True)


def build_models(folder: Path, params: Params, seed: int = 11) -> Path:
    """Train the predictor, filter and autoencoder (with its threshold) and save them in `folder`."""
    rng = np.random.default_rng(seed)
    radar = params.radar
    site = geodesy.radar_site_ecef(radar)  # every synthetic flight is seen by this one radar
    scalers = materials.scalers(params.windows)
    true, noisy = synthetic_flights(rng, radar)
    cfg = params.windows

    # Predictor: states -> next states (output steps 2..5 of a 6-state window).
    scaler = scalers["states"]
    raw_in, raw_out = predictor_pairs(true, cfg.predictor_inputs)
    keep = rng.choice(len(raw_in), min(len(raw_in), PREDICTOR_WINDOWS), replace=False)
    raw_in, raw_out = raw_in[keep], raw_out[keep]
    origin = scaler.origin(raw_in, site)
    config = network_config("predictor", params)
    module, _ = train(config, scaler.transform(raw_in, origin), output_scaler(scaler).transform(raw_out, origin),
                      _training("predictor", params, EPOCHS["predictor"]))
    save_network(folder / "predictor.pt", module.network, scaler=scaler)

    # Filter: 10 noisy plots -> the true last 5.
    scaler = scalers["plots"]
    length = cfg.filter_length
    starts = range(0, true.shape[1] - length + 1, 3)
    raw_in = np.concatenate([noisy[:, s:s + length] for s in starts])
    raw_out = np.concatenate([true[:, s:s + length] for s in starts])
    origin = scaler.origin(raw_in, site)
    config = network_config("filter", params)
    module, _ = train(config, scaler.transform(raw_in, origin),
                      scaler.transform(raw_out, origin)[:, -config.output_steps:],
                      _training("filter", params, EPOCHS["filter"]))
    save_network(folder / "filter.pt", module.network, scaler=scaler)

    # Autoencoder: 5 noisy plots reconstructed; threshold by the thesis's rule on calibration windows
    # whose 5th plot is the flight's next plot (target) or a clutter plot up to 20 km away (false).
    length = cfg.autoencoder_length
    raw = np.concatenate([noisy[:, s:s + length] for s in range(0, true.shape[1] - length + 1, 2)])
    scaled = scaler.transform(raw, scaler.origin(raw, site))
    config = network_config("autoencoder", params)
    module, _ = train(config, scaled, scaled, _training("autoencoder", params, EPOCHS["autoencoder"]))
    model = LoadedModel(module.network, config, scaler)
    head = noisy[:200, 6:6 + length - 1]
    target_candidate = noisy[:200, 6 + length - 1]
    offset = rng.normal(size=(200, 3))
    offset *= (rng.uniform(3000.0, 20000.0, 200) / np.linalg.norm(offset, axis=1))[:, None]
    false_candidate = target_candidate.copy()
    false_candidate[:, 1:4] += offset
    false_candidate[:, 4] = np.linalg.norm(false_candidate[:, 1:4] - geodesy.radar_site_ecef(radar), axis=1)
    calibration = np.concatenate([np.concatenate([head, target_candidate[:, None]], axis=1),
                                  np.concatenate([head, false_candidate[:, None]], axis=1)])
    labels = np.repeat([True, False], 200)
    errors = model_eval.reconstruction_errors(model, scaler.transform(calibration, scaler.origin(calibration, site)))
    threshold, rejected = model_eval.autoencoder_threshold(errors, labels)
    save_network(folder / "autoencoder.pt", module.network, {"threshold": threshold, "false_windows_rejected": rejected},
                 scaler)
    return folder


_TRAINED: dict[str, Path] = {}


def trained_models(tmp_path_factory, frame: str | None = None) -> Path:
    """The folder of tiny trained models for `windows.frame = frame` (the default params' frame when
    None), trained once per test process."""
    frame = frame or make_params().windows.frame
    if frame not in _TRAINED:
        folder = tmp_path_factory.mktemp(f"models_{frame}")
        build_models(folder, make_params({"windows.frame": frame}))
        _TRAINED[frame] = folder
    return _TRAINED[frame]


def untuned_filters(params: Params) -> dict[str, FilterSettings]:
    """The classical filters at params' start values (tuning is tested on its own)."""
    return {kind: start_settings(kind, params) for kind in KINDS}


def write_tuned_filters(folder: Path, params: Params) -> Path:
    """A models folder holding only `kalman_tuned.json` (the filters at params' start values, written
    as the tune stage writes them): all the classical methods need."""
    io.write_json({"cost": "rmse", "filters": {kind: settings.to_dict()
                                               for kind, settings in untuned_filters(params).items()}},
                  folder / "kalman_tuned.json")
    return folder


def load_models(folder: Path) -> Models:
    return Models({kind: load_model(folder / f"{kind}.pt", kind) for kind in ("predictor", "filter", "autoencoder")}
                  | {"kalman_tuned": untuned_filters(make_params())})


def plots_of(features: np.ndarray, plot_ids: np.ndarray, radar: Radar, target_ids: np.ndarray | None = None
             ) -> Plots:
    """The plot table of [t, x, y, z, r] rows (time order) seen by `radar`, with its measurement
    covariances; `target_ids` (NO_TARGET for false plots) when the truth is known."""
    n = len(features)
    return Plots(np.asarray(plot_ids, dtype=np.int64), np.full(n, radar.radar_id, np.int32),
                 np.full(n, NO_SCENARIO, np.int32), features[:, 0], features[:, 1:4], features[:, 4],
                 geodesy.measurement_covariance(features[:, 1:4], radar),
                 np.full(n, NO_TARGET, np.int32) if target_ids is None else np.asarray(target_ids, np.int32),
                 target_ids is not None, {radar.radar_id: radar})


# ----------------------------------------------------------------------------- recordings for `track`

def measurement_table(features: np.ndarray, plot_ids: np.ndarray, radar: Radar, radar_id: int,
                      scenario_id: int | None = None) -> pa.Table:
    """A `track` input table (PLOT_INPUT_SCHEMA) of ECEF plots seen from `radar`: exact slant range,
    azimuth and altitude."""
    slant, azimuth, altitude = geodesy.true_measurement(features[:, 1:4], radar)
    n = len(features)
    return pa.Table.from_pydict({
        "plot_id": plot_ids.astype(np.int64), "radar_id": np.full(n, radar_id, np.int32),
        "time_unix_s": features[:, 0], "range_m": slant, "azimuth_deg": azimuth, "altitude_m": altitude,
        "scenario_id": pa.array(np.full(n, -1 if scenario_id is None else scenario_id, np.int32),
                                mask=np.full(n, scenario_id is None)),
        "target_id": pa.nulls(n, pa.int32()),
    }, schema=PLOT_INPUT_SCHEMA)


def radar_table(radar_id: int, radar: Radar) -> pa.Table:
    return pa.Table.from_pylist([{"radar_id": radar_id, "latitude_deg": radar.latitude_deg,
                                  "longitude_deg": radar.longitude_deg, "height_m": radar.height_m}],
                                schema=RADAR_INPUT_SCHEMA)


def write_recording(folder: Path, plots: pa.Table, radars: pa.Table) -> tuple[Path, Path]:
    """`track`'s Parquet input: the plots and the radar description written in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    pq.write_table(plots, folder / "plots.parquet")
    pq.write_table(radars, folder / "radar.parquet")
    return folder / "plots.parquet", folder / "radar.parquet"


def busy_recording(radar: Radar) -> Plots:
    """Eight straight flights of 40 scans (some within 3 km of each other) and clutter, with truth."""
    rng = np.random.default_rng(3)
    flights = [(straight_features(radar, (20000.0 * k, 60000.0 + 1500.0 * (k % 2), 8000.0),
                                  (150.0, -100.0 + 25.0 * k, 0.0), 40, t_offset=0.3 * k), np.full(40, k))
               for k in range(8)]
    clutter = clutter_features(radar, 40, 30.0, rng, half_width_m=120000.0)
    features, targets = merge(*flights, (clutter, np.full(len(clutter), NO_TARGET)))
    return plots_of(features, np.arange(len(features)), radar, targets)


def assert_chunked_as_whole(recording: Plots, composed: Callable[[], Any], sizes: tuple[int, ...]) -> dict:
    """`track_chunks` over chunks of each of `sizes` plots joins into the update table `track` gives
    for the whole `recording`, bit for bit, with a fresh tracker (`composed()`) for each run; and so
    does `track` with tracks that keep all their plots (the estimator told it reads them all), so
    the plots the roles declare they read (`latest_plots`) are all they read. The whole's table."""
    from pipeline.tracker.run import track, track_chunks
    whole = track(recording, composed())
    every_plot = composed()
    every_plot.estimator.latest_plots = len(recording)
    assert every_plot.latest_plots == len(recording)
    _assert_same_updates(track(recording, every_plot), whole, "every plot kept")
    for size in sizes:
        chunks = [recording.take(np.arange(start, min(start + size, len(recording))))
                  for start in range(0, len(recording), size)]
        tables = list(track_chunks(chunks, composed()))
        assert len(tables) == len(chunks)
        _assert_same_updates({key: np.concatenate([table[key] for table in tables]) for key in whole}, whole, size)
    return whole


def _assert_same_updates(updates: dict[str, np.ndarray], expected: dict[str, np.ndarray], case: object) -> None:
    for key, column in expected.items():
        assert updates[key].dtype == column.dtype and updates[key].tobytes() == column.tobytes(), (case, key)


def tracks_of(updates: dict[str, np.ndarray]) -> dict[int, list[int]]:
    """Plot ids of each track of an update table, in update order."""
    out: dict[int, list[int]] = {}
    for track_id, plot_id in zip(updates["track_id"].tolist(), updates["plot_id"].tolist()):
        out.setdefault(track_id, []).append(plot_id)
    return out

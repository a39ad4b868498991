"""Time to associate 2 x N tracks (issue 19's goal: 2 x 100 in under 50 ms on one core), per method.

One scene of the seed's setting with N targets, every one tracked by both radars (Pd 1), in a square of
--area-m (30 km: 100 targets at the seed's density of about 24 in 10 km), radar 2 biased by --bias-m. Timed,
best of --repeat: the statistical assignment, the double threshold (its whole history of 4 times), the
bias-robust method, the network (models/association_net.pt if there, else untrained weights: same cost; its
scene tensor is N x N, which its adaptive pool allows), the memory every method's pairs then go through
(`association_memory.continue_pairs`, the bias-robust pairs held from the last time), and covariance intersection
of the decided pairs.
Torch on one thread.

    python benchmarks/bench_association.py [--tracks 100] [--repeat 5] [--bias-m 200] [--area-m 30000]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from pipeline.association import association_net
from pipeline.association.association_memory import HORIZONTAL, continue_pairs
from pipeline.association.association_net import AssociationNet, AssociationNetConfig
from pipeline.association.association_scenes import SceneSetting, make_scene
from pipeline.association.bias_robust_association import associate_bias_robust
from pipeline.association.common_time_states import STATE_SIZE, Snapshot
from pipeline.association.track_association import associate_double_threshold, associate_statistical
from pipeline.association.track_fusion import fuse_pairs

GATE = 0.999


def best_ms(work: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        began = time.perf_counter()
        work()
        times.append(time.perf_counter() - began)
    return 1000.0 * min(times)


def network(tracks: int, model_path: Path) -> AssociationNet:
    if model_path.is_file():
        trained = association_net.load(model_path)
        model = AssociationNet(dataclasses.replace(trained.config, size=tracks))
        model.load_state_dict(trained.state_dict())
        return model.eval()
    return AssociationNet(AssociationNetConfig(tracks, 14142.0, (8, 16, 36), 8)).eval()


def full_states(states: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[e, n, ve, vn] states (N, 4) and covariances as the common-time states' [e, n, u, ve, vn, vu] (up: 0 with
    unit variance)."""
    full = np.zeros((len(states), STATE_SIZE))
    full[:, HORIZONTAL] = states
    covariance = np.tile(np.eye(STATE_SIZE), (len(states), 1, 1))
    covariance[:, HORIZONTAL[:, None], HORIZONTAL[None, :]] = covariances
    return full, covariance


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tracks", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--bias-m", type=float, default=200.0)
    parser.add_argument("--area-m", type=float, default=30000.0)
    parser.add_argument("--model", type=Path, default=Path("models/association_net.pt"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    setting = SceneSetting((args.tracks, args.tracks), args.area_m, 4.0, 5, (50.0, 70.0), 1.0, (100.0, 300.0), 1.0,
                           (args.bias_m, args.bias_m), "kalman")
    scene = make_scene(setting, 1, 0)
    last = (scene.states1[-1], scene.covariances1[-1], scene.states2[-1], scene.covariances2[-1])
    model = network(args.tracks, args.model)
    methods = {
        "statistical": lambda: associate_statistical(*last, GATE),
        "double_threshold": lambda: associate_double_threshold(scene.states1, scene.covariances1, scene.states2,
                                                               scene.covariances2, GATE, 3),
        "bias_robust": lambda: associate_bias_robust(*last, GATE, 600.0, 150.0, 10).pairs,
        "network": lambda: association_net.associate_network(model, *last, 0.5),
    }
    print(f"2 x {args.tracks} tracks, bias {args.bias_m:g} m, best of {args.repeat} (one core; goal < 50 ms)")
    for name, work in methods.items():
        pairs = work()
        correct = len({tuple(p) for p in pairs.tolist()} & {tuple(p) for p in scene.true_pairs.tolist()})
        print(f"  {name:17s} {best_ms(work, args.repeat):8.1f} ms   {correct}/{len(scene.true_pairs)} pairs correct")
    pairs = methods["bias_robust"]()
    (x1, p1), (x2, p2) = full_states(*last[:2]), full_states(*last[2:])
    snapshot = Snapshot(0, 0.0, (np.arange(len(x1)), np.arange(len(x2))), (x1, x2), (p1, p2))
    held = {(int(i), int(j)) for i, j in pairs.tolist()}
    print(f"  {'memory':17s} {best_ms(lambda: continue_pairs(snapshot, pairs, None, held, 0.999999), args.repeat):8.1f}"
          f" ms   held {len(held)} pairs")
    print(f"  {'fusion (CI, trace)':17s} {best_ms(lambda: fuse_pairs(*last, pairs), args.repeat):8.1f} ms   "
          f"{len(pairs)} pairs")


if __name__ == "__main__":
    main()

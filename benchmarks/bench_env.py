"""Steps/s of the batched environment vs Gymnasium's SyncVectorEnv over the single environment.

Both play random legal moves (from the action mask) on the same bundle with the same
config, seeded alike, for --steps vector steps each, at N = 1, 16 and 256 parallel
episodes. Targets: batched >= 10 x SyncVectorEnv at N = 256, and >= 50 k steps/s.

    python benchmarks/bench_env.py [--dataset train --root data/processed] [--steps 300]
    python benchmarks/bench_env.py --dataset train --corpus corpus      # one city against many
    python benchmarks/bench_env.py --homing                              # the homing channel's cost
    python benchmarks/bench_env.py --tracking tiny-routes                # the tracking task against placement

Without --dataset it ingests and builds the embedded training city into a temporary root.
``--corpus NAME`` adds the batched env over the corpus's cities and the dataset together
(the training set of the `best` preset), with the training levers on (8 symmetries, the
visited channel, far starts), at N = 64: its steps/s against the one city's, measured in the same run.
``--tracking CITY`` (a city with routes): the tracking env (``rl.tasks.tracking.TrackingEnv``) against the placement env on
that city, both at N = 256 with random legal moves, in the same run (the median of 3 seeds each).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd

from uavplace.dataset.build import build_city
from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.catalog import expand_datasets
from uavplace.ingest.pipeline import ingest_city
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.tasks.placement.gym import UavPlacementEnv
from uavplace.rl.tasks.placement.policies import random_legal
from uavplace.rl.tasks.tracking import RouteSet, TrackingConfig, TrackingEnv
from uavplace.rl.world.maps import MapSet
from uavplace.schemas.bundle import EMBEDDED_NOISE_DBM, BuildConfig

REPO = Path(__file__).resolve().parents[1]


def bench_batched(maps: MapSet, n: int, steps: int, seed: int = 0) -> float:
    env = BatchedEnv(maps, n)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    mask = env.action_mask()
    t = time.perf_counter()
    for _ in range(steps):
        a = random_legal(mask, rng)
        _, _, _, _, info = env.step(a)
        mask = info["action_mask"]
    return n * steps / (time.perf_counter() - t)


def bench_tracking(routes: RouteSet, n: int, steps: int, seed: int = 0) -> float:
    env = TrackingEnv(routes, n)
    _, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    mask = info["action_mask"]
    t = time.perf_counter()
    for _ in range(steps):
        _, _, _, _, info = env.step(random_legal(mask, rng))
        mask = info["action_mask"]
    return n * steps / (time.perf_counter() - t)


def bench_sync(maps: MapSet, n: int, steps: int, seed: int = 0) -> float:
    env = gym.vector.SyncVectorEnv([lambda: UavPlacementEnv(maps) for _ in range(n)])
    _, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    mask = info["action_mask"].astype(bool)
    t = time.perf_counter()
    for _ in range(steps):
        a = random_legal(mask, rng)
        _, _, _, _, info = env.step(a)
        mask = info["action_mask"].astype(bool)
    return n * steps / (time.perf_counter() - t)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default=None, help="built city (default: the embedded train city, built here)")
    ap.add_argument("--root", default="data/processed")
    ap.add_argument("--steps", type=int, default=300, help="vector steps per measurement")
    ap.add_argument("--noise-dbm", type=float, default=EMBEDDED_NOISE_DBM, help="build setting when building the embedded city")
    ap.add_argument("--corpus", default=None, help="corpus name (built cities NAME-NNN) to compare with the one city")
    ap.add_argument(
        "--homing", action="store_true", help="also time the `best` preset's channels with the homing channel against without"
    )
    ap.add_argument("--tracking", default=None, help="a built city with routes: the tracking env against placement there")
    args = ap.parse_args()
    if args.tracking:
        bundle = load_bundle(args.tracking, root=args.root)
        place = MapSet([bundle], EnvConfig(rotate=False))
        track = RouteSet([bundle], TrackingConfig())
        rates = [np.median([bench(m, 256, args.steps, seed) for seed in range(3)]) for bench, m in
                 ((bench_batched, place), (bench_tracking, track))]  # fmt: skip
        print(f"N = 256, {args.tracking}: placement {rates[0]:,.0f} steps/s; tracking {rates[1]:,.0f} steps/s; "
              f"ratio {rates[1] / rates[0]:.2f}")  # fmt: skip
        return
    with tempfile.TemporaryDirectory() as tmp:
        root, name = args.root, args.dataset
        if name is None:
            root, name = tmp, "train"
            ingest_city(REPO / "data" / "raw" / "train", tmp)
            build_city("train", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=args.noise_dbm), tmp)
        maps = MapSet.load(name, EnvConfig(rotate=True), root=root)
        rows = []
        for n in (1, 16, 256):
            ours = bench_batched(maps, n, args.steps)
            sync = bench_sync(maps, n, max(20, args.steps // max(1, n // 16)))
            rows.append({"N": n, "batched steps/s": ours, "SyncVectorEnv steps/s": sync, "ratio": ours / sync})
        print(
            f"dataset {name}: {maps.bundles[0].shape[1]} x {maps.bundles[0].shape[0]} cells, {len(maps.scenarios)} users, window 61"
        )
        print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:,.1f}"))
        print("targets: ratio >= 10 at N = 256; batched >= 50,000 steps/s")
        if args.corpus:
            levers = EnvConfig(rotate=True, symmetries=8, visited_channel=True, far_starts=0.5)
            names = [*expand_datasets([args.corpus], root), name]
            many = MapSet.load(names, levers, root=root)
            one = MapSet.load(name, levers, root=root)
            single = np.median([bench_batched(one, 64, args.steps, seed) for seed in range(3)])
            corpus = np.median([bench_batched(many, 64, args.steps, seed) for seed in range(3)])
            print(
                f"N = 64, training levers on: {name} alone {single:,.0f} steps/s; {len(names)} cities "
                f"({len(many.scenarios)} users, {many.num_views} views) {corpus:,.0f} steps/s; ratio {corpus / single:.2f} "
                "(target: >= 0.9, no slowdown with many cities)"
            )

        if args.homing:
            plain = EnvConfig(rotate=True, visited_channel=True)
            rates = []
            for cfg in (plain, plain.model_copy(update={"homing_channel": True})):
                maps = MapSet.load(name, cfg, root=root)
                rates.append(np.median([bench_batched(maps, 64, args.steps, seed) for seed in range(3)]))
            print(
                f"N = 64, {name}: visited channel {rates[0]:,.0f} steps/s; with the homing channel {rates[1]:,.0f} "
                f"steps/s; ratio {rates[1] / rates[0]:.2f}"
            )


if __name__ == "__main__":
    main()

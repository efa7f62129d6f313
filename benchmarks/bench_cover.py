"""Time of the tracking searcher's rollouts: its float64 belief products reading each canvas's cover cast to float64
once (``CandidateMaps.cover64``) against numpy casting the float32 cover at every product (as before), in the same
run. (The placement and fleet searchers' beliefs are float32: their products never cast.)

For each routes city, this plays the tracking report's episodes of the searcher once to fill the prediction cache,
then twice per way, alternating (cast at every product, cast once, cast at every product, cast once), and prints the
best time of each way, the speed-up and whether every episode came out the same (each step's coverage and cell: the
numbers must not move).

    python benchmarks/bench_cover.py [--city trk-val] [--episodes 100]

Run it with the bundles built (README, first command) on a machine with nothing else running; the validation routes
city by default.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from unittest import mock

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.reports.tracking.config import TrackingReportConfig
from uavplace.rl.belief import PREDICTIONS, CandidateMaps, PredictionCache
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.tasks.tracking import RouteSet, TrackingSearchPolicy, run_tracking


def play(routes: RouteSet, episodes: np.ndarray, config: TrackingReportConfig, cache: PredictionCache, cast_each: bool):  # noqa: ANN201
    """(seconds, covered steps [episodes, steps], path [episodes, steps + 1, 2]) of a fresh tracking searcher's rollouts; ``cast_each``: its float64
    products read the float32 cover, which numpy casts at every product (before ``cover64``)."""
    searcher = TrackingSearchPolicy(MapSearchPolicy(load_predictor(config.predictor), config.search, cache), config.motion)
    patch = mock.patch.object(CandidateMaps, "cover64", property(lambda self: self.cover)) if cast_each else None
    with patch if patch is not None else contextlib.nullcontext():
        t = time.perf_counter()
        out = run_tracking(routes, searcher, episodes, record=True)
        seconds = time.perf_counter() - t
    return seconds, out.covered, out.path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", default=None, help="A routes city (repeatable; default trk-val)")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    print("| city | cast at every product [s] | cast once [s] | speed-up | every episode the same |")
    print("|---|---|---|---|---|")
    cache = PredictionCache(f"{args.root}/{PREDICTIONS}")
    for city in args.city or ["trk-val"]:
        config = TrackingReportConfig(datasets=[city], episodes=args.episodes)
        routes = RouteSet([load_bundle(city, root=args.root)], config.task)
        episodes = routes.sample_episodes(args.episodes, np.random.default_rng([config.seed, 7]))  # the report's draw
        play(routes, episodes[:2], config, cache, cast_each=False)  # the predicted maps, cached before the timing
        runs = [play(routes, episodes, config, cache, cast_each=c) for c in (True, False, True, False)]
        old, new = min(r[0] for r in runs[0::2]), min(r[0] for r in runs[1::2])
        same = all(np.array_equal(r[1], runs[0][1]) and np.array_equal(r[2], runs[0][2]) for r in runs)
        print(f"| {city} | {old:.1f} | {new:.1f} | {old / new:.2f} x | {same} |", flush=True)


if __name__ == "__main__":
    main()

"""Time of the map searcher's rollouts: its belief products reading each canvas's cover cast to float64 once
(``CandidateMaps.cover64``) against casting it at every product (as before), in the same run.

For each city, with its buildings shown and blanked (the report's ablation), this plays the report's episodes of
the searcher once to fill the prediction cache, then twice per way, alternating (cast at every product, cast once,
cast at every product, cast once), and prints the best time of each way, the speed-up and whether every episode
came out the same (steps, success: the numbers must not move).

    python benchmarks/bench_cover.py [--city etoile-val --city florence-val] [--episodes 300]

Run it with the bundles built (README, first command) on a machine with nothing else running; validation cities by
default.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from unittest import mock

import numpy as np

from uavplace.eval.evaluate import ReportConfig, report_env
from uavplace.rl.belief import PREDICTIONS, CandidateMaps, PredictionCache
from uavplace.rl.config import DEFAULT_PREDICTOR, SearchConfig
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.world.maps import MapSet


def play(maps: MapSet, episodes: np.ndarray, buildings: bool, cache: PredictionCache, cast_each: bool) -> tuple:
    """(seconds, steps, success) of a fresh searcher's rollouts; ``cast_each``: its float64 products read the float32
    cover, which numpy casts at every product (before ``cover64``)."""
    searcher = MapSearchPolicy(load_predictor(DEFAULT_PREDICTOR), SearchConfig(buildings=buildings), cache)
    patch = mock.patch.object(CandidateMaps, "cover64", property(lambda self: self.cover)) if cast_each else None
    with patch if patch is not None else contextlib.nullcontext():
        t = time.perf_counter()
        out = run_episodes(maps, searcher, episodes)
        seconds = time.perf_counter() - t
    return seconds, out["steps"].to_numpy(), out["success"].to_numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", default=None, help="City (repeatable; default etoile-val, florence-val)")
    ap.add_argument("--episodes", type=int, default=300)
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    print("| city | buildings | cast at every product [s] | cast once [s] | speed-up | every episode the same |")
    print("|---|---|---|---|---|---|")
    cache = PredictionCache(f"{args.root}/{PREDICTIONS}")
    for city in args.city or ["etoile-val", "florence-val"]:
        config = ReportConfig(dataset=city, episodes=args.episodes, predictor=None)
        maps = MapSet.load(city, report_env(config), root=args.root)
        episodes = maps.episode_list(args.episodes, config.seed)
        for buildings in (True, False):
            play(maps, episodes[:4], buildings, cache, cast_each=False)  # the predicted maps, cached before the timing
            runs = [play(maps, episodes, buildings, cache, cast_each=c) for c in (True, False, True, False)]
            old, new = min(r[0] for r in runs[0::2]), min(r[0] for r in runs[1::2])
            same = all(np.array_equal(r[1], runs[0][1]) and np.array_equal(r[2], runs[0][2]) for r in runs)
            print(f"| {city} | {'shown' if buildings else 'blanked'} | {old:.1f} | {new:.1f} | {old / new:.2f} x | {same} |")


if __name__ == "__main__":
    main()

"""Time of the map searcher's rollouts with the predictor's errors kriged, against the searcher as shipped, in one run.

``SearchConfig.error_share`` > 0 moves the searcher's numbers by what its measurements say of each candidate's map
errors (docs/searcher.md, "Kriging the predictor's errors"): the cover planner re-scores the cells near those it
measured for every candidate at every step (``kriging="planner"``), or the belief takes each measurement given those
before it (``kriging="belief"``). For each city this plays the same episodes with the shipped settings, then with each
of the two, one after the other in this process, and prints the seconds, the ratio to the shipped searcher's and the
steps they took in all (not the same: kriging changes the moves).

    python benchmarks/bench_kriging.py [--city etoile-val --city corpus-017] [--episodes 60]

Run it with the bundles built (README, first command) on a machine with nothing else running.
"""

from __future__ import annotations

import argparse
import time

from uavplace.rl.belief import PredictionCache
from uavplace.rl.config import SearchConfig
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.world.maps import MapSet


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", default=None, help="City (repeatable; default: etoile-val, corpus-017)")
    ap.add_argument("--episodes", type=int, default=60)
    ap.add_argument("--share", type=float, default=0.8, help="error_share of the kriged searchers")
    ap.add_argument("--range-cells", type=float, default=9.8, help="error_range_cells of the kriged searchers")
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    predictor = load_predictor()
    kriged = {"error_share": args.share, "error_range_cells": args.range_cells}
    print("| city | searcher | seconds | x shipped | steps |")
    print("|---|---|---|---|---|")
    for city in args.city or ["etoile-val", "corpus-017"]:
        maps = MapSet.load(city, EnvConfig(), root=args.root)
        episodes = maps.episode_list(args.episodes, 0)
        shipped = None
        for name, changed in (("shipped", {}), ("kriging planner", {**kriged, "kriging": "planner"}),
                              ("kriging belief", {**kriged, "kriging": "belief"})):  # fmt: skip
            policy = MapSearchPolicy(predictor, SearchConfig(**changed), PredictionCache(f"{args.root}/.predictions"))
            run_episodes(maps, policy, episodes[:2], num_envs=2)  # the predicted maps made or read before the clock
            t0 = time.perf_counter()
            df = run_episodes(maps, policy, episodes, num_envs=16)
            seconds = time.perf_counter() - t0
            shipped = shipped or seconds
            print(f"| {city} | {name} | {seconds:.1f} | {seconds / shipped:.1f} | {int(df['steps'].sum())} |", flush=True)


if __name__ == "__main__":
    main()

"""The fleet task's methods on validation cities: success, median steps against the oracle's, SPL and time.

Per validation city (never a test city), the same episodes (``FleetMaps.episode_list``) for the fleet's steered
random walk, greedy hill-climbing, each agent of ``--agent`` run on every UAV on the users dealt to it (default: the
shipped ``best`` and the fleet-trained ``fleet``) and the map searcher run for the fleet (rl/tasks/fleet/) with each
``--plan`` (``SearchConfig.fleet_plan``; default: the default plan), scored against the oracle by ``run_fleet``.
Prints one Markdown row per city. ``--agents-only``: the agents alone; ``--searcher-only``: the searcher alone.

    python experiments/fleet_validation.py [--city corpus-016] [--episodes 100] [--uavs 2] [--users 3]
                                          [--agent data/agents/best --agent data/agents/fleet] [--agents-only]
                                          [--searcher-only] [--plan product --plan makespan]
"""

from __future__ import annotations

import argparse
import time
import typing
from pathlib import Path

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import load_agent
from uavplace.rl.belief import PREDICTIONS, PredictionCache
from uavplace.rl.config import DEFAULT_PREDICTOR, SearchConfig
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.fleet.config import FleetConfig
from uavplace.rl.tasks.fleet.maps import FleetMaps
from uavplace.rl.tasks.fleet.policies import FleetGreedy, FleetPlacement, FleetRandomWalk
from uavplace.rl.tasks.fleet.rollout import run_fleet
from uavplace.rl.tasks.fleet.searcher import FleetSearcher

VALIDATION = ("corpus-016", "corpus-017", "oldtown-005", "etoile-val", "florence-val")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", default=None, help=f"Validation city (default: {', '.join(VALIDATION)})")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--uavs", type=int, default=2)
    ap.add_argument("--users", type=int, default=3)
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    ap.add_argument("--predictor", type=Path, default=DEFAULT_PREDICTOR, help="Constants' JSON or a learned tier's folder")
    ap.add_argument("--agent", type=Path, action="append", default=None, help="Agent run on every UAV (repeatable)")
    ap.add_argument("--agents-only", action="store_true", help="The agents alone: no random walk, greedy or searcher")
    ap.add_argument("--searcher-only", action="store_true", help="The searcher alone: no random walk, greedy or agent")
    plans = typing.get_args(SearchConfig.model_fields["fleet_plan"].annotation)
    ap.add_argument("--plan", action="append", choices=plans, default=None, help="The searcher's plan (repeatable)")
    args = ap.parse_args()
    config = FleetConfig(uavs=args.uavs, users=args.users)
    predictor, cache = load_predictor(args.predictor), PredictionCache(args.root / PREDICTIONS)
    print(f"{args.uavs} UAVs, {args.users} users, {args.episodes} episodes a city; success / median steps / SPL (seconds)")
    folders = [] if args.searcher_only else args.agent or [Path("data/agents/best"), Path("data/agents/fleet")]
    agents = [load_agent(f, 0.096, args.seed, task=None) for f in folders]
    names = [("" if a.config.task.kind == "fleet" else "independent ") + a.name for a in agents]
    searchers = [SearchConfig(fleet_plan=p) for p in args.plan or [SearchConfig().fleet_plan]]
    searcher_names = [f"map searcher ({s.fleet_plan})" for s in searchers]
    if args.agents_only:
        columns = names
    elif args.searcher_only:
        columns = searcher_names
    else:
        columns = ["random walk", "greedy", *names, *searcher_names]
    print(f"| city | oracle median | {' | '.join(columns)} | last median / oracle's |")
    print("|---|---|" + "---|" * (len(columns) + 1))
    for city in args.city or VALIDATION:
        bundle = load_bundle(city, root=args.root)
        if bundle.manifest.config.role == "test":
            ap.error(f"{city} is a test city: release numbers come from a report, never a choice")
        maps = FleetMaps.of([bundle], config)
        episodes = maps.episode_list(args.episodes, args.seed)
        cells, table = [], None
        players = [FleetPlacement(a.policy, a.config.env_config(evaluation=True), name, prefix="").bind(maps)
                   for a, name in zip(agents, names, strict=True)]  # fmt: skip
        if not args.agents_only:
            baselines = [] if args.searcher_only else [FleetRandomWalk(args.seed), FleetGreedy(args.seed)]
            players = [*baselines, *players, *(FleetSearcher(predictor, s, cache).bind(maps) for s in searchers)]
        for policy in players:
            t0 = time.perf_counter()
            table = run_fleet(maps, policy, episodes)
            wall = time.perf_counter() - t0
            cells.append(f"{100 * table['success'].mean():.0f} % / {np.median(table['steps']):g} / "
                         f"{table['spl'].mean():.3f} ({wall:.0f} s)")  # fmt: skip
        oracle = float(np.median(table["oracle_steps"]))
        ratio = np.median(table["steps"]) / oracle
        print(f"| {city} | {oracle:g} | {' | '.join(cells)} | {ratio:.2f} x |", flush=True)


if __name__ == "__main__":
    main()

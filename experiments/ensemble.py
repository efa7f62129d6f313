"""Several seeds of one preset acting as one agent (the mean of their Q values), against each seed alone.

The ensemble is the one ``uavrl ensemble`` writes (``MeanQ``): every seed keeps its own GRU state; the ensemble's
greedy move maximises the mean of the seeds' Q values minus the test rule's revisit penalty (the first run's), with
the report's epsilon 0.096. Each city is played by
``eval.evaluate.evaluate`` on the episodes ``uavrl report --seed`` draws (1000 by default), the genie beside. Measure it
on validation cities only: it is a candidate lever, not a way to look at test cities. ``uavrl ensemble`` writes the
ensemble chosen as an agent folder.

    python experiments/ensemble.py runs/levers-v5/GRU-R32-s0 runs/levers-v5/GRU-R32-s1 runs/levers-v5/GRU-R32-s2 \\
        --city corpus-016 --city corpus-017 --city oldtown-005
"""

from __future__ import annotations

import argparse
from pathlib import Path

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.cities import development_cities
from uavplace.eval.evaluate import Agent, ReportConfig, evaluate, load_agent
from uavplace.rl.agent.dqn import DQNPolicy
from uavplace.rl.agent.network import MeanQ
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.world.stats import summarise


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="Run folders of one preset (their checkpoints/best.pt)")
    ap.add_argument("--city", action="append", default=None, help="Validation city (repeatable; default: every one)")
    ap.add_argument("--release", action="store_true", help="Allow test cities (release numbers only, never to choose)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    agents = [load_agent(folder, 0.096, args.seed) for folder in args.runs]
    for a in agents:
        a.name = a.policy.name = a.folder.name
    first = agents[0]
    policy = DQNPolicy(MeanQ([a.policy.net for a in agents]), 0.096, args.seed, "ensemble", first.config.test_revisit_penalty)
    ensemble = Agent("ensemble", first.folder, first.config, first.run, policy, None, None)
    print("| city | " + " | ".join(["ensemble", *(a.name for a in agents), "genie"]) + " |")
    print("|" + "---|" * (len(agents) + 3))
    for city in development_cities(args.city, args.root, release=args.release):
        config = ReportConfig(dataset=city, episodes=args.episodes, t_max=500, seed=args.seed, trajectories=0)
        results = evaluate(config, load_bundle(city, root=args.root), [ensemble, *agents], baselines=[GeniePolicy()])
        cells = [f"{100 * s['success']:.1f} % / {s['median_steps']:g}" for s in map(summarise, results.values())]
        print(f"| {city} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()

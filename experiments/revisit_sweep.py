"""The acting rule's revisit penalty (and genie-head weight), swept on the validation cities (choose them there,
never on a test city).

Each run's ``best.pt`` plays the same episodes (``uavrl report``'s draw, t_max 500, epsilon
0.096) once per penalty ``beta`` and head weight ``aux``: the greedy move maximises
``Q - beta * visits + aux * log p`` (``visits``: earlier visits of the cell it leads to,
``DQNPolicy.revisit_penalty``; ``p``: the genie-move head's probability of the move, runs trained
with ``aux_genie`` only, ``DQNPolicy.aux_weight``; 0 and 0 are the plain argmax). Printed per city and
rule: the mean over the runs of the success, of the median steps and of its ratio to the
genie's median, and each run's success. Every (run, rule) is a freshly loaded agent, so
the random moves are the same draws for each rule.

    python experiments/revisit_sweep.py runs/agents-v2/best-s* --city corpus-016 --city corpus-017 \
        --city oldtown-005 [--beta 0 --beta 1 ...] [--aux 0 --aux 10 ...] [--episodes 1000]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.cities import development_cities
from uavplace.eval.evaluate import ReportConfig, evaluate, load_agent
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.world.stats import summarise

BETAS = (0.0, 1.0, 3.0, 10.0, 30.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--city", action="append", default=None, help="City to play (repeatable; default: every validation city)")
    ap.add_argument("--release", action="store_true", help="Allow test cities (release numbers only, never to choose)")
    ap.add_argument("--beta", action="append", type=float, default=None, help=f"Penalty per earlier visit (default {BETAS})")
    ap.add_argument("--aux", action="append", type=float, default=None, help="Genie-head weight (default 0)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    rules = [(b, w) for b in args.beta or list(BETAS) for w in args.aux or [0.0]]
    print("| city | penalty | head weight | success (mean of runs) | median steps | x genie | per run |")
    print("|---|---|---|---|---|---|---|")
    mean_success: dict[tuple[float, float], list[float]] = {r: [] for r in rules}
    for city in development_cities(args.city, args.root, release=args.release):
        agents = []
        for beta, weight in rules:
            for folder in args.runs:
                a = load_agent(folder, 0.096, args.seed)
                if weight > 0 and getattr(a.policy.net, "aux", None) is None:
                    raise SystemExit(f"{folder}: --aux {weight:g} needs a run trained with aux_genie > 0")
                a.name = a.policy.name = f"{folder.name} beta={beta:g} aux={weight:g}"
                a.policy.revisit_penalty, a.policy.aux_weight = beta, weight
                agents.append(a)
        config = ReportConfig(dataset=city, episodes=args.episodes, t_max=500, seed=args.seed, trajectories=0)
        results = evaluate(config, load_bundle(city, root=args.root), agents, baselines=[GeniePolicy()])
        genie = summarise(results[GeniePolicy.name])["median_steps"]
        for beta, weight in rules:
            s = [summarise(results[f"{f.name} beta={beta:g} aux={weight:g}"]) for f in args.runs]
            success = np.mean([x["success"] for x in s])
            median = np.mean([x["median_steps"] for x in s])
            mean_success[beta, weight].append(success)
            per_run = " / ".join(f"{100 * x['success']:.1f}" for x in s)
            print(
                f"| {city} | {beta:g} | {weight:g} | {100 * success:.1f} % | {median:.0f} | {median / genie:.2f} | {per_run} % |",
                flush=True,
            )
    print(
        "mean success over the cities: "
        + ", ".join(f"beta {b:g} aux {w:g}: {100 * np.mean(v):.1f} %" for (b, w), v in mean_success.items())
    )


if __name__ == "__main__":
    main()

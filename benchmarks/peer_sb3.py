"""A peer on the same env: Stable-Baselines3's DQN and PPO (CnnPolicy) against a `best` run, on the validation cities.

``train``: one SB3 algorithm on the training cities of the shipped agents (the corpora and the train city, their
train users, the paper's env: height map + SINR memory, t_max 800) until this process has used as many CPU
seconds as the `best` run of ``--match`` took in wall time (that run shared 2 cores with two others, so the peer
gets more compute than it did), on one torch thread; ``eval.peer.train_sb3``.
``table``: the `best` run, the peers and the genie on the same 1000 episodes of each validation city
(``eval.report.evaluate``: t_max 500, test epsilon 0.096 for every learner); success and median steps with
95 % intervals over users then episodes, and the ratios `best` / peer (success) and peer / `best` (median steps).

    OMP_NUM_THREADS=1 python benchmarks/peer_sb3.py train ppo --match runs/agents-v6/best-s4 --out runs/peer/ppo
    OMP_NUM_THREADS=1 python benchmarks/peer_sb3.py train dqn --match runs/agents-v6/best-s4 --out runs/peer/dqn
    python benchmarks/peer_sb3.py table --best runs/agents-v6/best-s4 --peer runs/peer/dqn --peer runs/peer/ppo
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.catalog import expand_datasets
from uavplace.eval.cities import development_cities
from uavplace.eval.metrics import bootstrap_table
from uavplace.eval.peer import load_peer, train_sb3
from uavplace.eval.report import ReportConfig, evaluate, load_agent
from uavplace.rl.agent.train import plan_cities
from uavplace.rl.config import EnvConfig
from uavplace.rl.maps import MapSet
from uavplace.rl.policies import GeniePolicy
from uavplace.rl.rollout import format_stat


def train(args: argparse.Namespace) -> None:
    seconds = args.cpu_seconds
    if seconds is None:
        seconds = float(pd.read_parquet(args.match / "eval.parquet")["wall_s"].iloc[-1])
    torch.set_num_threads(1)
    cities = expand_datasets(args.dataset, args.root)
    plan = plan_cities([load_bundle(c, root=args.root) for c in cities], [], None)  # the users a `best` run trains on
    maps = MapSet(plan.train, EnvConfig(split=plan.train_split), plan.train_users)
    record = train_sb3(args.algo, maps, args.out, cpu_seconds=seconds, max_steps=args.max_steps, n_envs=args.n_envs,
                       seed=args.seed, on_progress=lambda step, cpu: print(f"{args.algo}: step {step:,}, {cpu:.0f} CPU s", flush=True))  # fmt: skip
    print(
        f"{args.algo}: {record['steps']:,} steps in {record['cpu_seconds']:.0f} CPU s ({record['wall_seconds']:.0f} s wall) -> {args.out}"
    )


def table(args: argparse.Namespace) -> None:
    cities = development_cities(args.city, args.root)
    best = load_agent(args.best, 0.096, args.seed)
    best.name = best.policy.name = f"{best.name} [{args.best.name}]"
    bundles = {city: load_bundle(city, root=args.root) for city in cities}
    # The peers once: a model is made with an env, but its weights and its moves do not depend on which city's.
    maps = MapSet([bundles[cities[0]]], EnvConfig(t_max=500, rotate=False))
    peers = [load_peer(folder, maps, seed=args.seed) for folder in args.peer]
    lines = []
    for city, bundle in bundles.items():
        config = ReportConfig(dataset=city, episodes=args.episodes, t_max=500, seed=args.seed, trajectories=0)
        results = evaluate(config, bundle, [best], baselines=[GeniePolicy(), *peers])
        t = bootstrap_table(results, seed=args.seed).set_index("method")
        for name in [best.name, *(p.name for p in peers), GeniePolicy.name]:
            r = t.loc[name]
            row = {"city": city, "method": name, "success": r.success, "median_steps": r.median_steps}
            row["cells"] = (format_stat("success", r.success, r.success_lo, r.success_hi),
                            format_stat("median_steps", r.median_steps, r.median_steps_lo, r.median_steps_hi, 500))  # fmt: skip
            lines.append(row)
    df = pd.DataFrame(lines)
    out = [
        "| city | method | success | median steps | best / it: success | it / best: median steps |",
        "|---|---|---|---|---|---|",
    ]
    for city, part in df.groupby("city", sort=False):
        ref = part.iloc[0]
        for r in part.itertuples():
            ratio_s = "-" if r.method == ref.method or r.success == 0 else f"{ref.success / r.success:.2f}"
            ratio_m = (
                "-"
                if r.method == ref.method
                else ("inf" if not np.isfinite(r.median_steps) else f"{r.median_steps / ref.median_steps:.2f}")
            )
            out.append(f"| {city} | {r.method} | {r.cells[0]} | {r.cells[1]} | {ratio_s} | {ratio_m} |")
    text = "\n".join(out) + "\n"
    print(text, end="")
    if args.markdown:
        args.markdown.write_text(text, encoding="utf-8")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train", help="train one SB3 algorithm")
    t.add_argument("algo", choices=["dqn", "ppo"])
    t.add_argument("--out", type=Path, required=True)
    t.add_argument("--match", type=Path, help="a `best` run whose wall time is the CPU budget")
    t.add_argument("--cpu-seconds", type=float, default=None, help="the CPU budget [s] (instead of --match)")
    t.add_argument("--max-steps", type=int, default=3_000_000, help="env steps at most (the schedules anneal over them)")
    t.add_argument("--dataset", action="append", default=None, help="training city or corpus (default: corpus, oldtown, train)")
    t.add_argument("--n-envs", type=int, default=8)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--root", type=Path, default=Path("data/processed"))
    e = sub.add_parser("table", help="play the `best` run and the peers on the validation cities")
    e.add_argument("--best", type=Path, required=True)
    e.add_argument("--peer", type=Path, action="append", required=True)
    e.add_argument("--city", action="append", default=None, help="validation city (default: every one built)")
    e.add_argument("--episodes", type=int, default=1000)
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--markdown", type=Path, default=None)
    e.add_argument("--root", type=Path, default=Path("data/processed"))
    args = ap.parse_args()
    if args.command == "train":
        if args.match is None and args.cpu_seconds is None:
            ap.error("give --match RUN or --cpu-seconds S")
        args.dataset = args.dataset or ["corpus", "oldtown", "train"]
        train(args)
    else:
        table(args)


if __name__ == "__main__":
    main()

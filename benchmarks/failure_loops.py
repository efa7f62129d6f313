"""How an agent fails: loops near one spot, or long searches elsewhere.

Plays an agent on the report's episodes of each city (``eval.report.evaluate``, the same episodes,
epsilon and seed as ``uavrl report``) with every path recorded, and prints for its failed episodes
the number of distinct cells visited in the step budget: a failure that visits few cells is a loop
(the agent circles a small patch), one that visits hundreds is a search that never found the user.

    python benchmarks/failure_loops.py [--run data/agents/best] [--city florence --city test] [--episodes 1000]
"""

from __future__ import annotations

import argparse

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.report import ReportConfig, evaluate, load_agent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", default="data/agents/best", help="Agent folder (default: the shipped best)")
    ap.add_argument("--city", action="append", default=None, help="Test city (repeatable; default: florence, test)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--loop", type=int, default=50, help="A failure visiting fewer distinct cells than this is a loop")
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    print(f"| city | failures | distinct cells visited: p10 / median / p90 | loops (< {args.loop} cells) | loops / episodes |")
    print("|---|---|---|---|---|")
    for city in args.city or ["florence", "test"]:
        config = ReportConfig(dataset=city, episodes=args.episodes, trajectories=3)  # trajectories: record every path
        agent = load_agent(args.run, config.test_epsilon, config.seed)
        df = evaluate(config, load_bundle(city, root=args.root), [agent], baselines=[])[agent.name]
        failed = df[~df["success"]]
        distinct = np.array([len({tuple(c) for c in df.attrs["paths"][e]}) for e in failed["episode"]])
        if not len(distinct):
            print(f"| {city} | 0 | - | - | - |")
            continue
        p10, p50, p90 = np.percentile(distinct, [10, 50, 90])
        loops = int((distinct < args.loop).sum())
        print(
            f"| {city} | {len(failed)} | {p10:.0f} / {p50:.0f} / {p90:.0f} | {loops} ({100 * loops / len(failed):.1f} %) "
            f"| {100 * loops / len(df):.1f} % |"
        )


if __name__ == "__main__":
    main()

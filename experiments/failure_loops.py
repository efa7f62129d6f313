"""How an agent fails: loops near one spot, or long searches elsewhere.

Plays an agent on the report's episodes of each city (``eval.evaluate.evaluate``, the same episodes,
epsilon and seed as ``uavrl report``) with every path recorded, and prints for its failed episodes
the number of distinct cells visited in the step budget: a failure that visits few cells is a loop
(the agent circles a small patch), one that visits hundreds is a search that never found the user.
A second table follows each failed search from the best SINR it measured: the share of its moves made with
that cell beyond the window (half of the agent's window: where nothing it sees points back), the move at which
it first left it so, and the best SINR itself (how near P_T the search came before it drifted off).

    python experiments/failure_loops.py [--run data/agents/best] [--city florence --city test] [--episodes 1000]
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from common import agent_parser

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.cities import development_cities
from uavplace.eval.evaluate import ReportConfig, evaluate, load_agent


def main() -> None:
    ap = agent_parser(__doc__)
    ap.add_argument("--loop", type=int, default=50, help="A failure visiting fewer distinct cells than this is a loop")
    args = ap.parse_args()
    print(f"| city | failures | distinct cells visited: p10 / median / p90 | loops (< {args.loop} cells) | loops / episodes |")
    print("|---|---|---|---|---|")
    drift = []
    for city in development_cities(args.city, args.root, release=args.release):
        config = ReportConfig(dataset=city, episodes=args.episodes, trajectories=3)  # trajectories: record every path
        agent = load_agent(args.run, config.test_epsilon, config.seed)
        bundle = load_bundle(city, root=args.root)
        df = evaluate(config, bundle, [agent], baselines=[])[agent.name]
        failed = df[~df["success"]]
        drift.append(best_cell_drift(failed, df.attrs["paths"], np.asarray(bundle.sinr_db), agent.config.env.window // 2))
        drift[-1].insert(0, city)
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
    print(
        "\n| city | failures | moves with the best cell beyond the window: median share | first move beyond it: "
        "p10 / median / p90 | best SINR measured [dB]: p10 / median / p90 |\n|---|---|---|---|---|"
    )
    for row in drift:
        print("| " + " | ".join(row) + " |")


def best_cell_drift(failed: pd.DataFrame, paths: dict, sinr: np.ndarray, half: int) -> list[str]:
    """Cells of the drift table for the ``failed`` episodes: how long each kept the cell of its best SINR so far
    more than ``half`` cells away (Chebyshev: outside the window), when it first did, and that best SINR."""
    if not len(failed):
        return ["0", "-", "-", "-"]
    share, first, best = [], [], []
    for episode, user in zip(failed["episode"], failed["user"], strict=True):
        path = np.asarray(paths[episode])
        measured = sinr[user, path[:, 0], path[:, 1]]
        # The first cell of the best SINR so far, after each move: np.maximum.accumulate keeps the running best,
        # and its first index is where the running best last rose.
        rose = np.r_[True, measured[1:] > np.maximum.accumulate(measured)[:-1]]
        best_at = np.maximum.accumulate(np.where(rose, np.arange(len(measured)), 0))
        beyond = np.abs(path - path[best_at]).max(axis=1) > half
        share.append(beyond.mean())
        first.append(np.argmax(beyond) if beyond.any() else len(path))
        best.append(measured.max())
    p = np.percentile
    return [
        str(len(failed)),
        f"{100 * np.median(share):.0f} %",
        " / ".join(f"{v:.0f}" for v in p(first, [10, 50, 90])),
        " / ".join(f"{v:.1f}" for v in p(best, [10, 50, 90])),
    ]


if __name__ == "__main__":
    main()

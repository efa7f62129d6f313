"""Where an agent fails: its success by how far the start lies from a target, and by the SINR it starts at.

Plays an agent on the report's episodes of each city (``eval.report.evaluate``: the same episodes, epsilon
and seed as ``uavrl report``) and prints, per city, its success and median steps in bands of the genie's
moves from the start (a search that fails near its start did not find what lay around it; one that fails
far away may have run out of moves) and in bands of the SINR it starts at. Choose on validation cities only.

    python benchmarks/failure_bands.py [--run data/agents/best] --city oldtown-005 --city corpus-016
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.report import ReportConfig, evaluate, load_agent

GENIE_BANDS = [0, 5, 10, 20, 30, 500]
SINR_BANDS = [-200, -20, -10, -5, 0, 5]


def banded(df: pd.DataFrame, column: str, edges: list[float]) -> pd.DataFrame:
    """Episodes, success [%] and median steps in each band ``(lo, hi]`` of ``column``."""
    band = pd.cut(df[column], edges)
    out = df.groupby(band, observed=True).agg(
        episodes=("success", "size"), success=("success", "mean"), median=("steps", "median")
    )
    return out.assign(success=100 * out.success)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", default="data/agents/best", help="Agent folder (default: the shipped best)")
    ap.add_argument("--city", action="append", required=True, help="City to play (repeatable)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    for city in args.city:
        config = ReportConfig(dataset=city, episodes=args.episodes, trajectories=0)
        agent = load_agent(args.run, config.test_epsilon, config.seed)
        bundle = load_bundle(city, root=args.root)
        df = evaluate(config, bundle, [agent], baselines=[])[agent.name]
        sinr = np.asarray(bundle.sinr_db)
        df["start_sinr"] = sinr[df.user, df.start_y, df.start_x]
        print(f"\n{city}: {agent.name}, success {100 * df.success.mean():.1f} % over {len(df)} episodes")
        for title, column, edges in (("genie moves", "genie_steps", GENIE_BANDS), ("start SINR [dB]", "start_sinr", SINR_BANDS)):
            table = banded(df, column, edges)
            print(f"| {title} | episodes | success | median steps |\n|---|---|---|---|")
            for band, row in table.iterrows():
                print(f"| ({band.left:g}, {band.right:g}] | {int(row.episodes)} | {row.success:.1f} % | {row['median']:g} |")


if __name__ == "__main__":
    main()

"""Where an agent fails: its success by how far the start lies from a target, and by the SINR it starts at.

Plays an agent on the report's episodes of each city (``eval.evaluate.evaluate``: the same episodes, epsilon
and seed as ``uavrl report``) and prints, per city, its success and median steps in bands of the genie's
moves from the start (a search that fails near its start did not find what lay around it; one that fails
far away may have run out of moves) and in bands of the SINR it starts at. A third table says where the successful
searches spend their moves beyond the genie's: each move that takes the UAV farther from every target (in legal moves,
``steps_to_target``) costs two over the shortest path, and the moves are split by how far from a target they were
made (near a target: the last approach; far: a search in the wrong part of the map). Choose on validation cities only.

    python experiments/failure_bands.py [--run data/agents/best] --city oldtown-005 --city corpus-016
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pandas as pd
from common import agent_parser

from uavplace.dataset.bundle import Bundle, load_bundle
from uavplace.dataset.difficulty import steps_to_target
from uavplace.eval.cities import development_cities
from uavplace.eval.evaluate import ReportConfig, evaluate, load_agent

GENIE_BANDS = [0, 5, 10, 20, 30, 500]
SINR_BANDS = [-200, -20, -10, -5, 0, 5]
AWAY_BANDS = [0, 3, 10, 20, np.inf]


def banded(df: pd.DataFrame, column: str, edges: list[float]) -> pd.DataFrame:
    """Episodes, success [%] and median steps in each band ``(lo, hi]`` of ``column``."""
    band = pd.cut(df[column], edges)
    out = df.groupby(band, observed=True).agg(
        episodes=("success", "size"), success=("success", "mean"), median=("steps", "median")
    )
    return out.assign(success=100 * out.success)


def main() -> None:
    ap = agent_parser(__doc__)
    args = ap.parse_args()
    for city in development_cities(args.city, args.root, release=args.release):
        config = ReportConfig(dataset=city, episodes=args.episodes, trajectories=3)  # trajectories: record every path
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
        ok, moves, excess, shares = away_moves(df, df.attrs["paths"], bundle, config.p_t_db)
        heads = " | ".join(f"({lo:g}, {hi:g}]" for lo, hi in pairwise(AWAY_BANDS))
        print(
            f"| successes | moves | median moves over the genie's | moves away from every target | of them, made at "
            f"these moves from a target: {heads} |\n|---|---|---|---|" + "---|" * len(shares)
        )
        print(
            f"| {ok} | {moves} | {excess:g} | {100 * shares.sum() / max(moves, 1):.1f} % | "
            + " | ".join(f"{100 * v / max(shares.sum(), 1):.0f} %" for v in shares)
            + " |"
        )


def away_moves(df: pd.DataFrame, paths: dict, bundle: Bundle, p_t_db: float) -> tuple[int, int, float, np.ndarray]:
    """The successful episodes: how many, their moves, the median of their moves less the genie's, and their moves
    that took the UAV farther from every target, counted by the distance they started from (``AWAY_BANDS``)."""
    ok = df[df.success]
    users = np.unique(ok.user.to_numpy())
    dist = steps_to_target(~bundle.blocked, np.asarray(bundle.sinr_db)[users] >= p_t_db)
    row = {u: i for i, u in enumerate(users)}
    before = []
    for episode, user in zip(ok.episode, ok.user, strict=True):
        path = np.asarray(paths[episode])
        d = dist[row[user], path[:, 0], path[:, 1]]
        before.append(d[:-1][np.diff(d) > 0])
    away = np.concatenate(before) if before else np.zeros(0)
    shares = np.histogram(away, np.add(AWAY_BANDS, 0.5))[0]  # whole moves: the bands (lo, hi] of the labels
    return len(ok), int(ok.steps.sum()), float(np.median(ok.steps - ok.genie_steps)) if len(ok) else 0.0, shares


if __name__ == "__main__":
    main()

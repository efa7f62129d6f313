"""The paper's claim at equal budget: the proposed agent (height map + SINR memory) against the blind one.

Reads the periodic validation evaluations (``eval.parquet``) of two runs trained with the same
schedule on the same cities, and prints at every step both evaluated: each success with its 95 %
Wilson interval over the evaluation's episodes, the difference with a 95 % interval (normal
approximation of two independent proportions) and the median steps.

    python experiments/paper_claim.py runs/agents-v2/proposed runs/agents-v2/blind
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

Z = 1.96


def wilson(p: float, n: int) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion ``p`` over ``n`` trials."""
    centre = (p + Z**2 / (2 * n)) / (1 + Z**2 / n)
    half = Z * np.sqrt(p * (1 - p) / n + Z**2 / (4 * n**2)) / (1 + Z**2 / n)
    return centre - half, centre + half


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("proposed", type=Path)
    ap.add_argument("blind", type=Path)
    args = ap.parse_args()
    runs = {name: (json.loads((f / "run.json").read_text()), pd.read_parquet(f / "eval.parquet")) for name, f in
            (("proposed", args.proposed), ("blind", args.blind))}  # fmt: skip
    n = {name: int(run["config"]["eval_episodes"]) for name, (run, _) in runs.items()}
    both = runs["proposed"][1].merge(runs["blind"][1], on="step", suffixes=("_p", "_b"))
    print("| env steps | proposed | blind | proposed - blind | median steps (proposed / blind) |")
    print("|---|---|---|---|---|")
    for r in both.itertuples():
        p, b = r.success_p, r.success_b
        lo_p, hi_p = wilson(p, n["proposed"])
        lo_b, hi_b = wilson(b, n["blind"])
        half = Z * np.sqrt(p * (1 - p) / n["proposed"] + b * (1 - b) / n["blind"])
        med = " / ".join("> 500" if not np.isfinite(m) else f"{m:g}" for m in (r.median_steps_p, r.median_steps_b))
        print(f"| {r.step:,} | {100 * p:.1f} % [{100 * lo_p:.1f}, {100 * hi_p:.1f}] | {100 * b:.1f} % [{100 * lo_b:.1f}, "
              f"{100 * hi_b:.1f}] | {100 * (p - b):+.1f} [{100 * (p - b - half):+.1f}, {100 * (p - b + half):+.1f}] | {med} |")  # fmt: skip


if __name__ == "__main__":
    main()

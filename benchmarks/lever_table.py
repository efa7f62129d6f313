"""The lever table: each run's validation score and its success in the validation cities.

For every run or ensemble folder: the settings that differ from its preset, the evaluation that chose
``best.pt``, then ``best.pt`` on ``--episodes`` episodes of each validation city (t_max 500, epsilon 0.096,
the episodes ``uavrl report --seed`` draws, with the genie: ``eval.sweep.validation_table``, the table
``uavrl sweep`` ends with): success and median steps with 95 % intervals over users then episodes, the ratio
to the genie's median, and the run's wall time (``wall_s`` of its last evaluation). Test cities only with
``--release``, never to choose.

``--against RUN`` (one of the runs) adds, per city and for the cities pooled, every other run's success and
median steps minus that run's, paired on the same episodes, with 95 % intervals over users then episodes
(``eval.sweep.paired_differences``): whether a lever's change is more than the episodes' noise.

    python benchmarks/lever_table.py runs/levers/R* [--city corpus-016 --city etoile-val] [--episodes 1000]
    python benchmarks/lever_table.py data/agents/best runs/agents-v7/best-e0-8 --against data/agents/best
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from uavplace.eval.report import difference_rows, markdown_table
from uavplace.eval.sweep import markdown, paired_differences, validation_table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--city", action="append", default=None, help="City to play (repeatable; default: every validation city)")
    ap.add_argument("--release", action="store_true", help="Allow test cities (release numbers only, never to choose)")
    ap.add_argument("--against", type=Path, help="One of the runs: the others' paired differences from it")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    args = ap.parse_args()
    if args.against is not None and args.against.name not in {r.name for r in args.runs}:
        ap.error(f"--against {args.against}: not one of the runs")
    played: dict[str, dict[str, pd.DataFrame]] = {}
    table = validation_table(args.runs, args.city, root=args.root, episodes=args.episodes, seed=args.seed,
                             release=args.release, played=played)  # fmt: skip
    print(markdown(table), end="")
    if args.against is not None:
        for city, diffs in paired_differences(played, args.against.name, args.seed).items():
            print(f"\n{city}: paired differences (95 % intervals over users, then episodes)\n")
            print(markdown_table(difference_rows(diffs, 500)))


if __name__ == "__main__":
    main()

"""The lever table: each run's validation score and its success in the validation cities.

For every run or ensemble folder: the settings that differ from its preset, the evaluation that chose
``best.pt``, then ``best.pt`` on ``--episodes`` episodes of each validation city (t_max 500, epsilon 0.096,
the episodes ``uavrl report --seed`` draws, with the genie: ``eval.sweep.validation_table``, the table
``uavrl sweep`` ends with): success and median steps with 95 % intervals over users then episodes, the ratio
to the genie's median, and the run's wall time (``wall_s`` of its last evaluation). Test cities only with
``--release``, never to choose.

    python benchmarks/lever_table.py runs/levers/R* [--city corpus-016 --city etoile-val] [--episodes 1000]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from uavplace.eval.sweep import markdown, validation_table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--city", action="append", default=None, help="City to play (repeatable; default: every validation city)")
    ap.add_argument("--release", action="store_true", help="Allow test cities (release numbers only, never to choose)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    args = ap.parse_args()
    table = validation_table(args.runs, args.city, root=args.root, episodes=args.episodes, seed=args.seed, release=args.release)
    print(markdown(table), end="")


if __name__ == "__main__":
    main()

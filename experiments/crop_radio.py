"""How hard a city is for the radio, beside how built-up it is: before tracing a crop's every candidate, on a few users.

Per city (``ROOT:CITY``, or ``CITY`` under data/processed): the share of cells blocked for the UAV, and over the
users' open cells the share that reaches P_T, the dead share and the median SINR. With ``--versus A B`` (two cities
of the same grid and users, e.g. a crop traced with and without ``uavdata simulate --surround``) also the quantiles
of B's SINR minus A's where both are live.

    uavdata simulate sionna:florence --crop=322,32,442,152 --surround 50 --name dense6-s50 --user 376.069,142.284 \\
        --user 357.249,123.592 --user 396.583,128.385 --user 381.701,92.776 --user 349.986,46.973 \\
        --user 390.458,94.164 --seed 12 --samples 1.6e7 --gap-fill-walk 4-neighbour --out runs/bounds/raw6
    (the same with --surround 0 --name dense6-s0; then uavdata ingest and build under runs/bounds/processed6)
    python experiments/crop_radio.py florence-val etoile-val runs/bounds/processed:florence-val-dense \\
        --versus runs/bounds/processed6:dense6-s0 runs/bounds/processed6:dense6-s50

Validation cities and crops of them only: a test city is refused.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from uavplace.dataset.bundle import Bundle, load_bundle
from uavplace.infra.console import markdown_table


def _load(text: str) -> Bundle:
    root, _, city = text.rpartition(":")
    bundle = load_bundle(city, root=Path(root or "data/processed"))
    if bundle.manifest.config.role == "test":
        raise SystemExit(f"{city} is a test city: its numbers are the release's, never a choice")
    return bundle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cities", nargs="*", help="ROOT:CITY or CITY (under data/processed)")
    ap.add_argument("--versus", nargs=2, metavar=("A", "B"), help="Two traces of one grid and users: B's SINR minus A's")
    ap.add_argument("--p-t-db", type=float, default=5.0, help="The target SINR [dB]")
    args = ap.parse_args()
    rows = [["city", "cells", "users", "blocked", f"open user-cells >= {args.p_t_db:g} dB", "dead", "median SINR [dB]"]]
    named = [*args.cities, *(args.versus or ())]
    for text in named:
        b = _load(text)
        open_cells, live = ~b.blocked, ~b.dead
        sinr = np.where(live, b.sinr_db, b.sinr_floor_db)[:, open_cells]
        rows.append([text, f"{b.shape[0]} x {b.shape[1]}", str(b.num_users), f"{b.blocked.mean():.1%}",
                     f"{((b.sinr_db >= args.p_t_db) & live)[:, open_cells].mean():.1%}",
                     f"{b.dead[:, open_cells].mean():.1%}", f"{np.median(sinr):.1f}"])  # fmt: skip
    print(markdown_table(rows))
    if args.versus:
        a, b = (_load(t) for t in args.versus)
        if a.shape != b.shape or not np.array_equal(a.users[["x_m", "y_m"]], b.users[["x_m", "y_m"]]):
            raise SystemExit(f"{args.versus[0]} and {args.versus[1]}: not one grid and the same users")
        both = ~(a.dead | b.dead) & ~a.blocked
        q = np.percentile((b.sinr_db - a.sinr_db)[both], [5, 25, 50, 75, 95])
        print(f"\n{args.versus[1]} - {args.versus[0]} [dB], live in both, quantiles 5/25/50/75/95: "
              + " / ".join(f"{v:+.1f}" for v in q))  # fmt: skip


if __name__ == "__main__":
    main()

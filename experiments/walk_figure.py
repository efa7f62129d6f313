"""The walk's reach before and after (issue 51): where one user's cell values came from, under two fills of one trace.

Two bundles of the same city and trace, filled with ``--gap-fill-walk 4-neighbour`` and ``euclidean``
(``uavdata simulate ... --trace-cache DIR --gap-fill-walk W``, then ingest and build each under its own name): one
user's provenance codes side by side (ray-traced, straight path, walked, unreached, and the buildings), in a window.
The 4-neighbour walk lights a diamond around each isolated hit cell; the Euclidean one a disc along the streets.

    bash experiments/walk_validation.sh florence-val      (traces, fills both ways, builds into runs/walk/processed)
    python experiments/walk_figure.py --before florence-val-w4 --after florence-val-we --root runs/walk/processed \\
        --user 9 --window 260,90,420,250 --out docs/img/walk-before-after.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.schemas.provenance import CODES, RAY_TRACED, STRAIGHT_PATH, UNREACHED, WALKED

#: Codes drawn and their colours; buildings (blocked cells) in grey.
COLOURS = {UNREACHED: "#000000", RAY_TRACED: "#f2c14e", STRAIGHT_PATH: "#5fad56", WALKED: "#d1495b"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, help="the city filled with the 4-neighbour walk")
    ap.add_argument("--after", required=True, help="the same trace filled with the Euclidean walk")
    ap.add_argument("--root", default="data/processed")
    ap.add_argument("--user", type=int, default=0)
    ap.add_argument("--window", default=None, help="XMIN,YMIN,XMAX,YMAX [m] drawn (default: the whole grid)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 5.4), constrained_layout=True)
    for ax, name, title in zip(axes, (args.before, args.after), ("4-neighbour walk (before)", "Euclidean walk (after)"),
                               strict=True):  # fmt: skip
        b = load_bundle(name, root=args.root)
        g = b.manifest.grid
        rgb = np.ones((*b.shape, 3)) * 0.6
        codes = b.provenance[args.user]
        for code, colour in COLOURS.items():
            rgb[(codes == code) & ~b.blocked] = matplotlib.colors.to_rgb(colour)
        ax.imshow(rgb, origin="lower", extent=(g.x_min_m, g.x_max_m, g.y_min_m, g.y_max_m), interpolation="nearest")
        if args.window:
            x0, y0, x1, y1 = (float(v) for v in args.window.split(","))
            ax.set_xlim(x0, x1)
            ax.set_ylim(y0, y1)
        walked = int(((codes == WALKED) & ~b.blocked).sum())
        ax.set_title(f"{title}: {walked} walked cells", fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    handles = [matplotlib.patches.Patch(color=c, label=CODES[k][0]) for k, c in COLOURS.items()]
    handles.append(matplotlib.patches.Patch(color="0.6", label="building at or above the UAV"))
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8, bbox_to_anchor=(0.5, -0.06))
    fig.suptitle(f"user {args.user} of {args.before.rsplit('-', 1)[0]}: where each cell's value came from", fontsize=10)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90, bbox_inches="tight")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

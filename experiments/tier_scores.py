"""The predictor's tiers scored side by side on validation cities' users, with the project's scores
(rl/predictor/scores.py: median and p90 |error| [dB] on the live cells, dead/live agreement, calibration error of the
dead probability, ms a map on this machine), as docs/predictor.md's tables give them.

    python experiments/tier_scores.py --tier learned=data/agents/searcher/unet \
        --tier raytraced-1e5=runs/predictor/raytraced-1e5 [--city etoile-val ...] [--users 16] [--workers 2]

Validation cities only (data/raw/cities.toml's val): a test city is refused.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from common import VALIDATION, trace_with_workers

from uavplace.dataset.bundle import load_bundle
from uavplace.infra.console import markdown_table
from uavplace.rl.predictor import load_predictor
from uavplace.rl.predictor.scores import SCORE_COLUMNS, score_cells, score_tiers


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tier", action="append", required=True, help="NAME=PATH: a tier's folder or constants (repeatable)")
    ap.add_argument("--city", action="append", default=None, help=f"Validation city (default: {', '.join(VALIDATION)})")
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    ap.add_argument("--workers", type=int, default=1, help="Ray tasks a ray-traced tier traces in (a local Ray)")
    args = ap.parse_args()
    tiers = {}
    for text in args.tier:
        name, _, path = text.partition("=")
        tiers[name] = load_predictor(Path(path))
    trace_with_workers(list(tiers.values()), args.workers)
    bundles = []
    for city in args.city or VALIDATION:
        b = load_bundle(city, root=args.root)
        if b.manifest.config.role == "test":
            ap.error(f"{city} is a test city: never scored for a choice")
        bundles.append(b)
    scores, _ = score_tiers(bundles, tiers)
    rows = [["city", "tier", *SCORE_COLUMNS]]
    for city, row in scores.items():
        for name in tiers:
            rows.append([city, name, *score_cells(row, f"{name}_")])
    print(markdown_table(rows), flush=True)


if __name__ == "__main__":
    main()

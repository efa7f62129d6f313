"""A tracking report's tables made again from its episodes: each city's table and every city side by side.

``uavrl report --task tracking`` writes each city's episodes (``<city>-episodes.parquet``: every method's
per-episode metrics) and its config (``tracking.json``). This script recomputes the tables from them with the
report's own functions (``eval.reports.tracking.page.tracking_table`` and ``tables_markdown``, the same bootstrap resamples: the
report's ``n_boot`` and seed) and the columns of this version, such as the paired difference against the re-planning genie, so that
a report made before a column existed need not be played again. Prints Markdown: each city's table, then the
share of the horizon covered in every city side by side (``eval.reports.tracking.page.summary_rows``).

    python experiments/tracking_summary.py reports/tracking
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

from uavplace.eval.reports.tracking.page import TRACKING_JSON, tables_markdown, tracking_table
from uavplace.rl.tasks.tracking import TrackingEpisodes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path, help="A tracking report's folder (tracking.json, <city>-episodes.parquet)")
    args = ap.parse_args()
    config = json.loads((args.report / TRACKING_JSON).read_text(encoding="utf-8"))["config"]
    tables = []
    for city in config["datasets"]:
        city = city.split("@")[0]
        episodes = pd.read_parquet(args.report / f"{city}-episodes.parquet")
        results = {m: TrackingEpisodes(e.drop(columns="method").reset_index(drop=True), None)
                   for m, e in episodes.groupby("method", sort=False)}  # fmt: skip
        tables.append(tracking_table(results, config["n_boot"], config["seed"]))
    print(tables_markdown(tables, config["task"]["horizon"]), end="")


if __name__ == "__main__":
    main()

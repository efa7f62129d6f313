"""The share of the horizon covered, every method by city, from a tracking report's ``tracking.csv``.

``uavrl report --task tracking`` with several cities prints this table and writes it at the end of
``tracking.md`` (``eval.tracking.summary_rows``); this script makes it again from the CSV of a report.

    python benchmarks/tracking_summary.py reports/tracking/tracking.csv
"""

from __future__ import annotations

import argparse

import pandas as pd

from uavplace.eval.report import markdown_table
from uavplace.eval.tracking import SUMMARY_TITLE, summary_rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv", help="tracking.csv of a tracking report")
    args = ap.parse_args()
    print(f"{SUMMARY_TITLE}\n\n{markdown_table(summary_rows(pd.read_csv(args.csv)))}")


if __name__ == "__main__":
    main()

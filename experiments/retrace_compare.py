"""An embedded city traced again with provenance (``experiments/embedded_data.sh OUT``) against its committed export.

For each city of ``--retraced`` that also lies in ``--raw``: both exports must describe the same city (the same
``.city``, ``.txrx`` and ``.setup``, byte for byte); then, over every receiver of every power file, how many values
differ, how many by more than ``--tol-db`` and by more than 1 dB, how many turned dead or live, and the largest difference. Ray tracing on
the CPU does not reproduce a trace exactly (a few rays take other branches), so a re-trace moves some values.

``--install`` replaces each committed folder with its re-trace, which carries the provenance side file
(``<city>.provenance.csv.gz``) and a ``simulation.json`` of the re-trace: the re-trace is copied beside the committed
folder, then swapped in by renames, so a stop leaves one whole folder or the other. Ingest and build the cities again,
and play the release again on them, afterwards.

    python experiments/retrace_compare.py [--retraced runs/retrace] [--raw data/raw] [--city test ...] [--install]
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
from embedded_provenance import receiver_power

from uavplace.schemas.provenance import SIDE_FILE_SUFFIX
from uavplace.simulate.pipeline import PROVENANCE

SAME_FILES = (".city", ".txrx", ".setup")


def compare(committed: Path, again: Path, tol_db: float) -> dict:
    """What moved between two exports of one city (``again`` traced with provenance)."""
    name = committed.name
    for suffix in SAME_FILES:
        if (committed / f"{name}{suffix}").read_bytes() != (again / f"{name}{suffix}").read_bytes():
            raise SystemExit(f"{again / (name + suffix)}: not the committed city's ({committed / (name + suffix)})")
    if not (again / f"{name}{SIDE_FILE_SUFFIX}").is_file():
        raise SystemExit(f"{again}: no provenance side file {name}{SIDE_FILE_SUFFIX}")
    files = sorted(p.name for p in committed.glob(f"{name}.power.*.p2m.gz"))
    if files != sorted(p.name for p in again.glob(f"{name}.power.*.p2m.gz")):
        raise SystemExit(f"{again}: not the same power files as {committed}")
    out = {"receivers": 0, "differ": 0, "beyond_tol": 0, "beyond_1db": 0, "dead_to_live": 0, "live_to_dead": 0, "max_db": 0.0}
    for f in files:
        a, b = receiver_power(committed / f), receiver_power(again / f)
        out["receivers"] += len(a)
        out["dead_to_live"] += int((np.isnan(a) & ~np.isnan(b)).sum())
        out["live_to_dead"] += int((~np.isnan(a) & np.isnan(b)).sum())
        d = np.abs(a - b)[~(np.isnan(a) | np.isnan(b))]
        out["differ"] += int((d > 0).sum())
        out["beyond_tol"] += int((d > tol_db).sum())
        out["beyond_1db"] += int((d > 1.0).sum())
        out["max_db"] = max(out["max_db"], float(d.max(initial=0.0)))
    return out


def install(committed: Path, again: Path) -> None:
    """Swap ``again`` in for ``committed`` by renames (the committed folder removed last)."""
    new, old = committed.with_name(f".{committed.name}.new"), committed.with_name(f".{committed.name}.old")
    for stale in (new, old):
        if stale.exists():
            shutil.rmtree(stale)
    shutil.copytree(again, new)
    committed.rename(old)
    new.rename(committed)
    shutil.rmtree(old)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--retraced", type=Path, default=Path("runs/retrace"), help="folder of the re-traced exports")
    ap.add_argument("--raw", type=Path, default=Path("data/raw"), help="folder of the committed exports")
    ap.add_argument("--city", action="append", default=None, help="city (repeatable; default: every re-traced one)")
    ap.add_argument("--tol-db", type=float, default=0.01, help="a difference counted as a move [dB]")
    ap.add_argument("--install", action="store_true", help="replace each committed folder with its re-trace")
    args = ap.parse_args()
    cities = args.city or sorted(p.parent.name for p in args.retraced.glob(f"*/{PROVENANCE}"))
    print(f"| city | receivers | values that differ | by more than {args.tol_db:g} dB | by more than 1 dB | dead -> live | "
          "live -> dead | largest dB |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for city in cities:
        committed, again = args.raw / city, args.retraced / city
        if not (committed / PROVENANCE).is_file() or not (again / PROVENANCE).is_file():
            raise SystemExit(f"{city}: needs {committed / PROVENANCE} and {again / PROVENANCE}")
        c = compare(committed, again, args.tol_db)
        n = c["receivers"]
        print(f"| {city} | {n} | {c['differ']} ({c['differ'] / n:.1%}) | {c['beyond_tol']} ({c['beyond_tol'] / n:.1%}) | "
              f"{c['beyond_1db']} ({c['beyond_1db'] / n:.1%}) | "
              f"{c['dead_to_live']} | {c['live_to_dead']} | {c['max_db']:.1f} |", flush=True)  # fmt: skip
        if args.install:
            install(committed, again)
            print(f"{city}: installed ({json.loads((committed / PROVENANCE).read_text())['command']})", flush=True)


if __name__ == "__main__":
    main()

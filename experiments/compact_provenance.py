"""Provenance side files of an earlier version (runs of receivers) written again in today's form (a digit a receiver).

For each ``<city>.provenance.csv.gz`` under ``--raw`` whose header is ``schemas.provenance.RUN_COLUMNS``: its codes
are read, written again by ``simulate.insite.write_provenance`` (with the export sha256 it records, checked against
the .p2m files beside it first; none where it records none), read back and compared, code for code. Ingest reads
both forms and gives the same receivers table, so the bundles keep their versions; the new form takes about a
quarter of the bytes (the embedded side files: 1.07 MB -> 0.25 MB; docs/simulate.md, "Provenance").

    python experiments/compact_provenance.py [--raw data/raw] [--dry-run]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from uavplace.ingest.provenance import export_digest, preamble, read_provenance, recorded_export
from uavplace.schemas.provenance import RUN_COLUMNS, SIDE_FILE_SUFFIX
from uavplace.simulate.insite import write_provenance


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--raw", type=Path, default=Path("data/raw"), help="folder of city exports (default: data/raw)")
    ap.add_argument("--dry-run", action="store_true", help="say what would be written, write nothing")
    args = ap.parse_args()
    before_all = after_all = 0
    for path in sorted(args.raw.glob(f"*/*{SIDE_FILE_SUFFIX}")):
        folder, name = path.parent, path.name[: -len(SIDE_FILE_SUFFIX)]
        if preamble(path, str(path))[1] != RUN_COLUMNS:
            print(f"{path}: already in today's form")
            continue
        codes = read_provenance(path, str(path))
        rx_sets = {rx for _, _, rx in codes}
        if len(rx_sets) != 1:
            raise SystemExit(f"{path}: receiver sets {sorted(rx_sets)}; write_provenance writes one")
        p2m = [p for p in folder.iterdir() if p.name.lower().endswith((".p2m", ".p2m.gz"))]
        recorded = recorded_export(path, str(path))
        if recorded is not None and recorded != export_digest(p2m):
            raise SystemExit(f"{path}: records the sha256 of another export than the .p2m files beside it")
        before = path.stat().st_size
        if args.dry_run:
            print(f"{path}: {before:,} bytes, {sum(len(c) for c in codes.values()):,} receivers")
            continue
        write_provenance(folder, name, rx_sets.pop(), {(t, p): c for (t, p, _), c in codes.items()}, p2m if recorded else None)
        again = read_provenance(path, str(path))
        if again.keys() != codes.keys() or not all(np.array_equal(again[k], codes[k]) for k in codes):
            raise SystemExit(f"{path}: the codes read back differ")
        if recorded_export(path, str(path)) != recorded:
            raise SystemExit(f"{path}: the export sha256 read back differs")
        before_all, after_all = before_all + before, after_all + path.stat().st_size
        print(f"{path}: {before:,} -> {path.stat().st_size:,} bytes, the same codes")
    if after_all:
        print(f"in all: {before_all:,} -> {after_all:,} bytes")


if __name__ == "__main__":
    main()

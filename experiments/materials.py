"""How much a mix of wall materials moves a city's radio maps against all concrete, at 800 MHz and at 3.5 GHz (issue 88).

Four simulations of one validation crop with the same users, grid, rays and seed: every building concrete, and a mix
of ITU-R P.2040 classes dealt to the buildings by the seed (``uavdata simulate --materials``), each at both carriers.
Each is ingested and built as any city; over the open cells of every user it prints the share of cells whose
dead/live state agrees and, where both are live, the quantiles of |SINR mix - SINR concrete| [dB] and its mean.
The simulations go to ``--work`` (raw exports, trace cache, bundles); one already there with the same command is
kept, so the same command resumes.

    python experiments/materials.py                       # etoile-val's crop, 8 users, 40/30/20/10 %
    python experiments/materials.py --csv runs/materials/materials.csv
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from uavplace.dataset.build import build_city
from uavplace.dataset.bundle import load_bundle
from uavplace.infra.console import markdown_table
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas.bundle import BuildConfig

#: etoile-val's crop (data/raw/etoile-val/simulation.json), its seed and rays.
CROP = ["sionna:etoile", "--crop=200,-200,400,200", "--seed", "6", "--samples", "1.6e7"]
MIX = "concrete=0.4,brick=0.3,glass=0.2,metal=0.1"
CARRIERS = {"800 MHz": "8e8", "3.5 GHz": "3.5e9"}


def simulate(name: str, args: list[str], work: Path) -> Path:
    """``uavdata simulate`` into ``work/raw/<name>`` unless a simulation of the same command is there; its folder."""
    folder = work / "raw" / name
    command = ["uavdata", "simulate", *args, "--name", name, "--out", str(work / "raw"), "--trace-cache", str(work / "cache")]
    record = folder / "simulation.json"
    if not (record.is_file() and json.loads(record.read_text())["command"] == shlex.join(command)):
        print(f"simulating {name}: {shlex.join(command)}", flush=True)
        subprocess.run([str(Path(sys.executable).with_name("uavdata")), *command[1:]], check=True)
    return folder


def sinr(name: str, work: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(SINR [U, ny, nx] dB, dead [U, ny, nx], open cells [ny, nx]) of the built city ``name``."""
    root = work / "processed"
    ingest_city(work / "raw" / name, root)
    b = load_bundle(build_city(name, BuildConfig(grid_m=4.0, altitude_m=10.0), root).path)
    return b.sinr_db, b.dead, ~b.blocked


def compare(mixed: str, concrete: str, work: Path) -> dict[str, float]:
    """What the mix moves in each user's map, over the open cells."""
    s_mix, dead_mix, open_mix = sinr(mixed, work)
    s_con, dead_con, open_con = sinr(concrete, work)
    assert (open_mix == open_con).all(), "the two simulations differ in their buildings"
    cells = np.broadcast_to(open_con, dead_con.shape)
    both = cells & ~dead_mix & ~dead_con
    delta = (s_mix - s_con)[both]
    return {
        "open user-cells": int(cells.sum()),
        "dead/live agree [%]": 100 * float((dead_mix == dead_con)[cells].mean()),
        "live in concrete, dead in the mix [%]": 100 * float((dead_mix & ~dead_con)[cells].mean()),
        "dead in concrete, live in the mix [%]": 100 * float((~dead_mix & dead_con)[cells].mean()),
        "mean (mix - concrete) [dB]": float(delta.mean()),
        "p50 |d| [dB]": float(np.quantile(np.abs(delta), 0.5)),
        "p90 |d| [dB]": float(np.quantile(np.abs(delta), 0.9)),
        "p99 |d| [dB]": float(np.quantile(np.abs(delta), 0.99)),
        "cells > 3 dB [%]": 100 * float((np.abs(delta) > 3).mean()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--users", type=int, default=8, help="Users of the crop (default 8)")
    ap.add_argument("--mix", default=MIX, help=f"The mix against all concrete (default {MIX})")
    ap.add_argument("--work", type=Path, default=Path("runs/materials"), help="Where the simulations go")
    ap.add_argument("--csv", type=Path, help="Write the table here too")
    args = ap.parse_args()
    rows = []
    for carrier, hz in CARRIERS.items():
        tag = carrier.replace(" ", "").replace(".", "p").lower()
        common = [*CROP, "--users", str(args.users), "--freq", hz]
        concrete = simulate(f"mat-concrete-{tag}", common, args.work).name
        mixed = simulate(f"mat-mix-{tag}", [*common, "--materials", args.mix], args.work).name
        rows.append({"carrier": carrier} | compare(mixed, concrete, args.work))
    table = pd.DataFrame(rows)
    print(f"\nmix {args.mix} against all concrete, {args.users} users of etoile-val's crop\n")
    print(markdown_table([list(table.columns), *table.round(2).astype(str).values.tolist()]))
    if args.csv:
        table.to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()

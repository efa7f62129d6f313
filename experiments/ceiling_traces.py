"""The ceiling's true maps (docs/searcher.md, "The ceiling"): every stride-``--stride`` candidate user cell of a
validation city, ray-traced at the city's own settings (its ``simulation.json``: source, crop, seed, rays, walk),
so that the searcher can be played with the true map of every candidate.

The candidates are the searcher's own lattice (``rl.belief.candidate_cells`` over the bundle's heights). They are
traced ``--chunk`` users at a time as cities ``<city>-ceil-NNN`` under ``--raw`` (``uavdata simulate --user X,Y ...``),
one after another; a chunk traced with the same settings, or already packed in ``--out``, is skipped, so running the
command again resumes it (on a fresh clone too: the packs are committed, data/ceiling/, 10 MB budget). After the
trace (or alone, ``--pack-only``) every traced chunk is ingested, built and packed into ``--out`` (the compact
training-maps form, dataset/trainmaps.py, about 4 kB a user), which is what the ceiling reads.

    nohup nice -n 19 python experiments/ceiling_traces.py etoile-val florence-val > runs/ceiling.log 2>&1 &
    python experiments/ceiling_traces.py etoile-val florence-val --pack-only   # pack what is traced so far

Only validation cities: the test cities and their surroundings are never traced.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.catalog import read_roles
from uavplace.rl.belief import candidate_cells

#: What a chunk copies of its city's simulate command (value options), and the switch it adds.
_COPIED = ("--crop", "--seed", "--samples", "--grid", "--alt", "--freq", "--tx-dbm")


def candidates_m(city: str, stride: int, root: Path) -> np.ndarray:
    """``[C, 2]`` the metre positions (x, y) of the stride-``stride`` candidate cells of ``city``'s latest bundle."""
    b = load_bundle(city, root=root)
    ground = np.maximum(b.height_rel_m + b.altitude_m, 0)
    cells = candidate_cells(ground, stride, buildings=True)
    return np.stack([b.x_m[cells[:, 1]], b.y_m[cells[:, 0]]], axis=1)


def chunk_command(record: dict, name: str, users: np.ndarray, raw: Path) -> list[str]:
    """The ``uavdata simulate`` command of one chunk: the city's own source and settings, these users."""
    words = shlex.split(record["command"])
    source = words[2]
    options: list[str] = []
    for w in words[3:]:
        key = w.split("=", 1)[0]
        if key in _COPIED and "=" in w:
            options.append(w)
        elif options and options[-1] in _COPIED and "=" not in options[-1]:
            options.append(w)  # the value after a copied option
        elif key in _COPIED:
            options.append(w)
    walk = record["raytrace"].get("gap_fill_walk", "4-neighbour")  # a record without it traced the 4-neighbour walk
    users_args = [f"--user={x:.3f},{y:.3f}" for x, y in users]
    return ["uavdata", "simulate", source, *options, "--name", name, *users_args, "--gap-fill-walk", walk, "--out", str(raw)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cities", nargs="+", help="validation cities (data/raw/cities.toml's val)")
    ap.add_argument("--stride", type=int, default=2, help="the candidate lattice's stride [cells]")
    ap.add_argument("--chunk", type=int, default=16, help="users a traced chunk holds")
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    ap.add_argument("--raw", type=Path, default=Path("runs/ceiling/raw"))
    ap.add_argument("--processed", type=Path, default=Path("runs/ceiling/processed"))
    ap.add_argument("--out", type=Path, default=Path("data/ceiling"))
    ap.add_argument("--pack-only", action="store_true")
    args = ap.parse_args()
    val = set(read_roles(Path("data/raw/cities.toml")).val)
    for city in args.cities:
        if city not in val:
            sys.exit(f"{city} is not a validation city (data/raw/cities.toml): the ceiling is traced on validation only")
    names: list[str] = []
    for city in args.cities:
        record = json.loads((Path("data/raw") / city / "simulation.json").read_text())
        users = candidates_m(city, args.stride, args.root)
        chunks = [users[i : i + args.chunk] for i in range(0, len(users), args.chunk)]
        print(f"{city}: {len(users)} candidates at stride {args.stride}, {len(chunks)} chunks", flush=True)
        for i, part in enumerate(chunks):
            name = f"{city}-ceil-{i:03d}"
            names.append(name)
            if not args.pack_only and not (args.out / f"{name}.npz").is_file():
                subprocess.run(chunk_command(record, name, part, args.raw) + ["--quiet"], check=True)
    traced = [n for n in names if (args.raw / n / "simulation.json").is_file() and not (args.out / f"{n}.npz").is_file()]
    if not traced:
        print("no chunk traced and not packed yet")
        return
    for n in traced:
        subprocess.run(["uavdata", "ingest", str(args.raw / n), "--out", str(args.processed), "--quiet"], check=True)
    build = ["uavdata", "build", "--grid", "4m", "--alt", "10", "--root", str(args.processed), "--quiet"]
    subprocess.run(build + [f"--city={n}" for n in traced], check=True)
    pack = ["uavdata", "pack", *traced, "--root", str(args.processed), "--raw", str(args.raw), "--out", str(args.out)]
    subprocess.run(pack, check=True)
    print(f"packed {len(traced)} of {len(names)} chunks into {args.out}")


if __name__ == "__main__":
    main()

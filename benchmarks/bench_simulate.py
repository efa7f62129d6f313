"""How `uavdata simulate` scales with the rays per user: seconds per user of the radio map and of the direct paths.

Simulates one procedural city (default the embedded tiny city's recipe: ``procedural:tiny``, 4 users, seed 3) at
each ray count of ``--samples``, the first the anchor, each into a fresh temporary folder (no trace cache), and prints
per run the wall seconds, the ray tracing's and the direct paths' seconds per user (``simulation.json``), the rays
traced per second, and each run's ray-tracing time as a ratio to the anchor's (ideal: the ratio of the ray counts).
Needs Sionna RT (``pip install -e '.[raytrace]'``; on a CPU, LLVM >= 16).

    python benchmarks/bench_simulate.py [--source procedural:tiny] [--users 4] [--samples 1e6 --samples 4e6]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default="procedural:tiny", help="What `uavdata simulate` traces")
    ap.add_argument("--users", type=int, default=4)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument(
        "--samples", type=float, action="append", default=None, help="Rays per user (repeatable; the first is the anchor)"
    )
    args = ap.parse_args()
    counts = args.samples or [1e6, 4e6]
    print("| rays per user | wall [s] | ray tracing [s/user] | direct paths [s/user] | rays/s | ray tracing / anchor's |")
    print("|---|---|---|---|---|---|")
    anchor = None
    for samples in counts:
        with tempfile.TemporaryDirectory(prefix="uavplace-bench-") as out:
            cmd = [sys.executable, "-m", "uavplace.cli", "uavdata", "simulate", args.source, "--name", "bench", "--users",
                   str(args.users), "--seed", str(args.seed), "--samples", f"{samples:g}", "--out", out, "--quiet"]  # fmt: skip
            t0 = time.perf_counter()
            proc = subprocess.run(cmd, capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if proc.returncode != 0:
                sys.exit(proc.stdout + proc.stderr)
            record = json.loads((Path(out) / "bench" / "simulation.json").read_text(encoding="utf-8"))
        rt, direct = record["raytrace_seconds"], record["direct_path_seconds"]
        anchor = anchor or rt
        print(f"| {samples:g} | {wall:.1f} | {rt / args.users:.2f} | {direct / args.users:.2f} | "
              f"{samples * args.users / rt:,.0f} | {rt / anchor:.2f} (rays x {samples / counts[0]:g}) |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()

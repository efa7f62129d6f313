"""Parsing speed of receiver outputs: our .p2m reader vs pyarrow.csv and numpy.loadtxt on the same bytes.

Writes a synthetic power .p2m (new-style header, 6 significant digits, 10 %
unreached rows at the -250 dBm sentinel) and prints rows/s of each reader
(best of --repeat runs) and the ratios. Targets: ours >= 0.8 x pyarrow,
>= 10 x numpy.loadtxt.

    python benchmarks/bench_ingest.py [--rows 1000000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.csv as pacsv

from ingest.wireless_insite.p2m import read_p2m

HEADER = (
    "# <Transmitter Set: Tx: 1 User - Point 1>\n"
    "# <Receiver Set: Rx: 2 Drone_grid>\n"
    "# <X(m)> <Y(m)> <Z(m)> <Distance(m)> <Power(dBm)> <Phase(deg)>\n"
)


def write_p2m(path: Path, rows: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    nx = 1000
    i = np.arange(rows)
    x, y = (i % nx) * 4.0 - 2000.0, (i // nx) * 4.0 - 2000.0
    d = np.hypot(x, y) + 1.0
    p = -40 - 20 * np.log10(d) - rng.uniform(0, 30, rows)
    ph = rng.uniform(-180, 180, rows)
    dead = rng.random(rows) < 0.1
    p[dead], ph[dead] = -250.0, 0.0
    body = io.StringIO()
    np.savetxt(body, np.column_stack([i + 1, x, y, np.full(rows, 10.0), d, p, ph]), fmt="%d %.6g %.6g %.6g %.6g %.6g %.6g")
    path.write_text(HEADER + body.getvalue())


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000, help="receiver rows in the synthetic file")
    ap.add_argument("--repeat", type=int, default=3, help="runs per reader; the best is kept")
    ap.add_argument("--loadtxt-rows", type=int, default=200_000, help="rows given to numpy.loadtxt (its rate is per row)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.power.t001_01.r002.p2m"
        write_p2m(path, args.rows)
        raw = path.read_bytes()
        n_header = HEADER.count("\n")
        names = ["rx", "x", "y", "z", "d", "p", "ph"]

        def ours() -> None:
            meta, table = read_p2m(path)
            assert table.num_rows == args.rows

        def arrow() -> None:
            t = pacsv.read_csv(
                io.BytesIO(raw),
                pacsv.ReadOptions(column_names=names, skip_rows=n_header),
                pacsv.ParseOptions(delimiter=" "),
            )
            assert t.num_rows == args.rows

        lines = raw.split(b"\n")
        small = b"\n".join(lines[n_header : n_header + args.loadtxt_rows])

        def loadtxt() -> None:
            np.loadtxt(io.BytesIO(small))

        t_ours, t_arrow = best(ours, args.repeat), best(arrow, args.repeat)
        t_loadtxt = best(loadtxt, 1) * args.rows / min(args.rows, args.loadtxt_rows)
    size = len(raw) / 1e6
    print(f"synthetic power .p2m: {args.rows:,} rows, {size:.1f} MB")
    for label, t in (("uavplace read_p2m", t_ours), ("pyarrow.csv.read_csv", t_arrow), ("numpy.loadtxt (scaled)", t_loadtxt)):
        print(f"  {label:<24} {args.rows / t:>12,.0f} rows/s  {t:7.3f} s")
    print(f"ratio ours / pyarrow : {t_arrow / t_ours:5.2f} x  (target >= 0.8)")
    print(f"ratio ours / loadtxt : {t_loadtxt / t_ours:5.1f} x  (target >= 10)")


if __name__ == "__main__":
    main()

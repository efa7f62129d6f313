"""Parsing speed of receiver outputs: our .p2m reader vs pyarrow.csv and numpy.loadtxt on the same bytes.

Writes a synthetic power .p2m (new-style header, 6 significant digits, 10 %
unreached rows at the -250 dBm sentinel) and prints rows/s of each reader
(best of --repeat runs) and the ratios. Targets: ours >= 0.8 x pyarrow,
>= 10 x numpy.loadtxt.

    python benchmarks/bench_ingest.py [--rows 1000000] [--repeat 3]

``--memory`` instead ingests a city of one such file (default 5 M rows) with the real
``uavdata ingest`` in a child process and prints its peak RSS, beside the peak RSS of a
child that only imports the same modules, and the streaming reader's rows/s against the
same reader given the whole body as one batch (the former whole-file read), in one run.
Targets: at most 300 MB at 5 M rows, at no more than 10 % cost in rows/s.
"""

from __future__ import annotations

import argparse
import io
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.csv as pacsv

from uavplace.ingest.wireless_insite.p2m import P2MStream, read_p2m

REPO = Path(__file__).resolve().parents[1]

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
    ap.add_argument("--memory", action="store_true", help="peak RSS of `uavdata ingest` on a city of one large .p2m")
    args = ap.parse_args()
    if args.memory:
        memory(args.rows if args.rows != ap.get_default("rows") else 5_000_000, args.repeat)
        return
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


#: Runs a module as ``python -m`` would, then prints the process's own peak RSS [KiB] on stderr: VmHWM, which
#: starts afresh at exec (``ru_maxrss`` would carry the parent's peak across the fork).
_MEASURED = (
    "import runpy, sys\n"
    "sys.argv = sys.argv[1:]\n"
    "try:\n"
    "    runpy.run_module(sys.argv[0], run_name='__main__', alter_sys=True) if sys.argv[0] != '-' else None\n"
    "finally:\n"
    "    hwm = next(line for line in open('/proc/self/status') if line.startswith('VmHWM'))\n"
    "    print('peak-rss-kib', hwm.split()[1], file=sys.stderr)\n"
)


def _peak_rss_mb(module: str, *args: str, imports: str = "") -> float:
    """Peak resident memory [MB] of a child process running ``python -m module args`` (``-``: only ``imports``)."""
    env = os.environ | {"PYTHONPATH": str(REPO)}
    code = (f"import {imports}\n" if imports else "") + _MEASURED
    proc = subprocess.run([sys.executable, "-c", code, module, *args], env=env, cwd=REPO, capture_output=True, text=True)
    lines = [line for line in proc.stderr.splitlines() if line.startswith("peak-rss-kib")]
    if not lines or "error:" in proc.stdout + proc.stderr:
        raise SystemExit(f"{module} {' '.join(args)} failed:\n{proc.stdout}{proc.stderr}")
    return int(lines[-1].split()[1]) / 1024


def memory(rows: int, repeat: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        city = Path(tmp) / "big"
        city.mkdir()
        path = city / "big.power.t001_01.r002.p2m"
        t = time.perf_counter()
        write_p2m(path, rows)
        print(f"wrote {rows:,} rows ({path.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t:.0f} s")

        def streamed() -> None:
            assert sum(b.num_rows for b in P2MStream(path)) == rows

        def whole() -> None:
            assert sum(b.num_rows for b in P2MStream(path, batch_bytes=path.stat().st_size + 1)) == rows

        t_stream, t_whole = best(streamed, repeat), best(whole, repeat)
        imports = _peak_rss_mb("-", imports="uavplace.ingest.cli, uavplace.ingest.pipeline")
        t = time.perf_counter()
        peak = _peak_rss_mb("uavplace.cli", "uavdata", "ingest", str(city), "--out", str(Path(tmp) / "proc"), "--quiet")
        wall = time.perf_counter() - t
    print(f"uavdata ingest of {rows:,} rows: peak RSS {peak:.0f} MB (imports alone: {imports:.0f} MB), {wall:.1f} s")
    print(f"  streamed reader      {rows / t_stream:>12,.0f} rows/s")
    print(f"  whole body, 1 batch  {rows / t_whole:>12,.0f} rows/s")
    print(f"peak RSS: {peak:.0f} MB (target <= 300 MB at 5 M rows)")
    print(f"ratio streamed / whole rows/s: {t_whole / t_stream:5.2f} x  (target >= 0.9)")


if __name__ == "__main__":
    main()

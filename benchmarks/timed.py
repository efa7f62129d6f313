"""Any command, timed: its wall seconds beside the CPU seconds it and its children used (user + system; above the
wall time when more than one core works), so that a reader on a busier or slower machine can tell what to expect.

    python benchmarks/timed.py pytest -q
"""

from __future__ import annotations

import subprocess
import sys
import time

from main_job import children_cpu_s


def main() -> None:
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    wall, cpu = time.perf_counter(), children_cpu_s()
    done = subprocess.run(sys.argv[1:], check=False)
    wall, cpu = time.perf_counter() - wall, children_cpu_s() - cpu
    print(f"{wall:7.1f} s wall {cpu:7.1f} s CPU  {' '.join(sys.argv[1:])} (exit {done.returncode})", flush=True)
    sys.exit(done.returncode)


if __name__ == "__main__":
    main()

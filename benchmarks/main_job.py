"""The README's main job, timed: wall and CPU seconds of each of its commands, as the README states them.

It reads the first command of the README's first code block, leaves out the install (``python3 -m venv``, ``.
.venv/bin/activate``, ``pip install``) and runs the rest one command at a time in this environment, printing each
command's wall seconds beside the CPU seconds it and its children used (user + system: above the wall time when
more than one core works), then the totals. Run it from the repository root in the activated environment, on a
machine with nothing else running, for the README's numbers.

    python benchmarks/main_job.py [--readme README.md] [--dry-run]
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from pathlib import Path

INSTALL = ("python3 -m venv", ". .venv/bin/activate", "pip install")


def main_job(readme: Path) -> list[str]:
    """The main job's commands: the README's first command (the first line of its first code block that is not a
    comment), split at ``&&``, without the install steps."""
    text = readme.read_text(encoding="utf-8")
    start = text.index("```bash\n") + len("```bash\n")
    line = next(x for x in text[start:].splitlines() if x.strip() and not x.lstrip().startswith("#"))
    return [c.strip() for c in line.split("&&") if not c.strip().startswith(INSTALL)]


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--readme", type=Path, default=Path("README.md"))
    ap.add_argument("--dry-run", action="store_true", help="Print the commands only")
    args = ap.parse_args()
    commands = main_job(args.readme)
    total_wall = total_cpu = 0.0
    for command in commands:
        short = command if len(command) < 90 else command[:87] + "..."
        if args.dry_run:
            print(command)
            continue
        wall, cpu = time.perf_counter(), children_cpu_s()
        done = subprocess.run(["bash", "-c", command], stdout=subprocess.DEVNULL, check=False)  # the glob as typed
        wall, cpu = time.perf_counter() - wall, children_cpu_s() - cpu
        total_wall, total_cpu = total_wall + wall, total_cpu + cpu
        print(f"{wall:7.1f} s wall {cpu:7.1f} s CPU  {short}", flush=True)
        if done.returncode:
            sys.exit(f"exit {done.returncode}: {command}")
    if not args.dry_run:
        print(f"{total_wall:7.1f} s wall {total_cpu:7.1f} s CPU  the main job ({len(commands)} commands)")


if __name__ == "__main__":
    main()

"""Did a change move a report's numbers? The same `uavrl report` played by an earlier commit and by this tree, then
every method's headline statistics compared: the rule of issue 90 for a change that makes the arithmetic cheaper.

A change may move the numbers when, on the validation cities (the report's episodes, 300 or more a city), no
method's success or median steps leaves the interval the earlier code gave it, and no SPL moves by more than 0.01.
For the tracking report the same rule holds for its statistics: the median steps to first reach P_T, the coverage
after it, the median longest outage and the share of the horizon covered (it has no SPL). This runs the report with
the code of ``--base`` (a git worktree of that commit, ``benchmarks/versus.py``'s) and with this tree's, one after the
other, into ``--out``/base and ``--out``/tree, then prints one row per city, method and statistic: the earlier value
and interval, the new value, and whether it moved out. It exits 1 when one did.

    python benchmarks/moved.py --base HEAD -- --dataset etoile-val --dataset florence-val --episodes 1000
    python benchmarks/moved.py --base HEAD -- --task tracking --dataset etoile-val-routes --dataset trk-val
    python benchmarks/moved.py --compare runs/moved/base runs/moved/tree   # two report folders made before

Everything after ``--`` goes to `uavrl report` (``--out`` and ``--quiet`` are set here). Validation cities only: a
choice never comes from the test cities. Run it from the repository root with the bundles built.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from versus import REPO, shim  # noqa: E402 - a sibling script, imported from its folder

#: Per report file: the statistics whose new value must stay in the earlier interval, and those that may move by at
#: most ``SPL_MOVE`` (placement's ``results.csv`` per city, the fleet's ``results.csv``, the tracking ``tracking.csv``).
RULES = {
    "results.csv": (("success", "median_steps"), ("spl",)),
    "tracking.csv": (("first_reach", "coverage", "longest_outage", "covered_share"), ()),
}
#: The most an SPL may move.
SPL_MOVE = 0.01


def tables(folder: Path) -> dict[str, pd.DataFrame]:
    """``{relative path: table}`` of every report table under ``folder`` that ``RULES`` names, indexed by city (a
    placement report's: its folder's name) and method."""
    found = {}
    for name in RULES:
        for p in sorted(folder.rglob(name)):
            df = pd.read_csv(p)
            if "city" not in df:
                df = df.assign(city=p.parent.name)
            found[str(p.relative_to(folder))] = df.set_index(["city", "method"])
    return found


def compare(before: Path, after: Path) -> tuple[list[list[str]], int]:
    """The rows of the comparison (city, method, statistic, before [interval], after, verdict) and how many moved."""
    old, new = tables(before), tables(after)
    if not old or old.keys() != new.keys():
        raise SystemExit(f"{before} and {after} do not hold the same report tables: {sorted(old)} / {sorted(new)}")
    rows, moved = [], 0
    for path, a in old.items():
        inside, near = RULES[Path(path).name]
        for key, row in a.iterrows():
            other = new[path].loc[key]
            for stat in inside:
                lo, hi, now = row[f"{stat}_lo"], row[f"{stat}_hi"], other[stat]
                out = not (lo <= now <= hi)
                moved += out
                rows.append([*key, stat, f"{row[stat]:.4g} [{lo:.4g}, {hi:.4g}]", f"{now:.4g}", "MOVED OUT" if out else "in"])
            for stat in near:
                shift = other[stat] - row[stat]
                out = abs(shift) > SPL_MOVE
                moved += out
                rows.append([*key, stat, f"{row[stat]:.4f}", f"{other[stat]:.4f} ({shift:+.4f})", "MOVED" if out else "in"])
    return rows, moved


def play(base: str, report: list[str], out: Path, head: str | None = None) -> tuple[Path, Path]:
    """`uavrl report REPORT` with the code of ``base`` into ``out``/base, then with this tree's (or commit ``head``'s)
    into ``out``/tree."""
    folders = (out / "base", out / "tree")
    for path, folder in zip((str(shim(base)), str(shim(head)) if head else ""), folders, strict=True):
        env = os.environ | {"PYTHONPATH": path} if path else os.environ
        command = [sys.executable, "-c", "from uavplace.cli import uavrl; uavrl()", "report", *report]
        command += ["--out", str(folder), "--quiet", "--overwrite"]
        done = subprocess.run(command, env=env, cwd=REPO, check=False, capture_output=True, text=True)
        if done.returncode:
            raise SystemExit(f"{'the base' if path else 'this tree'}: exit {done.returncode}\n{done.stderr[-3000:]}")
    return folders


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="HEAD", help="the earlier commit (default: HEAD, the tree's changes against it)")
    ap.add_argument("--head", help="the later commit (default: this tree; a commit lets the tree change while the reports play)")
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "moved", help="where both reports go (default: runs/moved)")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"), help="compare two report folders only")
    ap.add_argument("report", nargs="*", help="`uavrl report`'s options, after --")
    args = ap.parse_args()
    before, after = args.compare if args.compare else play(args.base, args.report, args.out, args.head)
    rows, moved = compare(before, after)
    print("| city | method | statistic | before [95 % interval] | after | |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(str(c) for c in r) + " |")
    print(f"\n{moved} of {len(rows)} statistics moved out of the earlier interval (SPL: by more than {SPL_MOVE}).")
    sys.exit(1 if moved else 0)


if __name__ == "__main__":
    main()

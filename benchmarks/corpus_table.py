"""The README's table of the embedded cities: what each is, how hard it is, how faithful its maps are.

For every built city (its ``latest`` bundle) and its raw folder's
``simulation.json``: the source, size, buildings, users, role, the blocked
share, the share of legal cells at the target, the dead share, the genie's
median steps, the share of start cells excluded (no target reachable), and
the share of live cells outside buildings and above the SINR floor in constant
4 x 4 patches (cells raised to the floor are equal by design, not a mosaic), and
whether the maps show the 16 m and 64 m lattice of the earlier gap fills
(``simulate.fidelity``): the share of the dead/live boundaries between open
cells on those lines (about 25 % and 6 % when they follow the city; targets <=
30 % and <= 10 %) and the mean SINR step between live neighbours across them
over the step elsewhere (target <= 1.1).

    python benchmarks/corpus_table.py [--root data/processed] [--raw data/raw]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from uavplace.dataset.bundle import load_bundle, read_latest
from uavplace.dataset.catalog import list_cities
from uavplace.simulate.fidelity import lattice_boundary_shares, lattice_step_ratios
from uavplace.simulate.raytrace import constant_patch_share


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default="data/processed")
    ap.add_argument("--raw", default="data/raw")
    args = ap.parse_args()
    print(
        "| city | source | size [m] | buildings (tiers) | users | role | blocked | targets | dead | genie median steps "
        "| starts excluded | 4 x 4 patches | dead/live boundaries on 64 m / 16 m lines | step across 64 m / 16 m lines |"
    )
    print("|" + "---|" * 14)
    for c in list_cities(args.root):
        if read_latest(c.name, args.root) is None:
            continue
        b = load_bundle(c.name, root=args.root)
        sim = Path(args.raw) / c.name / "simulation.json"
        record = json.loads(sim.read_text()) if sim.is_file() else {}
        source = record.get("geometry", "-").split(",")[0].split(" (")[0]
        tiers = record.get("num_building_parts", "-")
        d = b.manifest.difficulty
        g = b.manifest.grid
        # live cells outside buildings and above the SINR floor (cells raised to the floor are equal by design)
        live = ~b.dead & ~b.blocked[None] & (b.sinr_db > b.sinr_floor_db)
        patches = constant_patch_share(b.sinr_db, live)
        shares = lattice_boundary_shares(~b.dead, ~b.blocked)
        steps = lattice_step_ratios(b.sinr_db, ~b.dead, ~b.blocked)
        print(
            f"| {c.name} | {source} | {g.num_x * g.spacing_m:g} x {g.num_y * g.spacing_m:g} | "
            f"{b.manifest.counts['buildings']} ({tiers}) | {b.num_users} | {b.manifest.config.role or '-'} | "
            f"{100 * d['blocked_share']:.0f} % | {100 * d['target_share']:.0f} % | {100 * d['dead_share']:.0f} % | "
            f"{d['bfs_median_steps']:g} | {_pct(d.get('excluded_start_share'))} | {100 * patches:.2f} % | "
            f"{_pct(shares['64 m'])} / {_pct(shares['16 m'])} | {steps['64 m']:.2f} / {steps['16 m']:.2f} |"
        )


if __name__ == "__main__":
    main()

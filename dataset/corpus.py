"""The table of built cities a user compares them by (``uavdata list --table``): what each is, how hard, how faithful.

For every built city (its ``latest`` bundle) and its raw folder's ``simulation.json`` where there is one: the
source, size, buildings, users, role, the blocked share, the share of legal cells at the target, the dead share, the
genie's median steps, the share of start cells excluded (no target reachable), the share of live cells outside
buildings and above the SINR floor in constant 4 x 4 patches (cells raised to the floor are equal by design, not a
mosaic), and whether the maps show the 16 m and 64 m lattice of a coarse gap fill (``simulate.fidelity``): the share
of the dead/live boundaries between open cells on those lines (about 25 % and 6 % when they follow the city) and the
mean SINR step between live neighbours across them over the step elsewhere (about 1 when they follow the city).
"""

from __future__ import annotations

from pathlib import Path

from uavplace.dataset.bundle import load_bundle, read_latest
from uavplace.dataset.catalog import list_cities
from uavplace.dataset.trainmaps import simulation_record
from uavplace.simulate.fidelity import lattice_boundary_shares, lattice_step_ratios
from uavplace.simulate.raytrace import constant_patch_share

HEADER = [
    "city",
    "source",
    "size [m]",
    "buildings (tiers)",
    "users",
    "role",
    "blocked",
    "targets",
    "dead",
    "genie median steps",
    "starts excluded",
    "4 x 4 patches",
    "dead/live boundaries on 64 m / 16 m lines",
    "step across 64 m / 16 m lines",
]


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def corpus_rows(root: str | Path, raw: str | Path) -> list[list[str]]:
    """The table's rows (header first) for the built cities under ``root``, their raw folders under ``raw``."""
    rows = [HEADER]
    for c in list_cities(root):
        if read_latest(c.name, root) is None:
            continue
        b = load_bundle(c.name, root=root)
        record = simulation_record(Path(raw) / c.name)  # a damaged record: one error line naming it
        source = str(record.get("geometry", "-")).split(",")[0].split(" (")[0]
        d, g = b.manifest.difficulty, b.manifest.grid
        live = ~b.dead & ~b.blocked[None] & (b.sinr_db > b.sinr_floor_db)
        shares = lattice_boundary_shares(~b.dead, ~b.blocked)
        steps = lattice_step_ratios(b.sinr_db, ~b.dead, ~b.blocked)
        rows.append(
            [
                c.name,
                source,
                f"{g.num_x * g.spacing_m:g} x {g.num_y * g.spacing_m:g}",
                f"{b.manifest.counts['buildings']} ({record.get('num_building_parts', '-')})",
                str(b.num_users),
                b.manifest.config.role or "-",
                f"{100 * d['blocked_share']:.0f} %",
                f"{100 * d['target_share']:.0f} %",
                f"{100 * d['dead_share']:.0f} %",
                f"{d['bfs_median_steps']:g}",
                _pct(d.get("excluded_start_share")),
                f"{100 * constant_patch_share(b.sinr_db, live):.2f} %",
                f"{_pct(shares['64 m'])} / {_pct(shares['16 m'])}",
                f"{steps['64 m']:.2f} / {steps['16 m']:.2f}",
            ]
        )
    return rows

"""What `uavdata simulate --complete-missed` gives the cells the radio map missed, against the exact-path twin (issue 51).

A city simulated three times with the same users and grid: ``--solver paths`` (PathSolver at every open cell: the
reference), the radio map with its fill (the default), and the radio map completed by exact paths at every open cell
its rays missed (``--complete-missed``). Each export is ingested (into a temporary folder) and compared receiver by
receiver over the open cells (no building at or above the plane, as the simulation computed them from its
simulation.json): over the cells the radio map missed, the median and p90 absolute error of the received power [dB]
where the reference is live (a cell the variant leaves dead counts as an infinite error, printed "dead"), and the
dead/live agreement; then over all open cells. The cost is the completion's own record (task seconds a cell and user).

    uavdata simulate procedural:oldtown:128x128 --name oldtown-twin-map --users 4 --seed 205 --samples 1.6e7 \\
        --out runs/twins/fill --trace-cache runs/traces
    uavdata simulate procedural:oldtown:128x128 --name oldtown-twin-map --users 4 --seed 205 --samples 1.6e7 \\
        --out runs/twins/complete --trace-cache runs/traces --complete-missed --complete-samples 2e6
    python experiments/complete_missed.py --paths data/raw/oldtown-twin-paths --fill runs/twins/fill/oldtown-twin-map \\
        --complete runs/twins/complete/oldtown-twin-map
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from uavplace.infra.console import markdown_table
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas.provenance import RAY_TRACED
from uavplace.simulate.config import SimulationSpec
from uavplace.simulate.pipeline import open_cells, receiver_grid
from uavplace.simulate.sources import load_geometry


def receivers(folder: Path, tmp: Path) -> pd.DataFrame:
    """The export's receivers (ingested as any city), in transmitter then receiver order."""
    ingest_city(folder, tmp, name="city")
    rx = pd.read_parquet(tmp / "city" / "ingested" / "receivers.parquet")
    return rx.sort_values(["tx_set_id", "tx_point", "rx_index"]).reset_index(drop=True)


def scores(power: np.ndarray, reference: np.ndarray, cells: np.ndarray) -> list[str]:
    """Median and p90 absolute error [dB] over the ``cells`` the reference calls live (dead: infinite), and the
    dead/live agreement over all ``cells``."""
    live_ref = ~np.isnan(reference) & cells
    err = np.where(np.isnan(power), np.inf, np.abs(power - reference))[live_ref]
    pct = [np.percentile(err, q, method="inverted_cdf") if len(err) else np.nan for q in (50, 90)]
    agree = (np.isnan(power) == np.isnan(reference))[cells].mean()
    return [" / ".join("dead" if np.isinf(v) else f"{v:.2f}" for v in pct), f"{100 * agree:.1f} %"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=Path, required=True, help="the --solver paths export (the reference)")
    ap.add_argument("--fill", type=Path, required=True, help="the radio map's export, filled (with its provenance side file)")
    ap.add_argument("--complete", type=Path, required=True, help="the same radio map completed by --complete-missed")
    args = ap.parse_args()
    record = json.loads((args.complete / "simulation.json").read_text())
    spec = SimulationSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in record["spec"].items()})
    blocks, bounds, _ = load_geometry(spec.source, spec.seed, spec.crop_m)
    opened = open_cells(blocks, receiver_grid(bounds, spec)).ravel()
    with tempfile.TemporaryDirectory(prefix="uavplace-complete-") as tmp:
        got = {name: receivers(folder, Path(tmp) / name) for name, folder in
               (("paths", args.paths), ("fill", args.fill), ("complete", args.complete))}  # fmt: skip
    users = got["paths"]["tx_point"].nunique()
    shape = (users, len(opened))
    power = {k: v["power_dbm"].to_numpy(dtype=float, na_value=np.nan).reshape(shape) for k, v in got.items()}
    cells = np.broadcast_to(opened, shape)
    missed = (got["fill"]["provenance"].to_numpy().reshape(shape) != RAY_TRACED) & cells
    rows = [["maps", "missed cells: median / p90 [dB]", "missed: dead/live", "all open cells: median / p90 [dB]",
             "all open: dead/live"]]  # fmt: skip
    for name, label in (("fill", "radio map + fill"), ("complete", "radio map + exact paths at the missed cells")):
        rows.append([label, *scores(power[name], power["paths"], missed), *scores(power[name], power["paths"], cells)])
    done = record["complete_missed"]
    print(f"{args.complete.name}: {users} users, {int(cells.sum())} open user-cells, {int(missed.sum())} missed by the rays")
    print(markdown_table(rows))
    print(
        f"completion: {done['cells']} cells of {done['users']} users at {done['samples']:g} rays, {done['seconds']:g} task "
        f"seconds, {done['seconds_per_cell']} s a cell and user; {done['cells_with_paths']} cells reached by a path"
    )


if __name__ == "__main__":
    main()

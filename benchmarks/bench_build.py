"""Speed of `uavdata build` on a paper-scale city: cells/s of our build vs a per-cell Python baseline.

Writes a synthetic paper-size city as Wireless InSite exports (550 x 500 m
receiver grid at 4 m and 10 m, 27 users, power outputs, ~190 buildings as
GeoJSON), ingests it, then times the build from the ingested tables (best of
--repeat, a forced rebuild each time). The baseline, measured in the same run
on a sample of cells and scaled per cell, is what the vectorisation replaces:
a Python loop over cells that asks an STRtree which footprint holds the cell
and averages each user's receivers in the linear domain.

    python benchmarks/bench_build.py [--repeat 3] [--users 27]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import shapely

from uavplace.dataset.build import build_city
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas.bundle import BuildConfig
from uavplace.simulate.insite import ReceiverGrid, write_p2m, write_setup, write_txrx


def write_city(folder: Path, users: int, seed: int = 0) -> ReceiverGrid:
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    grid = ReceiverGrid(x0_m=0.0, y0_m=0.0, z_m=10.0, num_x=138, num_y=126, spacing_m=4.0)
    pos = grid.points()
    tx = np.c_[rng.uniform(20, 530, users), rng.uniform(20, 480, users), np.full(users, 1.5)]
    write_txrx(folder / "city.txrx", tx, grid)
    write_setup(folder / "city.setup", "city")
    for t in range(users):
        d = np.hypot(pos[:, 0] - tx[t, 0], pos[:, 1] - tx[t, 1]) + 1.0
        p = 20 - (40 + 30 * np.log10(d) + rng.uniform(0, 20, d.size))
        p[rng.random(d.size) < 0.2] = np.nan
        write_p2m(folder, "city", "power", tx_point=t + 1, tx_set=(1, "User"), rx_set=(2, "Drone_grid"),
                  positions_m=pos, distance_m=d, values=p)  # fmt: skip
    feats = []
    for bx in np.arange(10, 540, 40.0):
        for by in np.arange(10, 490, 40.0):
            w, h = rng.uniform(12, 30, 2)
            poly = shapely.box(bx, by, bx + w, by + h)
            feats.append({"type": "Feature", "properties": {"height_m": float(rng.uniform(4, 40))},
                          "geometry": shapely.geometry.mapping(poly)})  # fmt: skip
    (folder / "b.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    return grid


def naive_seconds_per_cell(root: Path, city: str, sample: int, seed: int = 0) -> float:
    """Per-cell loop: which building holds the centre, and each user's linear mean of its receivers."""
    folder = root / city / "ingested"
    rx = pq.read_table(folder / "receivers.parquet").to_pandas()
    b = pq.read_table(folder / "building_parts.parquet").to_pandas()
    polys = shapely.from_wkb(b.footprint_wkb.to_numpy())
    tree = shapely.STRtree(polys)
    spacing = 4.0
    rx["ix"] = np.floor((rx.x_m + 2.0) / spacing).astype(int)
    rx["iy"] = np.floor((rx.y_m + 2.0) / spacing).astype(int)
    by_cell = {k: g for k, g in rx.groupby(["ix", "iy"])}
    cells = list(by_cell)
    pick = np.random.default_rng(seed).choice(len(cells), size=min(sample, len(cells)), replace=False)
    t = time.perf_counter()
    for i in pick:
        ix, iy = cells[i]
        pt = shapely.Point(ix * spacing, iy * spacing)
        hits = [j for j in tree.query(pt) if polys[j].intersects(pt)]
        _ = max((b.roof_z_m.iloc[j] for j in hits), default=0.0)
        g = by_cell[(ix, iy)]
        for _, gu in g.groupby("tx_point"):
            mw = np.where(gu.reached, 10 ** (gu.power_dbm.fillna(-400) / 10), 0.0)
            _ = 10 * np.log10(mw.mean()) if mw.any() else None
    return (time.perf_counter() - t) / len(pick)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="builds timed; the best is kept")
    ap.add_argument("--users", type=int, default=27, help="users (transmitters) of the city")
    ap.add_argument("--sample", type=int, default=400, help="cells the per-cell baseline is timed on")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        grid = write_city(tmp / "raw", args.users)
        root = tmp / "p"
        ingest_city(tmp / "raw", root, name="paper")
        config = BuildConfig(grid_m=4.0, altitude_m=10.0)
        times = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            result = build_city("paper", config, root, force=True)
            times.append(time.perf_counter() - t)
        m = result.manifest
        user_cells = m.num_users * m.grid.num_x * m.grid.num_y
        ours = min(times)
        naive = naive_seconds_per_cell(root, "paper", args.sample) * m.grid.num_x * m.grid.num_y
        table = pd.DataFrame(
            {
                "method": ["uavplace build (read + rasterise + write)", "per-cell Python loop (scaled from a sample)"],
                "seconds": [ours, naive],
                "user-cells/s": [user_cells / ours, user_cells / naive],
            }
        )
        print(
            f"city: {grid.num_x * 4:.0f} x {grid.num_y * 4:.0f} m, grid {m.grid.num_x} x {m.grid.num_y} at 4 m, "
            f"{m.num_users} users, {m.counts['buildings']} buildings, {m.counts['blocked_cells']} blocked cells"
        )
        print(table.to_string(index=False, float_format=lambda v: f"{v:,.3f}" if v < 100 else f"{v:,.0f}"))
        print(f"ratio ours / per-cell loop: {naive / ours:.1f} x   (target: a paper-scale city in seconds)")


if __name__ == "__main__":
    main()

"""How the procedural styles compare with real cities, before any ray tracing.

For every source (a few seeds of each generator-v2 style, and the real-geometry
crops), the buildings are rasterised on the 4 m grid at the 10 m altitude and
the script prints:

- the blocked share (cells under a building at or above the altitude);
- the quantiles (10, 50, 90 %) of building heights, over the cells under a building;
- the street width: twice the median distance from an open cell to the nearest
  building cell (any height) [m];
- the share of unblocked cells cut off from the largest open area (courtyards a UAV cannot leave).

    python experiments/geometry_stats.py [--seeds 3] [--real sionna:etoile@-200,-200,200,200 ...]
"""

from __future__ import annotations

import argparse

import numpy as np
import shapely
from scipy import ndimage

from uavplace.simulate.scene import Block
from uavplace.simulate.sources import load_geometry
from uavplace.simulate.styles import STYLES

GRID_M = 4.0
ALTITUDE_M = 10.0
REAL = ("sionna:etoile@-200,-200,200,200", "sionna:florence@-200,-250,200,250")


def raster_stats(blocks: list[Block], bounds: tuple[float, float, float, float]) -> dict[str, float]:
    x0, y0, x1, y1 = bounds
    gx, gy = np.meshgrid(np.arange(x0 + GRID_M / 2, x1, GRID_M), np.arange(y0 + GRID_M / 2, y1, GRID_M))
    height = np.zeros(gx.shape)
    for b in blocks:
        inside = shapely.contains_xy(b.footprint, gx, gy)
        height[inside] = np.maximum(height[inside], b.roof_z_m - b.base_z_m)
    building = height > 0
    blocked = height >= ALTITUDE_M
    street = 2 * GRID_M * float(np.median(ndimage.distance_transform_edt(~building)[~building])) if (~building).any() else 0.0
    regions, n = ndimage.label(~blocked)
    sizes = np.bincount(regions.ravel())[1:]
    enclosed = float((sizes.sum() - sizes.max()) / max(int((~blocked).sum()), 1)) if n else 0.0
    q = np.percentile(height[building], [10, 50, 90]) if building.any() else np.zeros(3)
    return {"blocked": float(blocked.mean()), "h10": q[0], "h50": q[1], "h90": q[2], "street": street, "enclosed": enclosed}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds per style")
    ap.add_argument("--real", action="append", default=None, help="SOURCE@XMIN,YMIN,XMAX,YMAX of a real city (repeatable)")
    args = ap.parse_args()
    rows = []
    for style in sorted(STYLES):
        per = [raster_stats(*load_geometry(f"procedural:{style}", seed)[:2]) for seed in range(args.seeds)]
        rows.append(
            (f"procedural:{style} (mean of {args.seeds} seeds)", {k: float(np.mean([p[k] for p in per])) for k in per[0]})
        )
    for real in args.real or REAL:
        source, _, box = real.partition("@")
        crop = tuple(float(v) for v in box.split(",")) if box else None
        try:
            blocks, bounds, _ = load_geometry(source, 0, crop)  # type: ignore[arg-type]
        except Exception as exc:  # Sionna and its scenes are an optional extra
            print(f"{real}: skipped ({type(exc).__name__}: {exc})")
            continue
        rows.append((real, raster_stats(blocks, bounds)))
    print("| source | blocked at 10 m | building height p10 / p50 / p90 [m] | street width [m] | enclosed open cells |")
    print("|---|---|---|---|---|")
    for name, r in rows:
        print(f"| {name} | {100 * r['blocked']:.0f} % | {r['h10']:.1f} / {r['h50']:.1f} / {r['h90']:.1f} | "
              f"{r['street']:.0f} | {100 * r['enclosed']:.1f} % |")  # fmt: skip


if __name__ == "__main__":
    main()

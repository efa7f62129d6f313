"""Fidelity of the radio maps `uavdata simulate` writes, against exact paths at sampled cells.

For each city, users are placed as `simulate` places them, the radio maps are
traced once (the grid and the coarser gap-fill maps), and every gap-fill
method is applied to the same maps. The reference is Sionna's ``PathSolver``
with one receiver per sampled cell centre (every path found, as InSite
computes them; the paths' powers summed, which is what a radio map estimates; a path buffer of
``PATHS_PER_POINT`` candidates per cell, so that no cell loses paths to the others; an isotropic
receiver, as the radio map's).
Printed per city and method:

- the median and p90 absolute error [dB] over the (user, cell) pairs that both call live;
- dead/live agreement over all sampled pairs;
- the share of live cells of the whole maps (outside buildings) inside a 4 x 4-cell patch of exactly equal gain.

Targets: median <= 3 dB, agreement >= 90 %, patches <= 1 %.

    python benchmarks/bench_fidelity.py [--city procedural:test] [--city sionna:etoile@-200,-200,200,200]
        [--users 3] [--cells 300] [--samples 2e6] [--ref-samples 2e6] [--seed 0] [--cache DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from uavplace.simulate.pipeline import SimulationSpec, load_geometry, open_cells, place_users, receiver_grid, squared_distances
from uavplace.simulate.raytrace import (
    FILL_METHODS,
    PATHS_PER_POINT,
    RadioMapJob,
    RayTraceConfig,
    constant_patch_share,
    fill,
    path_gain_maps_isolated,
    point_path_gains_isolated,
)
from uavplace.simulate.scene import write_scene

METHODS = ("none", *FILL_METHODS)


def _city(arg: str) -> tuple[str, tuple[float, float, float, float] | None]:
    source, _, crop = arg.partition("@")
    return source, (tuple(float(v) for v in crop.split(",")) if crop else None)  # type: ignore[return-value]


def _cached(path: Path | None, make):  # noqa: ANN001, ANN202
    """``make()``'s dict of arrays, or the one stored at ``path`` (written there after ``make`` when given)."""
    if path is not None and path.is_file():
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    out = make()
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **out)
    return out


def measure(
    source: str,
    crop: tuple[float, float, float, float] | None,
    users: int,
    cells: int,
    samples: float,
    seed: int,
    cache: Path | None = None,
    ref_samples: float | None = None,
) -> list[dict]:
    """The table's rows for one city: radio maps traced with ``samples`` rays per user, exact paths with
    ``ref_samples`` (default: ``samples``); each kept in ``cache`` under a key of its own settings, so that
    maps at another ray count are compared with the same reference."""
    ref_samples = samples if ref_samples is None else ref_samples
    spec = SimulationSpec(source=source, name="bench", num_users=users, seed=seed, crop_m=crop)
    blocks, bounds, described = load_geometry(source, seed, crop)
    grid = receiver_grid(bounds, spec)
    pos_users = place_users(blocks, grid, spec)
    size = (grid.num_x * grid.spacing_m, grid.num_y * grid.spacing_m)
    corner = (grid.x0_m - grid.spacing_m / 2, grid.y0_m - grid.spacing_m / 2)
    center = (corner[0] + size[0] / 2, corner[1] + size[1] / 2, grid.z_m)
    opened = open_cells(blocks, grid)
    rng = np.random.default_rng(seed)
    flat = rng.choice(np.flatnonzero(opened.ravel()), size=min(cells, int(opened.sum())), replace=False)
    points = grid.points()[flat]
    city_key = f"{source}-{crop}-{users}-{seed}".replace("/", "_").replace(" ", "")

    with tempfile.TemporaryDirectory() as tmp:
        bounds_box = (corner[0], corner[1], corner[0] + size[0], corner[1] + size[1])
        xml, _ = write_scene(tmp, blocks, bounds_box, RayTraceConfig().frequency_hz)
        job = RadioMapJob(str(xml), tuple(map(tuple, pos_users.tolist())), center, size, grid.spacing_m)

        def trace_maps() -> dict:
            t = time.perf_counter()
            maps = path_gain_maps_isolated(job, RayTraceConfig(samples_per_tx=int(samples), seed=seed))
            return {"t": np.float64(time.perf_counter() - t)} | {f"f{k}": v for k, v in maps.items()}

        def trace_ref() -> dict:
            t = time.perf_counter()
            ref = point_path_gains_isolated(job, points, RayTraceConfig(samples_per_tx=int(ref_samples), seed=seed))
            return {"t": np.float64(time.perf_counter() - t), "ref": ref}  # [users, cells]

        stored_maps = _cached(cache and cache / f"maps-{city_key}-{samples:g}.npz", trace_maps)
        stored_ref = _cached(cache and cache / f"ref-{city_key}-{cells}-{ref_samples:g}-{PATHS_PER_POINT}-isorx.npz", trace_ref)
    maps = {int(k[1:]): v for k, v in stored_maps.items() if k.startswith("f")}
    ref, t_maps, t_ref = stored_ref["ref"], float(stored_maps["t"]), float(stored_ref["t"])
    print(f"{source}{'@' + ','.join(f'{c:g}' for c in crop) if crop else ''}: {described}; grid {grid.num_x} x {grid.num_y}, "
          f"{len(pos_users)} users, {len(flat)} cells; radio maps ({samples:g} rays) {t_maps:.0f} s, "
          f"exact paths ({ref_samples:g} rays) {t_ref:.0f} s")  # fmt: skip
    d2 = squared_distances(pos_users, grid)
    rows = []
    for method in METHODS:
        if method == "none":
            gain = maps[1]
        else:
            gain, _ = fill(maps, RayTraceConfig(gap_fill_method=method), opened, d2)
        est = gain.reshape(len(pos_users), -1)[:, flat]
        both = (est > 0) & (ref > 0)
        err = np.abs(10 * np.log10(np.where(both, est, 1.0)) - 10 * np.log10(np.where(both, ref, 1.0)))[both]
        rows.append(
            {
                "city": source + ("@crop" if crop else ""),
                "method": method,
                "pairs_both_live": int(both.sum()),
                "median_abs_err_db": float(np.median(err)) if err.size else float("nan"),
                "p90_abs_err_db": float(np.percentile(err, 90)) if err.size else float("nan"),
                "dead_live_agreement": float(((est > 0) == (ref > 0)).mean()),
                "patch_share": constant_patch_share(gain, (gain > 0) & opened),
            }
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", default=None, help="SOURCE[@XMIN,YMIN,XMAX,YMAX] (repeatable)")
    ap.add_argument("--users", type=int, default=3)
    ap.add_argument("--cells", type=int, default=300, help="sampled cells per city (the same for every user)")
    ap.add_argument("--samples", type=float, default=2e6, help="rays per user of the radio maps")
    ap.add_argument("--ref-samples", type=float, default=None, help="rays per user of the exact paths (default: --samples)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="also write the table as CSV here")
    ap.add_argument("--cache", type=Path, default=None, help="keep the traced maps and exact paths here, to compare fills again")
    args = ap.parse_args()
    cities = args.city or ["procedural:test", "sionna:etoile@-200,-200,200,200"]
    rows = []
    for arg in cities:
        source, crop = _city(arg)
        rows += measure(source, crop, args.users, args.cells, args.samples, args.seed, args.cache, args.ref_samples)
    header = "| city | gap fill | pairs both live | median abs err [dB] | p90 abs err [dB] | dead/live agreement | 4x4 patches |"
    print(header)
    print("|" + "---|" * 7)
    for r in rows:
        print(f"| {r['city']} | {r['method']} | {r['pairs_both_live']} | {r['median_abs_err_db']:.2f} | {r['p90_abs_err_db']:.2f} "
              f"| {100 * r['dead_live_agreement']:.1f} % | {100 * r['patch_share']:.2f} % |")  # fmt: skip
    print("targets: median <= 3 dB, agreement >= 90 %, patches <= 1 %")
    if args.out is not None:
        import pandas as pd

        pd.DataFrame(rows).to_csv(args.out, index=False)


if __name__ == "__main__":
    main()

"""Fidelity of the radio maps `uavdata simulate` writes, against exact paths at sampled cells.

For each city, users are placed as `simulate` places them, the radio maps are
traced once (the grid and the coarser maps of the earlier fills), the
exact straight paths through the walls once, and every method is applied to the same maps. The
reference is Sionna's ``PathSolver`` with one receiver per sampled open cell
centre (every path, as InSite computes them; the paths' powers summed, which is what a radio map estimates; a
path buffer of ``PATHS_PER_POINT`` candidates per cell, so that no cell loses
paths to the others; an isotropic receiver, as the radio map's).
Printed per city and method:

- over ALL sampled (user, cell) pairs the reference calls live, separately for the
  cells the radio map hit and for those it alone misses: the median and p90
  absolute error [dB], where a pair the method leaves dead counts as an infinite error;
- dead/live agreement over all sampled pairs;
- on the whole maps: the share of the dead/live boundaries on the 64 m and 16 m
  lattice lines (about 6 % and 25 % when they follow the city), the mean step across
  those lines over the step elsewhere, and the share of live cells in constant 4 x 4 patches.

Targets: median <= 3 dB and p90 <= 8 dB for hit and for missed cells, agreement >= 95 %,
boundaries on 64 m lines <= 10 % and on 16 m lines <= 30 %, steps <= 1.1 x, patches <= 1 %.

    python experiments/fidelity.py [--city procedural:test#2] [--city sionna:etoile@-200,-200,200,200#4]
        [--users 3] [--cells 300] [--samples 1.6e7] [--ref-samples 2e6] [--seed 0] [--cache DIR] [--out CSV]

A city is SOURCE[@XMIN,YMIN,XMAX,YMAX][#SEED] (the seed of the generator and the users; default --seed).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from uavplace.simulate.config import SimulationSpec
from uavplace.simulate.fidelity import fill_scores
from uavplace.simulate.fill import fill
from uavplace.simulate.pipeline import direct_maps, map_quality, open_cells, place_users, receiver_grid, squared_distances
from uavplace.simulate.raytrace import (
    PATHS_PER_POINT,
    RadioMapJob,
    RayTraceConfig,
    path_gain_maps_isolated,
    point_path_gains_isolated,
)
from uavplace.simulate.scene import write_scene
from uavplace.simulate.sources import load_geometry

#: The coarse maps of the earlier fills (smooth, parent), traced for comparison.
COARSE = (4, 16)
#: Bump when simulate.transmission changes what it computes (the cache key of the direct paths).
DIRECT_VERSION = 1


def _pct(v: float | None) -> str:
    """A share, or "-" where ``map_quality`` has none (a map without a dead/live boundary)."""
    return "-" if v is None else f"{100 * v:.1f} %"


def _ratio(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def _db(v: float) -> str:
    return "dead" if v == np.inf else f"{v:.2f}"


def _city(arg: str, seed: int) -> tuple[str, tuple[float, float, float, float] | None, int]:
    """``SOURCE[@XMIN,YMIN,XMAX,YMAX][#SEED]``: the source, its crop and its seed (``seed`` when not given)."""
    arg, _, own_seed = arg.partition("#")
    source, _, crop = arg.partition("@")
    box = tuple(float(v) for v in crop.split(",")) if crop else None
    return source, box, int(own_seed) if own_seed else seed  # type: ignore[return-value]


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
    geodesic: tuple[tuple[float, float], ...] = ((24.0, 3.0),),
) -> list[dict]:
    """The table's rows for one city: radio maps traced with ``samples`` rays per user, exact paths with
    ``ref_samples`` (default: ``samples``); each kept in ``cache`` under a key of its own settings, so that
    maps at another ray count are compared with the same reference."""
    ref_samples = samples if ref_samples is None else ref_samples
    spec = SimulationSpec(source=source, name="bench", num_users=users, seed=seed, crop_m=crop)
    blocks, bounds, described = load_geometry(source, seed, crop)
    grid = receiver_grid(bounds, spec)
    pos_users = place_users(blocks, grid, spec)
    bounds_box, center, size = grid.plane()
    opened = open_cells(blocks, grid)
    rng = np.random.default_rng(seed)
    flat = rng.choice(np.flatnonzero(opened.ravel()), size=min(cells, int(opened.sum())), replace=False)
    points = grid.points()[flat]
    city_key = f"{source}-{crop}-{users}-{seed}".replace("/", "_").replace(" ", "")

    with tempfile.TemporaryDirectory() as tmp:
        xml, _ = write_scene(tmp, blocks, bounds_box, RayTraceConfig().frequency_hz)
        job = RadioMapJob(str(xml), tuple(map(tuple, pos_users.tolist())), center, size, grid.spacing_m)

        def trace_maps() -> dict:
            t = time.perf_counter()
            config = RayTraceConfig(samples_per_tx=int(samples), seed=seed, gap_fill_factors=COARSE)
            maps = path_gain_maps_isolated(job, config)
            return {"t": np.float64(time.perf_counter() - t)} | {f"f{k}": v for k, v in maps.items()}

        def trace_direct() -> dict:
            t = time.perf_counter()
            out = direct_maps(job, RayTraceConfig(seed=seed))
            return {"t": np.float64(time.perf_counter() - t)} | out

        def trace_ref() -> dict:
            t = time.perf_counter()
            ref = point_path_gains_isolated(job, points, RayTraceConfig(samples_per_tx=int(ref_samples), seed=seed))
            return {"t": np.float64(time.perf_counter() - t), "ref": ref}  # [users, cells]

        stored_maps = _cached(cache and cache / f"maps-{city_key}-{samples:g}.npz", trace_maps)
        stored_direct = _cached(cache and cache / f"direct-{city_key}-{DIRECT_VERSION}.npz", trace_direct)
        stored_ref = _cached(cache and cache / f"ref-{city_key}-{cells}-{ref_samples:g}-{PATHS_PER_POINT}-isorx.npz", trace_ref)
    maps: dict = {int(k[1:]): v for k, v in stored_maps.items() if k.startswith("f")}
    maps |= {k: v for k, v in stored_direct.items() if k != "t"}
    ref, t_maps, t_ref, t_direct = stored_ref["ref"], float(stored_maps["t"]), float(stored_ref["t"]), float(stored_direct["t"])
    print(f"{source}{'@' + ','.join(f'{c:g}' for c in crop) if crop else ''}#{seed}: {described}; grid {grid.num_x} x "
          f"{grid.num_y}, {len(pos_users)} users, {len(flat)} cells; radio maps ({samples:g} rays, with the coarse maps) "
          f"{t_maps:.0f} s, direct paths {t_direct:.0f} s, exact paths ({ref_samples:g} rays) {t_ref:.0f} s")  # fmt: skip
    d2 = squared_distances(pos_users, grid)
    hit = (maps[1] > 0).reshape(len(pos_users), -1)[:, flat]
    configs = {"none": None, "direct (reach 0)": RayTraceConfig(gap_fill_reach_m=0.0)}
    for reach, decay in geodesic:
        configs[f"geodesic {reach:g} m, {decay:g} dB/m"] = RayTraceConfig(gap_fill_reach_m=reach, gap_fill_decay_db_per_m=decay)
    for method in ("smooth", "parent"):
        configs[method] = RayTraceConfig(gap_fill_method=method, gap_fill_factors=COARSE)
    rows = []
    for method, config in configs.items():
        gain = maps[1] if config is None else fill(maps, config, opened, d2, cell_m=grid.spacing_m)[0]
        est = gain.reshape(len(pos_users), -1)[:, flat]
        rows.append({"city": f"{source}{'@crop' if crop else ''}#{seed}", "method": method, **fill_scores(est, ref, hit),
                     **map_quality(gain, opened)})  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", default=None, help="SOURCE[@XMIN,YMIN,XMAX,YMAX][#SEED] (repeatable)")
    ap.add_argument("--users", type=int, default=3)
    ap.add_argument("--cells", type=int, default=300, help="sampled cells per city (the same for every user)")
    ap.add_argument("--samples", type=float, default=1.6e7, help="rays per user of the radio maps")
    ap.add_argument("--ref-samples", type=float, default=2e6, help="rays per user of the exact paths")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--geodesic", action="append", default=None, help="REACH_M:DECAY_DB_PER_M of a geodesic fill to "
                    "measure (repeatable; default 24:3, the shipped setting)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=None, help="also write the table as CSV here")
    ap.add_argument("--cache", type=Path, default=None, help="keep the traced maps and exact paths here, to compare fills again")
    args = ap.parse_args()
    geodesic = tuple(tuple(float(v) for v in g.split(":")) for g in args.geodesic or ["24:3"])
    cities = args.city or ["procedural:test", "sionna:etoile@-200,-200,200,200"]
    rows = []
    for arg in cities:
        source, crop, seed = _city(arg, args.seed)
        rows += measure(source, crop, args.users, args.cells, args.samples, seed, args.cache, args.ref_samples, geodesic)
    print(
        "| city | method | hit pairs | hit median / p90 [dB] | missed pairs | missed median / p90 [dB] | SINR error hit "
        "median / p90 [dB] | SINR error missed median / p90 [dB] | dead/live agreement | boundaries on 64 m / 16 m "
        "lines | step across 64 m / 16 m lines | 4x4 patches |"
    )
    print("|" + "---|" * 12)
    for r in rows:
        print(f"| {r['city']} | {r['method']} | {r['hit_pairs']} | {_db(r['hit_median_db'])} / {_db(r['hit_p90_db'])} | "
              f"{r['missed_pairs']} | {_db(r['missed_median_db'])} / {_db(r['missed_p90_db'])} | "
              f"{r['sinr_hit_median_db']:.2f} / {r['sinr_hit_p90_db']:.2f} | "
              f"{r['sinr_missed_median_db']:.2f} / {r['sinr_missed_p90_db']:.2f} | "
              f"{100 * r['dead_live_agreement']:.1f} % | {_pct(r['dead_live_boundaries_on_64m_lines'])} / "
              f"{_pct(r['dead_live_boundaries_on_16m_lines'])} | {_ratio(r['step_ratio_across_64m_lines'])} / "
              f"{_ratio(r['step_ratio_across_16m_lines'])} | {100 * r['constant_4x4_patch_share']:.2f} % |")  # fmt: skip
    print(
        "targets: hit and missed median <= 3 dB and p90 <= 8 dB (a dead estimate of a live pair counts as an infinite "
        "error), agreement >= 95 %, boundaries <= 10 % / 30 %, steps <= 1.1 x, patches <= 1 %"
    )
    if len(cities) > 1:
        print("\nEach method over the cities above (means of the cities' figures; the geodesic settings are chosen on the "
              "validation cities by the SINR error over all pairs, then the agreement):")  # fmt: skip
        print("| method | SINR error, all pairs: mean / p90 [dB] | dead/live agreement |")
        print("|---|---|---|")
        for method in dict.fromkeys(r["method"] for r in rows):
            mine = [r for r in rows if r["method"] == method]
            mean_err, p90, agree = (np.mean([r[k] for r in mine]) for k in ("sinr_mean_db", "sinr_p90_db", "dead_live_agreement"))
            print(f"| {method} | {mean_err:.2f} / {p90:.2f} | {100 * agree:.1f} % |")
    if args.out is not None:
        import pandas as pd

        pd.DataFrame(rows).to_csv(args.out, index=False)


if __name__ == "__main__":
    main()

"""What reaches the cells Sionna's radio map misses: the exact paths there, by their sequence of interactions.

For a city of the fidelity benchmark (its cached radio maps and exact paths, ``bench_fidelity.py
--cache``), takes the sampled (user, cell) pairs the radio map left unreached while the exact
paths (Sionna's ``PathSolver``) reach them, traces their exact paths again for one user, and
prints, per cell, the share of its power carried by each sequence of interactions (R specular
reflection, T refraction through a wall, D diffraction, S diffuse), strongest first, then the
power share of each sequence over all those cells.

    python experiments/missed_paths.py --cache runs/fidelity/cache --city procedural:test#2 [--user 0] [--cells 12]
"""

from __future__ import annotations

import argparse
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

from uavplace.simulate.config import SimulationSpec
from uavplace.simulate.pipeline import open_cells, place_users, receiver_grid
from uavplace.simulate.raytrace import PATHS_PER_POINT, RayTraceConfig, _scene, _set_users
from uavplace.simulate.scene import write_scene
from uavplace.simulate.sources import load_geometry

#: Sionna RT's interaction types (``sionna.rt.constants.InteractionType``) by letter.
LETTERS = {1: "R", 2: "S", 4: "T", 8: "D"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", required=True, help="SOURCE[@XMIN,YMIN,XMAX,YMAX][#SEED], as bench_fidelity.py takes it")
    ap.add_argument("--cache", type=Path, required=True, help="bench_fidelity.py's --cache (its maps and exact paths)")
    ap.add_argument("--user", type=int, default=0)
    ap.add_argument("--cells", type=int, default=12, help="missed cells to trace (about a second each on 2 cores)")
    ap.add_argument("--users", type=int, default=3, help="the benchmark's --users")
    ap.add_argument("--sampled", type=int, default=300, help="the benchmark's --cells")
    args = ap.parse_args()
    arg, _, seed_text = args.city.partition("#")
    source, _, crop_text = arg.partition("@")
    seed = int(seed_text or 0)
    crop = tuple(float(v) for v in crop_text.split(",")) if crop_text else None
    spec = SimulationSpec(source=source, name="bench", num_users=args.users, seed=seed, crop_m=crop)  # type: ignore[arg-type]
    blocks, bounds, described = load_geometry(source, seed, crop)  # type: ignore[arg-type]
    grid = receiver_grid(bounds, spec)
    users = place_users(blocks, grid, spec)
    opened = open_cells(blocks, grid)
    flat = np.random.default_rng(seed).choice(
        np.flatnonzero(opened.ravel()), size=min(args.sampled, int(opened.sum())), replace=False
    )
    key = f"{source}-{crop}-{args.users}-{seed}".replace("/", "_").replace(" ", "")
    refs = sorted(args.cache.glob(f"ref-{key}-{args.sampled}-*"))
    maps = sorted(args.cache.glob(f"maps-{key}-*"))
    if not refs or not maps:
        raise SystemExit(f"no cached maps and exact paths for {args.city} in {args.cache}: run bench_fidelity.py --cache first")
    with np.load(refs[0]) as z:
        ref = z["ref"]
    with np.load(maps[0]) as z:
        fine = z["f1"].reshape(len(users), -1)[:, flat]
    missed = np.flatnonzero((fine[args.user] == 0) & (ref[args.user] > 0))
    print(f"{args.city}: {described}; user {args.user}: {len(missed)} of {len(flat)} sampled cells live in the exact paths "
          f"and missed by the radio map; tracing {min(args.cells, len(missed))}")  # fmt: skip
    points = grid.points()[flat[missed[: args.cells]]]
    size = (grid.num_x * grid.spacing_m, grid.num_y * grid.spacing_m)
    corner = (grid.x0_m - grid.spacing_m / 2, grid.y0_m - grid.spacing_m / 2)
    with tempfile.TemporaryDirectory() as tmp:
        from uavplace.simulate.raytrace import RadioMapJob

        xml, _ = write_scene(tmp, blocks, (corner[0], corner[1], corner[0] + size[0], corner[1] + size[1]), 800e6)
        job = RadioMapJob(str(xml), tuple(map(tuple, users.tolist())), (0.0, 0.0, grid.z_m), size, grid.spacing_m)
        mi, rt, scene = _scene(job, RayTraceConfig())
        for k, p in enumerate(points):
            scene.add(rt.Receiver(name=f"rx{k}", position=mi.Point3f(*map(float, p))))
        _set_users(mi, rt, scene, users[args.user : args.user + 1], args.user)
        paths = rt.PathSolver()(scene, max_depth=5, max_num_paths_per_src=PATHS_PER_POINT * len(points), samples_per_src=2_000_000,
                                diffraction=True, edge_diffraction=True, refraction=True, seed=seed)  # fmt: skip
        re, im = (np.asarray(x.numpy()) for x in paths.a)
        kinds = np.asarray(paths.interactions.numpy())
    power = (re**2 + im**2).reshape(len(points), -1)
    kinds = kinds.reshape(kinds.shape[0], len(points), -1)
    overall: Counter = Counter()
    for r in range(len(points)):
        total = power[r].sum()
        shares: Counter = Counter()
        for p in np.flatnonzero(power[r] > 0):
            seq = "".join(LETTERS.get(int(x), "?") for x in kinds[:, r, p] if int(x)) or "LOS"
            shares[seq] += float(power[r, p] / total)
        overall.update({k: v / len(points) for k, v in shares.items()})
        top = ", ".join(f"{k} {100 * v:.0f} %" for k, v in shares.most_common(3))
        print(f"cell ({points[r, 0]:.0f}, {points[r, 1]:.0f}): {10 * np.log10(total):.1f} dB; {top}")
    with_d = sum(v for k, v in overall.items() if "D" in k)
    print("power share over these cells: " + ", ".join(f"{k} {100 * v:.0f} %" for k, v in overall.most_common(8)))
    print(f"paths with a diffraction: {100 * with_d:.0f} % of the power; with a reflection before the diffraction: "
          f"{100 * sum(v for k, v in overall.items() if 'D' in k and 'R' in k.split('D')[0]):.0f} %")  # fmt: skip
    # Dr.Jit may crash in interpreter teardown after a correct run (raytrace._isolated): leave at once.
    import os
    import sys

    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    main()

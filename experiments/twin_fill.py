"""What a fill can know of the cells the radio map misses, measured on an exact-path twin (issue 32).

An exact-path twin (``uavdata simulate --solver paths``, docs/fidelity.md) holds the reference at every open
cell: every path Sionna's ``PathSolver`` finds, nothing filled. Its radio-map twin, simulated with
``--trace-cache DIR``, keeps the unfilled radio map and the direct paths in ``DIR/<name>.npz``. From the two:

1. The walk of the geodesic fill (``simulate/raytrace.py``, ``fill_geodesic``), by front (cells walked
   from the nearest hit cell through open ground): the exact gain of each missed cell relative to free
   space, minus what the walk carries there from the hit cells before any decay (dB quantiles), beside the
   shipped loss at that front. "Floor" is the median |error| that the best loss per front would leave,
   fitted on these very cells (each front's own median subtracted): no fill of this family can do better.
2. The geodesic fills (``--geodesic REACH:DECAY``) against the twin over every open (user, cell) pair, as
   ``bench_fidelity.py`` scores them (``simulate.fidelity.fill_scores``).
3. With ``--samples``: exact paths at the missed cells only, traced again with fewer rays per user than the
   twin's: seconds per cell and user, and the error against the twin there.

    uavdata simulate procedural:oldtown:128x128 --name oldtown-twin-map --users 4 --seed 205 --samples 1.6e7 \\
        --out runs/twin-fill/raw --trace-cache runs/twin-fill/traces
    python experiments/twin_fill.py --paths data/raw/oldtown-twin-paths --traces runs/twin-fill/traces/oldtown-twin-map.npz \\
        [--geodesic 24:3[:4-neighbour] ...] [--samples 2e5 ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from uavplace.ingest.wireless_insite.p2m import read_p2m
from uavplace.simulate.config import SimulationSpec
from uavplace.simulate.fidelity import error_quantiles, fill_scores
from uavplace.simulate.fill import _walk_fronts, fill, log_relative_gain
from uavplace.simulate.pipeline import open_cells, receiver_grid, squared_distances
from uavplace.simulate.raytrace import RadioMapJob, RayTraceConfig, point_path_gains_isolated
from uavplace.simulate.scene import write_scene
from uavplace.simulate.sources import load_geometry

#: Settings both twins must share to be twins (simulation.json's spec; the name and the solver differ).
SHARED = ("source", "num_users", "grid_m", "altitude_m", "tx_dbm", "seed", "extent_m", "crop_m")
#: How far the front table goes (cells walked).
FRONTS = 8


def _spec(doc: dict) -> SimulationSpec:
    """simulation.json's ``spec`` as a ``SimulationSpec`` (its lists made tuples)."""
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in doc.items() if k in SimulationSpec.__dataclass_fields__}
    return SimulationSpec(**fields)


def load_twins(paths: Path, traces: Path) -> dict:
    """The twins' arrays: the radio map (``fine``) and direct paths (``direct``) [U, ny, nx] of the trace cache,
    the exact paths (``exact``), the open cells, the squared distances and the scene's job."""
    doc = json.loads((paths / "simulation.json").read_text())
    if doc["raytrace"].get("solver") != "paths":
        raise SystemExit(f"{paths}: not an exact-path city (simulation.json's raytrace.solver is not 'paths')")
    with np.load(traces, allow_pickle=False) as z:
        key, fine, direct = json.loads(str(z["key"])), z["f1"], z["direct"]
    differ = [k for k in SHARED if key["spec"].get(k) != doc["spec"].get(k)]
    if differ:
        raise SystemExit(f"{traces} and {paths} are not twins: their spec differs in {', '.join(differ)}")
    spec = _spec(doc["spec"])
    blocks, bounds, _ = load_geometry(spec.source, spec.seed, spec.crop_m)
    grid = receiver_grid(bounds, spec)
    users = np.asarray(doc["users_m"], float)
    exact = np.zeros(fine.shape)
    for u in range(len(users)):
        _, table = read_p2m(paths / f"{spec.name}.power.t{u + 1:03d}_01.r002.p2m.gz")
        power = table.column("power_dbm").to_numpy(zero_copy_only=False)
        with np.errstate(invalid="ignore"):
            exact[u] = np.where(np.isnan(power), 0.0, 10 ** ((power - spec.tx_dbm) / 10)).reshape(fine.shape[1:])
    box, center, size = grid.plane()
    config = RayTraceConfig(**doc["raytrace"] | {"gap_fill_factors": tuple(doc["raytrace"]["gap_fill_factors"])})
    return {
        "fine": fine, "direct": direct, "exact": exact, "open": open_cells(blocks, grid), "d2": squared_distances(users, grid),
        "blocks": blocks, "box": box, "config": config,
        "job": (tuple(map(tuple, users.tolist())), center, size, grid.spacing_m), "points": grid.points(),
    }  # fmt: skip


def front_table(t: dict, decay_db_per_m: float) -> list[str]:
    """Section 1's rows: per front, the exact gain minus the walk's carried value [dB] over the missed live pairs."""
    fine, exact, d2 = t["fine"], t["exact"], t["d2"]
    spread = np.broadcast_to(t["open"], fine.shape)
    known = fine > 0
    value = log_relative_gain(fine, d2)
    front = np.zeros(fine.shape, int)
    _walk_fronts(value, known, spread, spread, sum(fine.shape[1:]), 0.0, front=front)
    sel = spread & (fine == 0) & (exact > 0)
    delta = 10 * np.log10(np.where(sel, exact * d2, 1.0)) - value * 10 / np.log(10)
    cell_m = float(t["job"][3])
    rows, residual = [], []
    for k in range(1, FRONTS + 1):
        d = delta[sel & (front == k)] if k < FRONTS else delta[sel & (front >= k)]
        if not d.size:
            continue
        residual.append(np.abs(d - np.median(d)))
        p10, med, p90 = np.percentile(d, [10, 50, 90])
        label = f"{k}" if k < FRONTS else f">= {k}"
        rows.append(f"| {label} ({k * cell_m:g} m) | {d.size} | {p10:+.1f} / {med:+.1f} / {p90:+.1f} | "
                    f"{-decay_db_per_m * cell_m * k:+.1f} | {np.median(residual[-1]):.1f} |")  # fmt: skip
    unwalked = int((sel & (front == 0)).sum())
    floor = np.median(np.concatenate(residual)) if residual else float("nan")
    rows.append(f"| all | {int(sel.sum()) - unwalked} | | | {floor:.1f} |")
    if unwalked:
        rows.append(f"| no walk reaches them | {unwalked} | | | |")
    return rows


def _db(v: float) -> str:
    return "dead" if v == np.inf else f"{v:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=Path, required=True, help="the exact-path twin's raw folder (simulate --solver paths)")
    ap.add_argument(
        "--traces", type=Path, required=True, help="the radio-map twin's trace cache file (--trace-cache DIR: DIR/NAME.npz)"
    )
    ap.add_argument("--geodesic", action="append", default=None, help="REACH_M:DECAY_DB_PER_M[:WALK] of a geodesic fill to "
                    "score (repeatable; WALK euclidean (the default) or 4-neighbour; default 0:3, 24:3:4-neighbour, 24:3 "
                    "(shipped), 24:1, 48:0.5)")  # fmt: skip
    ap.add_argument("--samples", action="append", type=float, default=[], help="rays per user of exact paths traced again "
                    "at the missed cells (repeatable; about a second a cell and user at 2e6 on 2 cores)")  # fmt: skip
    args = ap.parse_args()
    t = load_twins(args.paths, args.traces)
    fine, exact = t["fine"], t["exact"]
    opened = np.broadcast_to(t["open"], fine.shape)
    shipped = RayTraceConfig()
    print(f"{args.paths.name} against {args.traces.name}: {len(fine)} users, {int(opened.sum())} open (user, cell) pairs, "
          f"{int((opened & (fine == 0)).sum())} of them missed by the radio map ({int((opened & (fine == 0) & (exact > 0)).sum())} "
          f"live in the exact paths); the exact paths leave {int((opened & (exact == 0)).sum())} dead")  # fmt: skip
    print("\n| front (walked) | missed live pairs | exact - carried [dB]: p10 / median / p90 | shipped loss [dB] | floor: "
          "median abs error [dB] |")  # fmt: skip
    print("|---|---|---|---|---|")
    print("\n".join(front_table(t, shipped.gap_fill_decay_db_per_m)))
    print("\n| fill | hit median / p90 [dB] | missed median / p90 [dB] | SINR error hit median / p90 | SINR error missed "
          "median / p90 | SINR error, all: mean | dead/live agreement |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    hit = fine[opened] > 0
    maps = {1: fine, "direct": t["direct"]}
    for spec in args.geodesic or ["0:3", "24:3:4-neighbour", "24:3", "24:1", "48:0.5"]:
        reach, decay, *walk = spec.split(":")
        walk = walk[0] if walk else RayTraceConfig.gap_fill_walk
        config = RayTraceConfig(gap_fill_reach_m=float(reach), gap_fill_decay_db_per_m=float(decay), gap_fill_walk=walk)
        gain = fill(maps, config, t["open"], t["d2"], cell_m=float(t["job"][3]))[0]
        s = fill_scores(gain[opened], exact[opened], hit)
        print(f"| geodesic {float(reach):g} m, {float(decay):g} dB/m, {walk} | {_db(s['hit_median_db'])} / {_db(s['hit_p90_db'])} | "
              f"{_db(s['missed_median_db'])} / {_db(s['missed_p90_db'])} | {s['sinr_hit_median_db']:.2f} / "
              f"{s['sinr_hit_p90_db']:.2f} | {s['sinr_missed_median_db']:.2f} / {s['sinr_missed_p90_db']:.2f} | "
              f"{s['sinr_mean_db']:.2f} | {100 * s['dead_live_agreement']:.1f} % |")  # fmt: skip
    if not args.samples:
        return
    cells = np.flatnonzero((opened & (fine == 0)).any(axis=0).ravel())
    missed = (opened & (fine == 0)).reshape(len(fine), -1)[:, cells]
    ref = exact.reshape(len(fine), -1)[:, cells]
    print(f"\nExact paths at the {len(cells)} cells some user's radio map misses ({int(missed.sum())} missed pairs), "
          f"against the twin's ({t['config'].samples_per_tx:g} rays):")  # fmt: skip
    print("| rays per user | seconds per cell and user | missed pairs: median / p90 [dB] | dead/live agreement |")
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        xml, _ = write_scene(tmp, t["blocks"], t["box"], t["config"].frequency_hz)
        job = RadioMapJob(str(xml), *t["job"])
        for samples in args.samples:
            start = time.perf_counter()
            config = dataclasses.replace(t["config"], samples_per_tx=int(samples))
            gain = point_path_gains_isolated(job, t["points"][cells], config)
            per = (time.perf_counter() - start) / gain.size
            q = error_quantiles(gain, ref, missed)
            agree = ((gain > 0) == (ref > 0))[missed].mean()
            print(f"| {samples:g} | {per:.3f} | {_db(q['median_db'])} / {_db(q['p90_db'])} | {100 * agree:.1f} % |", flush=True)


if __name__ == "__main__":
    main()

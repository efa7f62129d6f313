"""`uavdata simulate`: a city source -> Sionna RT radio maps -> a folder of Wireless InSite exports.

The recipe:

1. geometry from the source: the procedural generator (``procedural:train``,
   ``procedural:test``, ``procedural:tiny``), an InSite ``.city`` or a GeoJSON
   file of footprints with heights (read with ingest's own parsers);
2. the grid (``--grid`` cells covering the city at ``--alt``) and the users
   (sampled on open ground, or given);
3. a Mitsuba scene (extruded buildings, ground plane, P.2040 materials) and
   one Sionna radio map per user;
4. written as InSite would: ``<name>.txrx``, ``<name>.setup``, ``<name>.city``,
   one ``<name>.power.t<PPP>_01.r002.p2m.gz`` per user (unreached cells at the
   -250 dBm threshold sentinel), and ``simulation.json`` (every parameter,
   package versions, material mapping, seed, wall time), all into a temporary
   folder renamed into place.
"""

from __future__ import annotations

import datetime as dt
import json
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import shapely

from uavplace.infra.files import atomic_directory, check_name, check_replaceable
from uavplace.infra.limits import check_limit
from uavplace.schemas import InputError
from uavplace.schemas.base import uavplace_version
from uavplace.schemas.provenance import CODES, ESTIMATED, EXACT_PATHS, UNREACHED, code_name
from uavplace.simulate.complete import complete_users, missed_cells
from uavplace.simulate.config import SimulationSpec
from uavplace.simulate.fidelity import lattice_boundary_shares, lattice_step_ratios
from uavplace.simulate.fill import check_fill, fill
from uavplace.simulate.insite import (
    UNREACHED_POWER_DBM,
    ReceiverGrid,
    write_city,
    write_p2m,
    write_provenance,
    write_setup,
    write_txrx,
)
from uavplace.simulate.procedural import USER_HEIGHT_M, sample_users
from uavplace.simulate.raytrace import (
    RadioMapJob,
    RayTraceConfig,
    constant_patch_share,
    direct_gains_isolated,
    exact_path_maps,
    free_space_cap,
    path_gain_maps_isolated,
    raytrace_record,
    sionna_versions,
)
from uavplace.simulate.routes import KINDS, MAX_STEP_M, ROUTE_SET, Route, draw_routes, write_routes_csv
from uavplace.simulate.scene import CONCRETE, GROUND_MARGIN_M, Block, assign_materials, parse_mix, walls_of, write_scene
from uavplace.simulate.sources import check_bounded, check_simulation, load_geometry, surrounded
from uavplace.simulate.trace_cache import cached_traces, read_cache_entry, spec_record, trace_key, write_cache_entry
from uavplace.simulate.transmission import EVERY_SHAPE

USER_SET = (1, "User")
GRID_SET = (2, "Drone_grid")
#: Files of a simulated city beside the exports (ingest lists them as provenance and skips them).
PROVENANCE = "simulation.json"


SOLVER_TEXT = {"radio-map": "Sionna's radio map", "paths": "Sionna's PathSolver, a receiver at every open cell's centre"}
PATHS_TEXT = (
    "none: every open cell from exact paths (PathSolver, every path of up to max_depth interactions, as InSite "
    "computes them); a cell no path reaches stays unreached"
)
#: How the geodesic fill's walk measures its way (``RayTraceConfig.gap_fill_walk``).
WALK_TEXT = {
    "euclidean": "the shortest way in steps of 1, sqrt 2 and sqrt 5 cells, no corner of a building cut",
    "4-neighbour": "steps along the axes only, front by front",
}
#: How simulation.json describes each gap-fill method.
GAP_FILL_TEXT = {
    "geodesic": "a cell no ray hit takes the exact straight path from the user through the walls it crosses (ITU-R "
    "P.2040-4 slab transmission of the wall material at each crossing's incidence, free space, the user antenna's "
    "gain; none when it crosses more than max_depth walls), and a hit cell keeps at least that path's power; cells "
    "within {reach:g} m of a hit cell, walking through cells without a building at or above the plane ({walk}), "
    "take the geometric mean of their known neighbours' gain relative to free space, nearest first, less {decay:g} "
    "dB per metre walked; no coarse maps",
    "smooth": "a cell no ray hit, whose parent in the maps of {factors} x coarser cells got rays, takes the geometric "
    "mean of its known 4-neighbours' gain relative to free space, spread outward from the hit cells through cells "
    "without a building at or above the plane; then each parent's gaps are scaled to the parent's mean gain",
    "parent": "a cell no ray hit takes the mean path gain of its parent cell in the maps of {factors} x coarser cells "
    "(same samples per user), finest first",
}


def gap_fill_text(config: RayTraceConfig) -> str:
    """What simulation.json says of how the cells no ray hit were filled (none with exact paths)."""
    if config.solver == "paths":
        return PATHS_TEXT
    return GAP_FILL_TEXT[config.gap_fill_method].format(
        factors=config.gap_fill_factors,
        reach=config.gap_fill_reach_m,
        decay=config.gap_fill_decay_db_per_m,
        walk=WALK_TEXT[config.gap_fill_walk],
    )


def open_cells(blocks: list[Block], grid: ReceiverGrid) -> np.ndarray:
    """[num_y, num_x] True where no building reaches the receiver plane at the cell centre."""
    tall = [b.footprint for b in blocks if b.roof_z_m >= grid.z_m]
    if not tall:
        return np.ones((grid.num_y, grid.num_x), bool)
    pts = grid.points()
    inside = shapely.contains_xy(shapely.union_all(tall), pts[:, 0], pts[:, 1])
    return ~inside.reshape(grid.num_y, grid.num_x)


def squared_distances(users: np.ndarray, grid: ReceiverGrid) -> np.ndarray:
    """[num_users, num_y, num_x] squared distance [m^2] from each user to each cell centre (at least 1 m^2)."""
    pts = grid.points()
    d2 = ((pts[None, :, :] - np.asarray(users, float)[:, None, :]) ** 2).sum(axis=-1)
    return np.maximum(d2, 1.0).reshape(len(users), grid.num_y, grid.num_x)


def buildings_of(blocks: list[Block]) -> list[list[tuple[shapely.Polygon, float, float]]]:
    """Blocks grouped by building, as ``write_city`` takes them: per building its parts (footprint, base, roof)."""
    grouped: dict[int, list[tuple[shapely.Polygon, float, float]]] = {}
    for b in blocks:
        grouped.setdefault(b.building, []).append((b.footprint, b.base_z_m, b.roof_z_m))
    return list(grouped.values())


def receiver_grid(bounds: tuple[float, float, float, float], spec: SimulationSpec) -> ReceiverGrid:
    x0, y0, x1, y1 = spec.extent_m or bounds
    nx, ny = int((x1 - x0) // spec.grid_m), int((y1 - y0) // spec.grid_m)
    # The work of the radio maps grows with the cells as well as with the rays: a grid no build could take is refused
    # before the ray tracer starts (a 5 km extent at 1 m held 25 M cells and ran for hours).
    check_limit("grid_cells", nx * ny, "--grid", "cells of the receiver grid (the extent over the grid squared)", field="grid_m")
    check_bounded(nx * ny * (len(spec.users_m) or spec.num_users), "--grid with --users (the city's size)", limit="user_cells")
    if nx < 2 or ny < 2:
        raise InputError(
            spec.source, f"a {x1 - x0:g} x {y1 - y0:g} m extent holds fewer than 2 x 2 cells of {spec.grid_m:g} m", field="extent"
        )
    return ReceiverGrid(
        x0_m=x0 + spec.grid_m / 2, y0_m=y0 + spec.grid_m / 2, z_m=spec.altitude_m, num_x=nx, num_y=ny, spacing_m=spec.grid_m
    )


def city_routes(blocks: list[Block], grid: ReceiverGrid, spec: SimulationSpec) -> list[Route]:
    """``spec.routes`` routes over the open ground of the grid (``simulate.routes``), seeded by ``spec.seed``."""
    if not spec.routes:
        return []
    x0, y0 = grid.x0_m - grid.spacing_m / 2, grid.y0_m - grid.spacing_m / 2
    box = (x0, y0, x0 + grid.num_x * grid.spacing_m, y0 + grid.num_y * grid.spacing_m)
    try:
        return draw_routes(
            [b.footprint for b in blocks],
            box,
            spec.routes,
            spec.route_length_m,
            spec.route_kinds,
            np.random.default_rng([spec.seed, 3]),
        )
    except ValueError as err:
        raise InputError(spec.source, str(err), field="routes") from None


def place_users(blocks: list[Block], grid: ReceiverGrid, spec: SimulationSpec) -> np.ndarray:
    foot = [b.footprint for b in blocks]
    union = shapely.union_all(foot) if foot else shapely.Polygon()
    x0, y0 = grid.x0_m - grid.spacing_m / 2, grid.y0_m - grid.spacing_m / 2
    x1, y1 = x0 + grid.num_x * grid.spacing_m, y0 + grid.num_y * grid.spacing_m
    if spec.extent_m is not None and foot and not shapely.intersects(shapely.box(x0, y0, x1, y1), union):
        raise InputError(
            spec.source, f"the grid x {x0:g}..{x1:g}, y {y0:g}..{y1:g} does not overlap the city's buildings", field="extent"
        )
    if spec.users_m:
        users = np.array([(x, y, USER_HEIGHT_M) for x, y in spec.users_m])
        inside = shapely.contains_xy(union, users[:, 0], users[:, 1]) if foot else np.zeros(len(users), bool)
        if inside.any():
            k = int(np.flatnonzero(inside)[0])
            raise InputError(
                spec.source, f"user {k + 1} at ({users[k, 0]:g}, {users[k, 1]:g}) is inside a building", field="user"
            )
        off = (users[:, 0] < x0) | (users[:, 0] > x1) | (users[:, 1] < y0) | (users[:, 1] > y1)
        if off.any():
            k = int(np.flatnonzero(off)[0])
            raise InputError(spec.source, f"user {k + 1} at ({users[k, 0]:g}, {users[k, 1]:g}) is outside the grid", field="user")
        return users
    rng = np.random.default_rng([spec.seed, 2])
    try:
        users = sample_users(
            (x1 - x0, y1 - y0), [shapely.transform(f, lambda c: c - [x0, y0]) for f in foot], spec.num_users, rng
        )
    except ValueError as err:  # too little open ground 8 m inside the edges
        raise InputError(
            spec.source, f"{err}: give a larger --extent or --crop, fewer --users, or place them with --user", field="users"
        ) from None
    return users + [x0, y0, 0.0]


def as_written(gain: np.ndarray, source: np.ndarray, tx_dbm: float) -> tuple[np.ndarray, np.ndarray]:
    """The received power each .p2m gets [U, ny * nx] (dBm; NaN: unreached, written as the no-path value) and the
    provenance codes as ingest will read them: a power written at or below the no-path value is unreached."""
    g = gain.reshape(len(gain), -1)
    with np.errstate(divide="ignore"):
        power = np.where(g > 0, tx_dbm + 10 * np.log10(np.where(g > 0, g, 1.0)), np.nan)
    codes = np.where(np.round(power, 4) > UNREACHED_POWER_DBM, source.reshape(len(source), -1), UNREACHED).astype(np.uint8)
    return power, codes.reshape(source.shape)


def transmitter_of(source: int, num_users: int) -> tuple[tuple[int, str], int]:
    """(transmitter set, point number) of traced source ``source``: the users first, then the route points."""
    return (USER_SET, source + 1) if source < num_users else (ROUTE_SET, source - num_users + 1)


def direct_maps(
    job: RadioMapJob,
    config: RayTraceConfig,
    on_batch: Callable[[int, int], None] | None = None,
    walls: dict[str, dict] | None = None,
) -> dict:
    """What ``fill``'s ``geodesic`` method adds to the radio maps of ``job``: the exact straight paths through the
    buildings' walls (``raytrace.direct_gains``, in a child process), ``{"direct": [U, ny, nx], "crossings": ...}``;
    ``walls``: each building shape's material (``scene.walls_of``; None: every wall concrete)."""
    walls = {EVERY_SHAPE: CONCRETE.at(config.frequency_hz)} if walls is None else walls
    return direct_gains_isolated(job, config, walls, on_batch=on_batch)


def map_quality(gain: np.ndarray, open_cells: np.ndarray) -> dict[str, float]:
    """The reference-free measures of ``simulate.fidelity`` on path gain maps [U, ny, nx]: the share of the dead/live
    boundaries on the 16 m and 64 m lattice lines, the step ratios across them, and the constant 4 x 4 patch share."""
    live = gain > 0
    shares = lattice_boundary_shares(live, open_cells)
    with np.errstate(divide="ignore"):
        steps = lattice_step_ratios(np.where(live, 10 * np.log10(np.where(live, gain, 1.0)), 0.0), live, open_cells)
    out = {
        "dead_live_boundaries_on_64m_lines": shares["64 m"],
        "dead_live_boundaries_on_16m_lines": shares["16 m"],
        "step_ratio_across_64m_lines": steps["64 m"],
        "step_ratio_across_16m_lines": steps["16 m"],
        "constant_4x4_patch_share": constant_patch_share(gain, live & open_cells),
    }
    return {k: (None if np.isnan(v) else v) for k, v in out.items()}  # None (JSON null) where undefined: no boundary


def complete_missed(
    job: RadioMapJob,
    config: RayTraceConfig,
    missed: np.ndarray,
    cache: Path | None,
    key: str,
    name: str,
    *,
    address: str | None = None,
    cpus_per_user: float = 2.0,
    progress: Callable[[str, int, int], None] | None = None,
) -> tuple[np.ndarray, dict]:
    """Exact path gains at the ``missed`` cells [U, ny, nx] (``simulate.complete``; 0 elsewhere and where no path was
    found) and what the completion cost. Each user's result is kept in ``cache/<name>.missed-<user>.npz`` (under
    ``key`` and the PathSolver rays) as it arrives and reused, so an interrupted completion resumes per user."""
    exact = np.zeros(missed.shape)
    record = {
        "cells": int(missed.sum()),
        "users": int(missed.any(axis=(1, 2)).sum()),
        "samples": config.complete_missed_samples,
        "users_from_cache": 0,
        "seconds": 0.0,
    }
    entry_key = f"{key}|complete-missed|{config.complete_missed_samples}"
    entries = {u: None if cache is None else cache / f"{name}.missed-{u + 1:04d}.npz" for u in range(len(missed))}
    todo = []
    for u in np.flatnonzero(missed.any(axis=(1, 2))).tolist():
        arrays, _ = read_cache_entry(entries[u], entry_key) if entries[u] is not None and entries[u].is_file() else (None, "")
        if arrays is not None and arrays["gain"].shape == (int(missed[u].sum()),):
            exact[u][missed[u]] = arrays["gain"]
            record["users_from_cache"] += 1
        else:
            todo.append(u)
    done = [record["users"] - len(todo)]

    def on_user(u: int, gains: np.ndarray, seconds: float) -> None:
        exact[u][missed[u]] = gains
        record["seconds"] += seconds
        if entries[u] is not None:
            write_cache_entry(entries[u], entry_key, {"gain": gains})
        done[0] += 1
        if progress is not None:
            progress("exact paths (users)", done[0], record["users"])

    paths_config = replace(config, samples_per_tx=config.complete_missed_samples)
    complete_users(job, paths_config, missed, todo, on_user, address=address, cpus_per_user=cpus_per_user)
    traced = record["cells"] - sum(int(missed[u].sum()) for u in range(len(missed)) if u not in todo)
    record["seconds"] = round(record["seconds"], 2)
    record["seconds_per_cell"] = round(record["seconds"] / traced, 3) if traced else None
    record["cells_with_paths"] = int((exact[missed] > 0).sum())
    return exact, record


def simulate_city(
    spec: SimulationSpec,
    rt_config: RayTraceConfig,
    out_root: str | Path = "data/raw",
    *,
    command: str = "",
    on_progress: Callable[[str, int, int], None] | None = None,
    trace_cache: str | Path | None = None,
    ray_address: str | None = None,
    cpus_per_user: float = 2.0,
) -> tuple[Path, dict]:
    """Simulate one city into ``out_root/<name>/``; returns (folder, the simulation.json record).

    ``trace_cache``: a folder where the traced maps are kept (``<name>.npz``) and reused when the spec and the
    ray-trace settings are the same, so that changing only the fill's reach, decay or walk needs no new trace; the
    exact paths of ``--complete-missed`` are kept there per user. ``ray_address``, ``cpus_per_user``: where the
    completion's Ray tasks run (``simulate.complete``).
    """

    def progress(stage: str, done: int, total: int) -> None:
        if on_progress is not None:
            on_progress(stage, done, total)

    check_name(spec.name, "city name")
    check_simulation(spec, rt_config)
    try:
        check_fill(rt_config)
    except ValueError as err:
        raise InputError(spec.source, str(err), field="gap_fill_method") from None
    check_replaceable(Path(out_root) / spec.name, PROVENANCE, "simulated city")  # before minutes of ray tracing
    t_start = time.perf_counter()
    blocks, bounds, described = load_geometry(spec.source, spec.seed, spec.crop_m)
    traced = blocks  # what the ray tracer sees: the city's buildings, and with --surround those around the crop
    if spec.surround_m:
        traced = load_geometry(spec.source, spec.seed, surrounded(spec.crop_m, spec.surround_m))[0]
        described += f"; traced with the buildings within {spec.surround_m:g} m around it ({len(traced)} roof tiers in all)"
    grid = receiver_grid(bounds, spec)
    users = place_users(blocks, grid, spec)
    routes = city_routes(blocks, grid, spec)
    route_points = (
        np.concatenate([np.c_[r.points_m, np.full(len(r.points_m), USER_HEIGHT_M)] for r in routes])
        if routes
        else np.zeros((0, 3))
    )
    sources = np.concatenate([users, route_points])  # every transmitter traced: the users, then the route points
    box, center, size = grid.plane()
    progress("scene", 0, len(users))
    opened = open_cells(blocks, grid)
    with tempfile.TemporaryDirectory(prefix="uavplace-scene-") as tmp:
        margin = GROUND_MARGIN_M + spec.surround_m  # the ground under every traced building
        mix = parse_mix(spec.materials)
        materials_of = assign_materials([b.building for b in traced], mix, spec.seed)
        xml, materials = write_scene(tmp, traced, box, rt_config.frequency_hz, ground_margin_m=margin, materials_of=materials_of)
        job = RadioMapJob(str(xml), tuple(map(tuple, sources.tolist())), center, size, spec.grid_m)
        seconds = {"raytrace": 0.0, "direct": 0.0}

        def trace() -> dict:
            t = time.perf_counter()
            if rt_config.solver == "paths":  # every open cell from exact paths: nothing to fill
                exact = exact_path_maps(job, rt_config, opened, on_batch=lambda d, n: progress("exact paths (cells)", d, n))
                seconds["raytrace"] = time.perf_counter() - t
                return {1: exact}
            maps: dict = path_gain_maps_isolated(job, rt_config, on_batch=lambda d, n: progress("ray tracing", d, n))
            seconds["raytrace"] = time.perf_counter() - t
            if rt_config.gap_fill_method == "geodesic":
                t = time.perf_counter()
                maps |= direct_maps(
                    job, rt_config, on_batch=lambda d, n: progress("direct paths", d, n), walls=walls_of(materials)
                )
                seconds["direct"] = time.perf_counter() - t
            return maps

        # What a trace of this city holds at most: a fine, a direct and each coarse map of float64 per source and cell,
        # with room for the arrays beside them: an entry that inflates beyond it is not read.
        most = 8.0 * len(sources) * grid.num_x * grid.num_y * (4 + 2 * len(rt_config.gap_fill_factors)) + 2**20
        maps, cached = cached_traces(
            Path(trace_cache) if trace_cache else None, spec.name, trace_key(spec, rt_config), trace, most
        )
        d2 = squared_distances(sources, grid)
        gain, source = fill(maps, rt_config, opened, d2, cell_m=grid.spacing_m)
        cap = free_space_cap(d2, rt_config.frequency_hz, rt_config.antenna)  # d2: 3D, the users at their height
        capped = gain > cap  # grazing rays' artifacts: above free space and paths in phase
        gain = np.where(capped, cap, gain)
        completion = None
        if rt_config.complete_missed_samples:  # exact paths where the rays missed: their values, not the fill's estimates
            missed = missed_cells(maps[1], opened)
            exact, completion = complete_missed(
                job,
                rt_config,
                missed,
                Path(trace_cache) if trace_cache else None,
                trace_key(spec, rt_config),
                spec.name,
                address=ray_address,
                cpus_per_user=cpus_per_user,
                progress=progress,
            )
            gain = np.where(missed, exact, gain)
            source = np.where(missed, np.where(exact > 0, EXACT_PATHS, UNREACHED), source).astype(np.uint8)
    pos = grid.points()  # [ny * nx, 3], x fastest: the same order as gain[u].ravel()
    with atomic_directory(Path(out_root) / spec.name, marker=PROVENANCE, what="simulated city") as out:
        write_txrx(
            out / f"{spec.name}.txrx",
            users,
            grid,
            tx_power_dbm=spec.tx_dbm,
            user_set=USER_SET,
            grid_set=GRID_SET,
            route_points_m=route_points,
            route_set=ROUTE_SET,
        )
        if routes:
            write_routes_csv(out / f"{spec.name}.routes.csv", routes)
        write_setup(out / f"{spec.name}.setup", spec.name, frequency_hz=rt_config.frequency_hz, features=[f"{spec.name}.city"])
        write_city(out / f"{spec.name}.city", buildings_of(blocks), name=spec.name)
        power, source = as_written(gain, source, spec.tx_dbm)
        codes, written = {}, []
        for u in range(len(sources)):
            dist = np.linalg.norm(pos - sources[u], axis=1)
            tx_set, tx_point = transmitter_of(u, len(users))
            written.append(
                write_p2m(
                    out,
                    spec.name,
                    "power",
                    tx_point=tx_point,
                    tx_set=tx_set,
                    rx_set=GRID_SET,
                    positions_m=pos,
                    distance_m=dist,
                    values=power[u],
                    gz=True,
                )
            )
            codes[(tx_set[0], tx_point)] = source[u].ravel()
            progress("writing", u + 1, len(sources))
        write_provenance(out, spec.name, GRID_SET[0], codes, written)
        gain = np.where(source == UNREACHED, 0.0, gain)
        reached = gain > 0
        filled = np.isin(source, ESTIMATED)
        quality = map_quality(gain[: len(users)], opened)
        record = {
            "tool": "uavdata simulate",
            "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            "uavplace_version": uavplace_version(),
            "command": command,
            "spec": spec_record(spec),
            "geometry": described,
            "num_buildings": len({b.building for b in blocks}),
            "num_building_parts": len(blocks),
            "grid": {
                "x0_m": grid.x0_m,
                "y0_m": grid.y0_m,
                "num_x": grid.num_x,
                "num_y": grid.num_y,
                "spacing_m": grid.spacing_m,
                "altitude_m": spec.altitude_m,
            },
            "users_m": np.round(users, 3).tolist(),
            "routes": {
                "count": len(routes),
                "points": len(route_points),
                "kinds": {k: sum(r.kind == k for r in routes) for k in spec.route_kinds} if routes else {},
                "speeds_mps": {k: KINDS[k] for k in spec.route_kinds} if routes else {},
                "length_m": spec.route_length_m if routes else 0.0,
                "max_step_m": MAX_STEP_M,
                "drawn": "shortest 8-connected paths over a 1 m raster of the open ground at least 1 m from every "
                "footprint, straightened where the line stays 0.5 m from them (every point and step at least 0.25 m clear), resampled at equal steps <= 2 m (simulate/routes.py)",
                "seconds_per_point": round((seconds["raytrace"] + seconds["direct"]) / len(sources), 3) if routes else None,
            },
            "raytrace": raytrace_record(rt_config),
            "receiver_antenna": f"isotropic ({SOLVER_TEXT[rt_config.solver]}); user antenna: vertical {rt_config.antenna}",
            "phase_deg": "not computed (the radio map is an incoherent power sum); written as 0 in the power outputs",
            "unreached_power_dbm": UNREACHED_POWER_DBM,
            "materials": materials,
            **({"building_materials": {str(b): m for b, m in sorted(materials_of.items())}} if len(mix) > 1 else {}),
            "packages": sionna_versions(),
            "cells": {
                "user_cells": int(gain.size),
                "hit_by_rays": int((reached & ~filled).sum()),
                "monte_carlo_gaps_filled": int(filled.sum()),
                "unreached": int((~reached).sum()),
                "capped_at_free_space": int(capped.sum()),
                "gap_fill": gap_fill_text(rt_config),
                "provenance": {
                    code_name(c): int(n) for c, n in enumerate(np.bincount(source.ravel(), minlength=len(CODES))) if n
                },
                **quality,
            },
            "unreached_cell_share": float(1 - reached.mean()),
            "gap_filled_cell_share": float(filled.mean()),
            "raytrace_seconds": round(seconds["raytrace"], 2),
            "direct_path_seconds": round(seconds["direct"], 2),
            "complete_missed": completion,
            "traces_from_cache": cached == "used",
            "trace_cache": cached,
            "wall_seconds": round(time.perf_counter() - t_start, 2),
        }
        (out / PROVENANCE).write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return Path(out_root) / spec.name, record

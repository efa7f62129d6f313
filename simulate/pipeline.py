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
import hashlib
import json
import math
import os
import tempfile
import time
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import shapely

from uavplace.infra.files import atomic_directory, check_name, check_replaceable
from uavplace.infra.limits import check_limit, limits, shown
from uavplace.infra.options import field_bounds
from uavplace.ingest.formats import GEOMETRY_TITLES, geometry_format
from uavplace.schemas import InputError
from uavplace.schemas.base import uavplace_version
from uavplace.schemas.provenance import CODES, ESTIMATED, EXACT_PATHS, UNREACHED, code_name
from uavplace.simulate.complete import complete_users, missed_cells
from uavplace.simulate.config import Simulation, SimulationSpec
from uavplace.simulate.fidelity import lattice_boundary_shares, lattice_step_ratios
from uavplace.simulate.insite import (
    UNREACHED_POWER_DBM,
    ReceiverGrid,
    write_city,
    write_p2m,
    write_provenance,
    write_setup,
    write_txrx,
)
from uavplace.simulate.procedural import PRESETS, USER_HEIGHT_M, generate_city, sample_users
from uavplace.simulate.raytrace import (
    SOLVERS,
    RadioMapJob,
    RayTraceConfig,
    check_fill,
    constant_patch_share,
    direct_gains_isolated,
    exact_path_maps,
    fill,
    free_space_cap,
    path_gain_maps_isolated,
    raytrace_record,
    sionna_versions,
)
from uavplace.simulate.routes import KINDS, MAX_STEP_M, ROUTE_SET, Route, draw_routes, write_routes_csv
from uavplace.simulate.scene import CONCRETE, GROUND_MARGIN_M, Block, write_scene
from uavplace.simulate.styles import STYLE_SIZE_M, STYLES, styled_city

USER_SET = (1, "User")
GRID_SET = (2, "Drone_grid")
#: Files of a simulated city beside the exports (ingest lists them as provenance and skips them).
PROVENANCE = "simulation.json"


#: Scenes shipped with Sionna RT that ``sionna:<name>`` names (any scene of ``sionna.rt.scene`` works).
SIONNA_SCENES = ("etoile", "florence", "munich", "san_francisco", "simple_street_canyon")


def _sionna_scene(name: str) -> Path:
    try:
        from sionna.rt import scene as scenes
    except ImportError:
        raise InputError(f"sionna:{name}", "Sionna RT is not installed: pip install -e '.[raytrace]'", field="source") from None
    path = getattr(scenes, name, None)
    if not isinstance(path, str) or not path.endswith(".xml"):
        raise InputError(f"sionna:{name}", f"Sionna RT ships no scene '{name}' (e.g. {', '.join(SIONNA_SCENES)})", field="source")
    return Path(path)


def _size(text: str, source: str) -> tuple[float, float]:
    try:
        w, h = (float(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(source, f"size '{text}': expected WIDTHxHEIGHT in metres, e.g. 400x500", field="source") from None
    if not (48 <= w <= 5000 and 48 <= h <= 5000):
        raise InputError(source, f"size {w:g} x {h:g} m: each side must be 48 to 5000 m", field="source")
    return (w, h)


def _bounded(value: float, option: str, field: str | None = None, limit: str | None = None) -> None:
    """``InputError`` naming ``option`` unless ``value`` is finite, within the bounds of ``Simulation``'s ``field`` and
    within the resource ``limit`` (by default the one the field names; without a field, from 0 up to the limit)."""
    info = Simulation.model_fields[field] if field is not None else None
    bounds = field_bounds(info) if info is not None else {}
    extra = (info.json_schema_extra or {}) if info is not None else {}
    limit = limit or extra.get("limit")
    lo, hi = bounds.get("min", 0), bounds.get("max")
    value = float(value)  # an integer option may be of any size (1e300 rays as an int)
    if not (math.isfinite(value) and lo <= value <= (math.inf if hi is None else hi)):
        upto = f"to {hi:g}" if hi is not None else f"up (and at most the limit {limit} = {shown(getattr(limits(), limit))})"
        raise InputError(option, f"{value!r} is out of range: {lo:g} {upto}", field=field or limit)
    if limit is not None:
        check_limit(limit, value, option, "value", field=field or limit)


def check_simulation(spec: SimulationSpec, config: RayTraceConfig, count: int = 1) -> None:
    """``InputError`` naming the option unless every setting of the call is finite, within the bounds of
    ``Simulation``'s fields and the resource limits (also the box of ``--extent``/``--crop`` and the ``--user`` positions), before any geometry is loaded or any
    memory allocated."""
    _bounded(count, "--count", "count")
    _bounded(len(spec.users_m) or spec.num_users, "--users", "num_users")
    _bounded(spec.grid_m, "--grid", "grid_m")
    _bounded(spec.altitude_m, "--alt", "altitude_m")
    _bounded(spec.tx_dbm, "--tx-dbm", "tx_dbm")
    _bounded(config.frequency_hz, "--freq", "frequency_hz")
    _bounded(config.samples_per_tx, "--samples", "samples")
    _bounded(config.max_depth, "--depth", "depth")
    if config.solver not in SOLVERS:
        raise InputError("--solver", f"{config.solver!r}: expected one of {', '.join(SOLVERS)}", field="solver")
    if config.complete_missed_samples:
        _bounded(config.complete_missed_samples, "--complete-samples", "complete_samples")
        if config.solver == "paths":
            raise InputError(
                "--complete-missed",
                "--solver paths traces exact paths at every cell already: nothing is missed",
                field="complete_missed",
            )
    if spec.surround_m and spec.crop_m is None:
        raise InputError("--surround", "traces the buildings around a --crop: give --crop too", field="surround")
    for option, box in (("--extent", spec.extent_m), ("--crop", spec.crop_m)):
        if box is None:
            continue
        if not all(np.isfinite(box)) or box[2] <= box[0] or box[3] <= box[1]:
            raise InputError(option, f"{box}: expected finite XMIN,YMIN,XMAX,YMAX with XMIN < XMAX and YMIN < YMAX", field="box")
        _bounded(max(box[2] - box[0], box[3] - box[1]), option, limit="extent_m")
        cells = ((box[2] - box[0]) // spec.grid_m) * ((box[3] - box[1]) // spec.grid_m)
        check_limit("grid_cells", cells, option, "cells of the receiver grid (the extent over the grid squared)", field="grid_m")
        _bounded(cells * (len(spec.users_m) or spec.num_users), f"{option} with --grid and --users", limit="user_cells")
    if spec.surround_m and spec.crop_m is not None and all(np.isfinite(spec.crop_m)):
        x0, y0, x1, y1 = surrounded(spec.crop_m, spec.surround_m)
        _bounded(max(x1 - x0, y1 - y0), "--crop with --surround (the traced box)", limit="extent_m")
    for k, (x, y) in enumerate(spec.users_m):
        if not (np.isfinite(x) and np.isfinite(y)):
            raise InputError("--user", f"user {k + 1} at ({x}, {y}): coordinates must be finite", field="user")
    _bounded(spec.routes, "--routes", "routes")
    if spec.routes:
        _bounded(spec.route_length_m, "--route-length", "route_length_m")
        _bounded(route_point_count(spec), "--routes with --route-length (their points)", limit="simulated_route_points")
        unknown = [k for k in spec.route_kinds if k not in KINDS]
        if unknown or not spec.route_kinds:
            raise InputError(
                "--route-kinds", f"{unknown or 'none'}: expected kinds among {', '.join(KINDS)}", field="route_kinds"
            )


def surrounded(box: tuple[float, float, float, float], margin_m: float) -> tuple[float, float, float, float]:
    """``box`` (XMIN, YMIN, XMAX, YMAX) grown by ``margin_m`` on every side: the buildings ``--surround`` traces."""
    return (box[0] - margin_m, box[1] - margin_m, box[2] + margin_m, box[3] + margin_m)


def route_point_count(spec: SimulationSpec) -> int:
    """The route points ``spec`` asks for (each route resampled at steps of at most ``MAX_STEP_M``)."""
    return spec.routes * (math.ceil(spec.route_length_m / MAX_STEP_M) + 1)


def load_geometry(
    source: str, seed: int, crop: tuple[float, float, float, float] | None = None
) -> tuple[list[Block], tuple[float, float, float, float], str]:
    """(building parts, city bounds, description) of a source; ``crop`` keeps the buildings in that box (clipped).

    Sources: ``procedural:<preset>`` (train, test, tiny, open: the original generator),
    ``procedural:<style>[:WxH]`` (generator v2, ``simulate.styles``: grid, rotated,
    perimeter, towers, organic, plazas, oldtown, or mixed: the first six styles in turn by seed); an InSite ``.city``; a GeoJSON file; a Mitsuba
    ``.xml`` scene with its PLY/OBJ meshes, or ``sionna:<scene>`` for one that Sionna
    RT ships (``sionna:etoile``, ``sionna:florence``): buildings per connected body, the
    ground left out, roofs split into height tiers (``ingest.mitsuba``).
    """
    if source.startswith("procedural"):
        if crop is not None:
            raise InputError(source, "--crop applies to real geometry; a procedural city takes --extent", field="crop")
        preset, _, size_text = (source.partition(":")[2] or "train").partition(":")
        if preset in STYLES or preset == "mixed":
            size = _size(size_text, source) if size_text else STYLE_SIZE_M
            used, parts = styled_city(preset, size, seed)
            blocks = [Block(f, 0.0, h, k) for f, h, k in parts]
            return blocks, (0.0, 0.0, *size), f"procedural style {used} ({size[0]:g} x {size[1]:g} m), seed {seed}"
        if preset not in PRESETS:
            known = ", ".join([*PRESETS, *sorted(STYLES), "mixed"])
            raise InputError(source, f"unknown procedural preset or style '{preset}' (known: {known})", field="source")
        size = PRESETS[preset]
        city = generate_city(size, 0, seed)
        blocks = (
            []
            if preset == "open"
            else [Block(f, 0.0, h, k) for k, (f, h) in enumerate(zip(city.footprints, city.heights_m, strict=True))]
        )
        return blocks, (0.0, 0.0, *size), f"procedural preset {preset} ({size[0]:g} x {size[1]:g} m), seed {seed}"
    path = _sionna_scene(source.partition(":")[2]) if source.startswith("sionna:") else Path(source)
    if not path.is_file():
        raise InputError(
            path,
            f"no such file: expected procedural[:preset], sionna:<scene> or a file of {GEOMETRY_TITLES}",
            field="source",
        )
    fmt = geometry_format(path)
    got = fmt.read(path, str(path), crop)
    records, rejected, cropped, heights = got.records, got.rejected, got.cropped, got.heights
    left_out = sum(r.count for r in rejected)
    if crop is not None and not fmt.crops:
        from uavplace.ingest.buildings import crop_records

        records, cropped = crop_records(records, crop)
    blocks = []
    for k, rec in enumerate(records):
        base = min(p.base_z_m for p in rec.parts) if rec.parts else 0.0
        for p in rec.parts:
            if not p.footprint.is_valid or p.footprint.area <= 0:
                raise InputError(
                    rec.source, f"footprint is not a valid polygon: {shapely.is_valid_reason(p.footprint)}", field="footprint"
                )
            for poly in shapely.get_parts(p.footprint):
                blocks.append(Block(poly, p.base_z_m - base, p.roof_z_m - base, k))
    if not blocks:
        raise InputError(path, "no building in the geometry" + (" inside --crop" if crop else ""), field="geometry")
    b = crop if crop is not None else tuple(shapely.total_bounds([blk.footprint for blk in blocks]))
    if max(b[2] - b[0], b[3] - b[1]) > limits().extent_m:
        raise InputError(
            path,
            f"the geometry spans {b[2] - b[0]:.0f} x {b[3] - b[1]:.0f} m, more than "
            f"the limit extent_m = {limits().extent_m:g} m a side: give --crop, or raise it with "
            "`--limit extent_m=VALUE`",
            field="geometry",
        )
    tiers = len(blocks)
    described = f"{source if source.startswith('sionna:') else path.name}: {len(records)} buildings in {tiers} roof tiers"
    if left_out:
        described += f", {left_out} feature(s) left out ({rejected[0].field}: {rejected[0].reason}, ...)"
    if heights:
        described += f"; heights: {heights}"
    if crop is not None:
        described += f", cropped to x {crop[0]:g}..{crop[2]:g}, y {crop[1]:g}..{crop[3]:g} m ({cropped} buildings outside)"
    return blocks, (float(b[0]), float(b[1]), float(b[2]), float(b[3])), described


#: What simulation.json says of the solver that traced a city.
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
    _bounded(nx * ny * (len(spec.users_m) or spec.num_users), "--grid with --users (the city's size)", limit="user_cells")
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


def direct_maps(job: RadioMapJob, config: RayTraceConfig, on_batch: Callable[[int, int], None] | None = None) -> dict:
    """What ``fill``'s ``geodesic`` method adds to the radio maps of ``job``: the exact straight paths through the
    buildings' walls (``raytrace.direct_gains``, in a child process), ``{"direct": [U, ny, nx], "crossings": ...}``."""
    return direct_gains_isolated(job, config, CONCRETE.at(config.frequency_hz), on_batch=on_batch)


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


#: Settings that only change how the traced maps are filled or completed: a trace cache entry serves any of their values.
FILL_ONLY = ("gap_fill_reach_m", "gap_fill_decay_db_per_m", "gap_fill_walk", "complete_missed_samples")


def trace_key(spec: SimulationSpec, config: RayTraceConfig) -> str:
    """What a city's traced maps depend on: its spec and the ray-trace settings, less ``FILL_ONLY``."""
    settings = {k: v for k, v in raytrace_record(config).items() if k not in FILL_ONLY}
    return json.dumps({"spec": spec_record(spec), "raytrace": settings, "uavplace": uavplace_version()}, sort_keys=True)


def spec_record(spec: SimulationSpec) -> dict:
    """``spec`` as simulation.json records it: without the route settings when it has no routes (as before routes)."""
    doc = asdict(spec)
    if not spec.surround_m:  # as before --surround: a crop's buildings only
        del doc["surround_m"]
    return doc if spec.routes else {k: v for k, v in doc.items() if not k.startswith("route")}


def _entry_digest(key: str, arrays: dict[str, np.ndarray]) -> str:
    """The sha256 a trace cache entry carries: of its key (what made it) and of every array's name, type, shape and
    bytes."""
    h = hashlib.sha256(key.encode("utf-8"))
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def read_cache_entry(path: Path, key: str, max_bytes: float | None = None) -> tuple[dict[str, np.ndarray] | None, str]:
    """A trace cache entry's arrays, or None and why it is not used: not a regular file, not a readable archive, an
    array over the limits or of objects, arrays that together hold more than ``max_bytes`` (what the simulation can
    make: read from the headers before anything is decompressed), another key (other settings), or arrays that do
    not match the sha256 the entry carries (damaged or altered). Never raises on a damaged entry."""
    bound = limits().array_bytes
    total = 0
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                with archive.open(info) as member:
                    version = np.lib.format.read_magic(member)
                    read_header = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
                    if version not in read_header:
                        return None, f"{info.filename}: .npy format {version}"
                    shape, _, dtype = read_header[version](member)  # the header only, before anything is decompressed
                size = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
                if dtype.hasobject or size > bound:
                    return None, f"{info.filename}: {dtype} {shape} is over the limit array_bytes or not numbers"
                total += size
                if max_bytes is not None and total > max_bytes:
                    return None, f"its arrays hold over {max_bytes:,.0f} bytes, more than this simulation makes"
        with np.load(path, allow_pickle=False) as z:
            if "key" not in z.files or str(z["key"]) != key:
                return None, "made with other settings"
            arrays = {k: z[k] for k in z.files if k not in ("key", "sha256")}
            carried = str(z["sha256"]) if "sha256" in z.files else ""
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError, zlib.error) as exc:
        return None, f"unreadable ({type(exc).__name__}: {str(exc)[:120]})"
    if carried != _entry_digest(key, arrays):
        return None, "its arrays do not match the sha256 it carries (damaged or altered)"
    return arrays, "used"


def _cached_traces(cache: Path | None, name: str, key: str, trace, max_bytes: float | None = None) -> tuple[dict, str]:  # noqa: ANN001
    """``trace()``'s maps, or those kept in ``cache/<name>.npz`` under the same key (``trace_key``; arrays only, no
    pickle, checked by ``read_cache_entry``, at most ``max_bytes`` in all); (maps, what became of the entry: ``used``,
    ``none``, or why it was traced again). A new trace is kept there with its sha256, written atomically."""
    path = None if cache is None else Path(cache) / f"{name}.npz"
    status = "none"
    if path is not None and (path.is_symlink() or (path.exists() and not path.is_file())):  # before minutes of tracing
        raise InputError(path, "exists and is not a regular file: not a trace cache entry; move it away", field="trace_cache")
    if path is not None and path.exists():
        arrays, status = read_cache_entry(path, key, max_bytes)
        if arrays is not None:
            return {(int(k[1:]) if k[0] == "f" and k[1:].isdigit() else k): v for k, v in arrays.items()}, status
        status = f"traced again: the entry was {status}" if status.startswith("made") else f"traced again: {status}"
    maps = trace()
    if path is not None:
        write_cache_entry(path, key, {(f"f{k}" if isinstance(k, int) else k): v for k, v in maps.items()})
    return maps, status


def write_cache_entry(path: Path, key: str, arrays: dict[str, np.ndarray]) -> None:
    """A trace cache entry: ``arrays`` with the ``key`` that made them and their sha256, written atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, key=np.array(key), sha256=np.array(_entry_digest(key, arrays)), **arrays)
    os.replace(tmp, path)


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
        xml, materials = write_scene(tmp, traced, box, rt_config.frequency_hz, ground_margin_m=margin)
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
                maps |= direct_maps(job, rt_config, on_batch=lambda d, n: progress("direct paths", d, n))
                seconds["direct"] = time.perf_counter() - t
            return maps

        # What a trace of this city holds at most: a fine, a direct and each coarse map of float64 per source and cell,
        # with room for the arrays beside them: an entry that inflates beyond it is not read.
        most = 8.0 * len(sources) * grid.num_x * grid.num_y * (4 + 2 * len(rt_config.gap_fill_factors)) + 2**20
        maps, cached = _cached_traces(
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

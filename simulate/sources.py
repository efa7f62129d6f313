"""The city source of ``uavdata simulate`` and its checks before any work: Sionna RT's scenes (``sionna:<name>``),
the procedural styles, geometry files read through ingest's reader table (``load_geometry``), and the bounds of a
simulation's grid, users and routes (``check_simulation``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import shapely

from uavplace.infra.limits import check_limit, limits, shown
from uavplace.infra.options import field_bounds
from uavplace.ingest.formats import GEOMETRY_TITLES, geometry_format
from uavplace.schemas import InputError
from uavplace.simulate.config import Simulation, SimulationSpec
from uavplace.simulate.procedural import PRESETS, generate_city
from uavplace.simulate.raytrace import (
    SOLVERS,
    RayTraceConfig,
)
from uavplace.simulate.routes import KINDS, MAX_STEP_M
from uavplace.simulate.scene import Block
from uavplace.simulate.styles import STYLE_SIZE_M, STYLES, styled_city

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


def check_bounded(value: float, option: str, field: str | None = None, limit: str | None = None) -> None:
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
    check_bounded(count, "--count", "count")
    check_bounded(len(spec.users_m) or spec.num_users, "--users", "num_users")
    check_bounded(spec.grid_m, "--grid", "grid_m")
    check_bounded(spec.altitude_m, "--alt", "altitude_m")
    check_bounded(spec.tx_dbm, "--tx-dbm", "tx_dbm")
    check_bounded(config.frequency_hz, "--freq", "frequency_hz")
    check_bounded(config.samples_per_tx, "--samples", "samples")
    check_bounded(config.max_depth, "--depth", "depth")
    if config.solver not in SOLVERS:
        raise InputError("--solver", f"{config.solver!r}: expected one of {', '.join(SOLVERS)}", field="solver")
    if config.complete_missed_samples:
        check_bounded(config.complete_missed_samples, "--complete-samples", "complete_samples")
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
        check_bounded(max(box[2] - box[0], box[3] - box[1]), option, limit="extent_m")
        cells = ((box[2] - box[0]) // spec.grid_m) * ((box[3] - box[1]) // spec.grid_m)
        check_limit("grid_cells", cells, option, "cells of the receiver grid (the extent over the grid squared)", field="grid_m")
        check_bounded(cells * (len(spec.users_m) or spec.num_users), f"{option} with --grid and --users", limit="user_cells")
    if spec.surround_m and spec.crop_m is not None and all(np.isfinite(spec.crop_m)):
        x0, y0, x1, y1 = surrounded(spec.crop_m, spec.surround_m)
        check_bounded(max(x1 - x0, y1 - y0), "--crop with --surround (the traced box)", limit="extent_m")
    for k, (x, y) in enumerate(spec.users_m):
        if not (np.isfinite(x) and np.isfinite(y)):
            raise InputError("--user", f"user {k + 1} at ({x}, {y}): coordinates must be finite", field="user")
    check_bounded(spec.routes, "--routes", "routes")
    if spec.routes:
        check_bounded(spec.route_length_m, "--route-length", "route_length_m")
        check_bounded(route_point_count(spec), "--routes with --route-length (their points)", limit="simulated_route_points")
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

"""CityJSON buildings (versions 0.2 to 2.0, LoD1 and LoD2) as format-neutral buildings (``ingest.buildings``).

A CityJSON file holds ``CityObjects`` (a ``Building``, its ``BuildingPart``s, terrain, ...) whose geometries index one
shared ``vertices`` list; from version 0.8 on the vertices may be integers under a ``transform`` (``real = v *
scale + translate``). Each ``Building`` or ``BuildingPart`` with a geometry becomes a building record (of the
highest LoD it carries); other objects are counted and left out (``Rejection``), as are buildings without a
surface seen from above.

How a building's heights are taken (``HEIGHT_METHOD``, said in what ``read_cityjson`` returns):

- its **ground**: the attribute ``TerrainHeight`` [m] where the object has one (Rotterdam's 3D model), else the
  lowest vertex of its geometry (the foot of its walls);
- its **roof tiers**: every surface that is not vertical (its outline seen from above covers more than
  ``MIN_ROOF_M2``) and is a roof: semantics ``RoofSurface`` where the file says, else any non-vertical surface but
  the lowest (the ground surface, within ``GROUND_TOLERANCE_M`` of the ground). Each is a tier over its outline at
  the **mean height of its vertices** (a pitched roof at its middle, neither eaves nor ridge); where tiers overlap
  seen from above, the higher wins.

Coordinates stay as the file gives them (metres of its reference system, e.g. EPSG:7415 or 28992); the caller crops.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import shapely

from uavplace.infra.files import regular_file_bytes
from uavplace.infra.limits import check_limit
from uavplace.ingest.buildings import BuildingRecord, Part
from uavplace.schemas import InputError, Rejection

#: The object types that are buildings.
BUILDING_TYPES = ("Building", "BuildingPart")
#: A surface seen from above smaller than this [m^2] is a wall, not a roof.
MIN_ROOF_M2 = 0.5
#: Surfaces within this of a building's ground [m] are its ground surface, never a roof.
GROUND_TOLERANCE_M = 0.5
#: How each building's heights are taken, as ``simulation.json`` records it.
HEIGHT_METHOD = (
    "CityJSON: ground at the attribute TerrainHeight where the building has one, else its lowest vertex; each roof "
    "surface (semantics RoofSurface, else every non-vertical surface above the ground) a tier over its outline at "
    "the mean height of its vertices, the higher tier where two overlap"
)


def is_cityjson(doc: object) -> bool:
    """Whether a parsed JSON document is CityJSON (``type`` CityJSON, or the 0.2 form's CityModel with CityObjects)."""
    return isinstance(doc, dict) and doc.get("type") in ("CityJSON", "CityModel") and isinstance(doc.get("CityObjects"), dict)


def load_json(path: Path, name: str) -> object:
    """The parsed JSON document; ``InputError`` for text that is not UTF-8 JSON."""
    raw = regular_file_bytes(path, name, "text_bytes")
    try:
        return json.loads(raw.decode("utf-8-sig"))
    except UnicodeDecodeError as exc:
        raise InputError(name, f"not UTF-8 text (byte at offset {exc.start})", field="encoding") from None
    except json.JSONDecodeError as exc:
        raise InputError(name, f"invalid JSON: {exc.msg}", line=exc.lineno, field=f"column {exc.colno}") from None
    except RecursionError:
        raise InputError(name, "JSON nested too deeply", field="json") from None


def vertices_of(doc: dict, name: str) -> np.ndarray:
    """``[N, 3]`` float64 real coordinates [m]: the ``vertices`` under the ``transform`` when there is one."""
    try:
        v = np.asarray(doc.get("vertices", []), np.float64).reshape(-1, 3)
    except (TypeError, ValueError):
        raise InputError(name, "vertices are not [x, y, z] numbers", field="vertices") from None
    transform = doc.get("transform")
    if transform is not None:
        try:
            v = v * np.asarray(transform["scale"], np.float64) + np.asarray(transform["translate"], np.float64)
        except (KeyError, TypeError, ValueError):
            raise InputError(name, "transform needs scale and translate, 3 numbers each", field="transform") from None
    if not np.isfinite(v).all():
        raise InputError(name, "a vertex is not finite", field="vertices")
    return v


def _surfaces(geometry: dict) -> list[tuple[list, str | None]]:
    """``[(rings, semantic type or None), ...]`` of a geometry: every surface of a MultiSurface, CompositeSurface,
    Solid, MultiSolid or CompositeSolid, with its semantic surface type in either form (0.2's list, or ``surfaces`` and
    nested ``values``)."""
    kind, boundaries = geometry.get("type"), geometry.get("boundaries", [])
    depth = {"MultiSurface": 0, "CompositeSurface": 0, "Solid": 1, "MultiSolid": 2, "CompositeSolid": 2}.get(kind)
    if depth is None:
        return []
    semantics = geometry.get("semantics")

    def flatten(node: list, values: object, level: int) -> list[tuple[list, str | None]]:
        if level == 0:
            out = []
            for i, rings in enumerate(node):
                label = None
                if isinstance(semantics, list) and i < len(semantics) and isinstance(semantics[i], dict):
                    label = semantics[i].get("type")  # the 0.2 form: one semantic object per surface
                elif isinstance(values, list) and i < len(values) and isinstance(values[i], int):
                    surfaces = semantics.get("surfaces", []) if isinstance(semantics, dict) else []
                    label = surfaces[values[i]].get("type") if 0 <= values[i] < len(surfaces) else None
                out.append((rings, label))
            return out
        out = []
        for j, child in enumerate(node):
            sub = values[j] if isinstance(values, list) and j < len(values) else None
            out += flatten(child, sub, level - 1)
        return out

    values = semantics.get("values") if isinstance(semantics, dict) else None
    return flatten(boundaries, values, depth)


def _outline(rings: list, v: np.ndarray) -> tuple[shapely.Polygon | None, float, float]:
    """(the surface's outline seen from above, or None for a wall; the mean and the lowest z of its vertices)."""
    indices = [np.asarray(r, np.int64) for r in rings if len(r) >= 3]
    if any((i < 0).any() for i in indices):
        raise IndexError("a negative vertex index")
    points = [v[i] for i in indices]
    if not points:
        return None, math.nan, math.nan
    z = np.concatenate([p[:, 2] for p in points])
    poly = shapely.Polygon(points[0][:, :2], [p[:, :2] for p in points[1:]])
    if not poly.is_valid:
        poly = shapely.make_valid(poly)
    if poly.area < MIN_ROOF_M2:
        return None, float(z.mean()), float(z.min())
    return poly, float(z.mean()), float(z.min())


def _record(key: str, obj: dict, v: np.ndarray, name: str) -> tuple[BuildingRecord | None, str]:
    """A building's record (None when no roof is seen from above) and how its ground was taken."""
    geometries = [g for g in obj.get("geometry") or [] if isinstance(g, dict)]
    lods = [float(g.get("lod", 0) or 0) for g in geometries]
    top = max(lods)
    surfaces = [s for g, lod in zip(geometries, lods, strict=True) if lod == top for s in _surfaces(g)]
    try:
        outlines = [(*_outline(rings, v), label) for rings, label in surfaces]
    except (IndexError, TypeError, ValueError):
        raise InputError(name, f"{key}: a surface indexes no vertex", field=f"CityObjects.{key}.geometry") from None
    if not outlines:
        return None, "no surface"
    attrs = obj.get("attributes") or {}
    terrain = attrs.get("TerrainHeight")
    try:
        ground = float(terrain) if terrain is not None else min(low for _, _, low, _ in outlines)
        taken = "TerrainHeight" if terrain is not None else "lowest vertex"
    except (TypeError, ValueError):
        raise InputError(name, f"{key}: TerrainHeight {terrain!r} is not a number", field=f"CityObjects.{key}") from None
    labelled = any(label == "RoofSurface" for *_, label in outlines)
    roofs = [
        (poly, mean)
        for poly, mean, low, label in outlines
        if poly is not None and (label == "RoofSurface" if labelled else low > ground + GROUND_TOLERANCE_M)
    ]
    roofs = [(p, z) for p, z in roofs if z > ground]
    if not roofs:
        return None, taken
    parts, covered = [], shapely.Polygon()
    for poly, z in sorted(roofs, key=lambda r: -r[1]):  # the higher tier wins where two overlap
        rest = shapely.difference(poly, covered)
        if rest.area >= MIN_ROOF_M2:
            parts.append(Part(footprint=rest, base_z_m=ground, roof_z_m=z))
            covered = shapely.union(covered, poly)
    return BuildingRecord(name=key[:200], source_file=f"{name}#CityObjects.{key}", source_line=None, parts=parts), taken


def read_cityjson(
    path: str | Path, display: str | None = None, doc: object = None
) -> tuple[list[BuildingRecord], list[Rejection], str]:
    """(buildings, what was left out and why, how the heights were taken: ``HEIGHT_METHOD`` with each ground's
    count) of a CityJSON file (``doc``: its parsed JSON, when the caller read it already); ``InputError`` naming the
    file and the field for what is not CityJSON."""
    name = display or str(path)
    doc = load_json(Path(path), name) if doc is None else doc
    if not is_cityjson(doc):
        raise InputError(name, "not CityJSON (no type CityJSON with CityObjects)", field="type")
    check_limit("buildings", len(doc["CityObjects"]), name, "CityObjects of the CityJSON (before any is processed)")
    v = vertices_of(doc, name)
    records, rejected, grounds = [], [], {"TerrainHeight": 0, "lowest vertex": 0}
    for key, obj in doc["CityObjects"].items():
        if not isinstance(obj, dict):
            raise InputError(name, f"{key} is a JSON {type(obj).__name__}, not an object", field=f"CityObjects.{key}")
        if obj.get("type") not in BUILDING_TYPES:
            rejected.append(Rejection(file=name, field=f"CityObjects.{key}", reason=f"{obj.get('type')} is not a building"))
            continue
        if not obj.get("geometry"):
            continue  # a Building whose parts carry its geometry
        record, taken = _record(str(key), obj, v, name)
        if record is None:
            rejected.append(Rejection(file=name, field=f"CityObjects.{key}", reason=f"no roof seen from above ({taken})"))
            continue
        grounds[taken] += 1
        records.append(record)
    counts = ", ".join(f"{n} by {k}" for k, n in grounds.items() if n)
    return records, rejected, f"{HEIGHT_METHOD} (grounds: {counts or 'none'})"

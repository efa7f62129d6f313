"""Geometry files (.city buildings, .ter terrain) of Wireless InSite.

``begin_<structure_group>`` > ``begin_<structure>`` (a building) >
``begin_<sub_structure>`` (a part, e.g. one tier) > ``begin_<face>`` with
``nVertices K`` and K vertex lines ``x y z`` [m]. Buildings carry no footprint
or height field: a part's footprint is the union of its non-vertical faces
seen from above (roof, floor) or, failing those, the polygons its walls
enclose; its base and roof are the min and max vertex z.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import shapely

from uavplace.infra.limits import check_limit
from uavplace.ingest.buildings import BuildingRecord, Part
from uavplace.ingest.wireless_insite.keyword import N_VERTICES, Block, parse_keyword_file
from uavplace.schemas import InputError


def _faces(block: Block) -> list[tuple[int, np.ndarray]]:
    """Every face below ``block``: (line of its vertex count, vertices [K, 3] in metres)."""
    faces = []
    for face in block.walk("face"):
        v = face.vertices()
        found = face.find_entry(N_VERTICES)
        line = found[0] if found else face.line
        if len(v) < 3:
            raise InputError(face.path, f"face has {len(v)} vertices, a face needs at least 3", line=line, field=N_VERTICES)
        faces.append((line, v))
    return faces


def _is_vertical(face: np.ndarray) -> bool:
    """True for a face whose vertices, seen from above, lie on one line (a wall): no area in any ordering."""
    xy = face[:, :2] - face[:, :2].mean(axis=0)
    s = np.linalg.svd(xy, compute_uv=False)
    return bool(s[-1] <= 1e-6 * max(s[0], 1.0))


def _part(path: str, faces: list[tuple[int, np.ndarray]]) -> Part:
    flat = []
    for line, f in faces:
        if _is_vertical(f):
            continue  # a wall, seen from above
        poly = shapely.Polygon(f[:, :2])
        if not poly.is_valid:  # a roof or floor that crosses itself: the same polygon in GeoJSON is refused too
            raise InputError(
                path, f"face is not a simple polygon seen from above ({shapely.is_valid_reason(poly)})", line=line, field="face"
            )
        flat.append(poly)
    if flat:
        footprint = shapely.union_all(flat)
    else:
        edges = [shapely.LineString(np.vstack([f[:, :2], f[:1, :2]])) for _, f in faces]
        noded = shapely.union_all(edges)  # split the walls' base lines where they meet
        footprint = shapely.union_all(list(shapely.get_parts(shapely.polygonize([noded]))))
    z = np.concatenate([f[:, 2] for _, f in faces])
    return Part(footprint=footprint, base_z_m=float(z.min()), roof_z_m=float(z.max()))


def read_city(path: str | Path, display: str | None = None) -> list[BuildingRecord]:
    """Buildings of an InSite .city file, one per ``structure``, in file order."""
    name = display or str(path)
    root = parse_keyword_file(path, name)
    structures = list(root.walk("structure"))
    check_limit("buildings", len(structures), name, "structures of the .city (before any is processed)")
    records = []
    for structure in structures:
        subs = structure.blocks("sub_structure") or [structure]
        parts = []
        for sub in subs:
            faces = _faces(sub)
            if faces:
                parts.append(_part(name, faces))
        records.append(BuildingRecord(name=structure.name or None, source_file=name, source_line=structure.line, parts=parts))
    return records


def read_terrain(path: str | Path, display: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Terrain mesh of a .ter file: vertices [V, 3] (float64, m) and triangles [F, 3] (int64).

    Faces with more than 3 vertices are split into a triangle fan.
    """
    name = display or str(path)
    root = parse_keyword_file(path, name)
    faces = [f for _, f in _faces(root)]
    if not faces:
        raise InputError(name, "terrain has no faces", field="face")
    vertices = np.vstack(faces)
    tris = []
    start = 0
    for f in faces:
        k = len(f)
        idx = np.arange(1, k - 1)
        tris.append(np.column_stack([np.full(k - 2, start), start + idx, start + idx + 1]))
        start += k
    triangles = np.vstack(tris)
    unique, inverse = np.unique(np.round(vertices, 6), axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[triangles]

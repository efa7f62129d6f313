"""Building meshes (OBJ, PLY, STL, GLB/GLTF) through trimesh.

The mesh is z-up in the local metric frame. Each connected body is a
building: footprint = union of its triangles seen from above, base and roof =
its min and max z. Flat bodies (z extent below ``FLAT_M``, e.g. a ground
plane) are rejected and counted, not taken as buildings.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import shapely

from uavplace.ingest.buildings import MIN_AREA_M2, BuildingRecord, Part
from uavplace.schemas import InputError, Rejection

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")
#: Bodies thinner than this [m] are ground or road surfaces, not buildings.
FLAT_M = 0.5


def _footprint(body) -> shapely.Geometry:  # noqa: ANN001 - a trimesh.Trimesh
    tri = body.triangles[:, :, :2]
    polys = shapely.polygons(tri)
    polys = polys[shapely.area(polys) > MIN_AREA_M2]
    return shapely.union_all(polys)


def read_mesh(path: str | Path, display: str | None = None) -> tuple[list[BuildingRecord], list[Rejection]]:
    import trimesh  # heavy (about 50 MB): only for cities that ship meshes

    name = display or str(path)
    try:
        loaded = trimesh.load(str(path), force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types on malformed files
        raise InputError(name, f"unreadable mesh ({type(exc).__name__}: {exc})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputError(name, "mesh has no faces", field="faces")
    if not np.isfinite(loaded.vertices).all():
        raise InputError(name, "mesh has non-finite vertices", field="vertices")
    records, rejected = [], []
    for i, body in enumerate(loaded.split(only_watertight=False)):
        zmin, zmax = float(body.vertices[:, 2].min()), float(body.vertices[:, 2].max())
        if zmax - zmin < FLAT_M:
            rejected.append(
                Rejection(file=name, field=f"body[{i}]", reason=f"flat body ({zmax - zmin:.2f} m tall): ground, not a building")
            )
            continue
        records.append(
            BuildingRecord(
                name=f"body{i}",
                source_file=f"{name}#body[{i}]",
                source_line=None,
                parts=[Part(footprint=_footprint(body), base_z_m=zmin, roof_z_m=zmax)],
            )
        )
    return records, rejected

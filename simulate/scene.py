"""Mitsuba/Sionna scene folders from building footprints: extruded meshes (PLY), a ground plane, radio materials.

ITU-R P.2040 gives concrete and the grounds only from 1 GHz, and Sionna's ITU
table refuses them below that, so the scene carries explicit radio materials:
P.2040's formulas (eps_r = a f^b, sigma = c f^d, f in GHz) evaluated at the
carrier frequency, under ids that do not start with an ITU name. The mapping
is recorded in ``simulation.json``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
import trimesh


@dataclass(frozen=True)
class Material:
    """An ITU-R P.2040 material law: eps_r = a * f^b, sigma = c * f^d [S/m], f in GHz."""

    id: str
    itu_name: str
    a: float
    b: float
    c: float
    d: float
    thickness_m: float

    def at(self, frequency_hz: float) -> dict[str, float | str]:
        f = frequency_hz / 1e9
        return {
            "id": self.id,
            "itu_name": self.itu_name,
            "relative_permittivity": round(self.a * f**self.b, 4),
            "conductivity_s_m": round(self.c * f**self.d, 5),
            "thickness_m": self.thickness_m,
            "law": f"P.2040: eps_r = {self.a} f^{self.b}, sigma = {self.c} f^{self.d} (f in GHz), evaluated at {f:g} GHz",
        }


#: Building walls and roofs, and the ground (ITU-R P.2040 table 3).
CONCRETE = Material("uav-concrete", "concrete", a=5.24, b=0.0, c=0.0462, d=0.7822, thickness_m=0.2)
GROUND = Material("uav-medium-dry-ground", "medium_dry_ground", a=15.0, b=-0.1, c=0.035, d=1.63, thickness_m=1.0)


@dataclass(frozen=True)
class Block:
    """A building part to extrude: footprint, base and roof z [m], and the building it belongs to."""

    footprint: shapely.Polygon
    base_z_m: float
    roof_z_m: float
    building: int = 0


def extrude(footprint: shapely.Polygon, base_z: float, roof_z: float) -> trimesh.Trimesh:
    """A closed prism: roof and floor from a constrained Delaunay triangulation, one quad per ring edge."""
    poly = shapely.orient_polygons(footprint)  # exterior counter-clockwise, holes clockwise
    tris = np.array([np.asarray(t.exterior.coords)[:3] for t in shapely.get_parts(shapely.constrained_delaunay_triangles(poly))])
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    ccw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0
    tris[~ccw] = tris[~ccw][:, ::-1]
    n = len(tris)
    verts = [np.c_[tris.reshape(-1, 2), np.full(3 * n, roof_z)], np.c_[tris.reshape(-1, 2), np.full(3 * n, base_z)]]
    faces = [np.arange(3 * n).reshape(n, 3), 3 * n + np.arange(3 * n).reshape(n, 3)[:, ::-1]]
    start = 6 * n
    for ring in [poly.exterior, *poly.interiors]:
        xy = np.asarray(ring.coords)[:-1, :2]
        a, b = xy, np.roll(xy, -1, axis=0)
        k = len(xy)
        quad = np.stack(
            [
                np.c_[a, np.full(k, base_z)],
                np.c_[b, np.full(k, base_z)],
                np.c_[b, np.full(k, roof_z)],
                np.c_[a, np.full(k, roof_z)],
            ],
            1,
        )
        verts.append(quad.reshape(-1, 3))
        idx = start + 4 * np.arange(k)[:, None]
        faces.append(np.vstack([np.c_[idx, idx + 1, idx + 2], np.c_[idx, idx + 2, idx + 3]]))
        start += 4 * k
    return trimesh.Trimesh(vertices=np.vstack(verts), faces=np.vstack(faces), process=True)


#: How far the ground reaches beyond the traced buildings' box [m].
GROUND_MARGIN_M = 50.0


def write_scene(
    folder: str | Path,
    blocks: Sequence[Block],
    bounds_m: tuple[float, float, float, float],
    frequency_hz: float,
    *,
    ground_margin_m: float = GROUND_MARGIN_M,
) -> tuple[Path, list[dict[str, float | str]]]:
    """Write ``scene.xml`` and ``meshes/*.ply`` into ``folder``; returns (xml path, materials used).

    All buildings go into one mesh (one shape is faster to trace than hundreds); the
    ground is a rectangle ``ground_margin_m`` larger than ``bounds_m`` on each side.
    """
    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    x0, y0, x1, y1 = bounds_m
    m = ground_margin_m
    ground = trimesh.Trimesh(
        vertices=[[x0 - m, y0 - m, 0], [x1 + m, y0 - m, 0], [x1 + m, y1 + m, 0], [x0 - m, y1 + m, 0]],
        faces=[[0, 1, 2], [0, 2, 3]],
    )
    ground.export(folder / "meshes" / "ground.ply")
    materials = [GROUND.at(frequency_hz)]
    shapes = [("ground", GROUND.id)]
    if blocks:
        trimesh.util.concatenate([extrude(b.footprint, b.base_z_m, b.roof_z_m) for b in blocks]).export(
            folder / "meshes" / "buildings.ply"
        )
        materials.append(CONCRETE.at(frequency_hz))
        shapes.append(("buildings", CONCRETE.id))
    xml = ['<scene version="2.1.0">']
    for mat in materials:
        xml += [
            f'  <bsdf type="radio-material" id="{mat["id"]}">',
            f'    <float name="relative_permittivity" value="{mat["relative_permittivity"]}"/>',
            f'    <float name="conductivity" value="{mat["conductivity_s_m"]}"/>',
            f'    <float name="thickness" value="{mat["thickness_m"]}"/>',
            "  </bsdf>",
        ]
    for name, mat_id in shapes:
        xml += [
            f'  <shape type="ply" id="{name}">',
            f'    <string name="filename" value="meshes/{name}.ply"/>',
            '    <boolean name="face_normals" value="true"/>',
            f'    <ref id="{mat_id}" name="bsdf"/>',
            "  </shape>",
        ]
    xml.append("</scene>")
    path = folder / "scene.xml"
    path.write_text("\n".join(xml) + "\n", encoding="utf-8")
    return path, materials

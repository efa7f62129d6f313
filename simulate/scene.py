"""Mitsuba/Sionna scene folders from building footprints: extruded meshes (PLY), a ground plane, radio materials.

ITU-R P.2040 gives concrete and the grounds only from 1 GHz, and Sionna's ITU
table refuses them below that, so the scene carries explicit radio materials:
P.2040's formulas (eps_r = a f^b, sigma = c f^d, f in GHz) evaluated at the
carrier frequency, under ids that do not start with an ITU name. The mapping
is recorded in ``simulation.json``.

Every building is concrete unless a mix is declared (``uavdata simulate --materials``):
then each building takes one of ``MATERIALS``' classes, in the declared shares of the
buildings, by the seed (``assign_materials``), and the scene holds one mesh per class.
P.2040's laws hold from 1 GHz for most classes (glass from 0.1, wood from 1 MHz);
below that they are extrapolated, as for concrete.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
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
#: The building classes of a material mix (ITU-R P.2040-4 table 3's laws; the thickness is a wall's, ours: a load-bearing
#: wall for concrete and brick, a glazed facade's panes, a steel cladding sheet, a timber wall, boards).
MATERIALS: dict[str, Material] = {
    m.itu_name: m
    for m in (
        CONCRETE,
        Material("uav-brick", "brick", a=3.91, b=0.0, c=0.0238, d=0.16, thickness_m=0.2),
        Material("uav-plasterboard", "plasterboard", a=2.73, b=0.0, c=0.0085, d=0.9395, thickness_m=0.025),
        Material("uav-wood", "wood", a=1.99, b=0.0, c=0.0047, d=1.0718, thickness_m=0.1),
        Material("uav-glass", "glass", a=6.31, b=0.0, c=0.0036, d=1.3394, thickness_m=0.02),
        Material("uav-ceiling-board", "ceiling_board", a=1.48, b=0.0, c=0.0011, d=1.075, thickness_m=0.02),
        Material("uav-chipboard", "chipboard", a=2.58, b=0.0, c=0.0217, d=0.78, thickness_m=0.02),
        Material("uav-metal", "metal", a=1.0, b=0.0, c=1e7, d=0.0, thickness_m=0.005),
    )
}
#: The mix of every city before ``--materials``: all concrete.
ALL_CONCRETE: tuple[tuple[str, float], ...] = (("concrete", 1.0),)
#: The random stream of the buildings' materials (``assign_materials``), apart from the users' and the rays'.
MATERIAL_STREAM = 2040
#: The shape of every building when they are all of one material (one mesh is faster to trace).
BUILDINGS = "buildings"


def parse_mix(items: Sequence[str]) -> tuple[tuple[str, float], ...]:
    """A material mix from its words: ``("concrete",)`` (every building) or ``("concrete=0.4", "brick=0.6", ...)``,
    shares of the buildings in (0, 1] that sum to 1; a ``ValueError`` names the word at fault."""
    if len(items) == 1 and "=" not in items[0]:
        items = (f"{items[0]}=1",)
    mix: dict[str, float] = {}
    for item in items:
        name, sep, share_text = item.partition("=")
        name = name.strip()
        if not sep:
            raise ValueError(f"{item!r}: expected CLASS=SHARE (e.g. concrete=0.4,brick=0.6) or one CLASS")
        if name not in MATERIALS:
            raise ValueError(f"{name!r} is not a material class (known: {', '.join(MATERIALS)})")
        if name in mix:
            raise ValueError(f"{name!r} is given twice")
        try:
            share = float(share_text)
        except ValueError:
            raise ValueError(f"{item!r}: the share {share_text!r} is not a number") from None
        if not 0.0 < share <= 1.0:
            raise ValueError(f"{item!r}: a share is in (0, 1]")
        mix[name] = share
    if not mix:
        raise ValueError("no material class given")
    if abs(sum(mix.values()) - 1.0) > 1e-6:
        raise ValueError(f"the shares sum to {sum(mix.values()):g}, not 1")
    return tuple(mix.items())


def assign_materials(buildings: Sequence[int], mix: Sequence[tuple[str, float]], seed: int) -> dict[int, str]:
    """Each building's material class: the buildings shuffled by ``seed`` and dealt out in ``mix``'s shares of their
    count (rounded by largest remainder, so that 40 / 30 / 20 / 10 % of 21 buildings are 9, 6, 4 and 2)."""
    ids = sorted(set(buildings))
    names = [name for name, _ in mix]
    if len(names) == 1:
        return dict.fromkeys(ids, names[0])
    exact = np.array([share for _, share in mix]) * len(ids)
    counts = np.floor(exact).astype(int)
    short = len(ids) - counts.sum()
    counts[np.argsort(-(exact - counts), kind="stable")[:short]] += 1
    dealt = np.repeat(names, counts)
    order = np.random.default_rng([seed, MATERIAL_STREAM]).permutation(len(ids))
    return {ids[i]: str(dealt[k]) for k, i in enumerate(order)}


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
    materials_of: Mapping[int, str] | None = None,
) -> tuple[Path, list[dict]]:
    """Write ``scene.xml`` and ``meshes/*.ply`` into ``folder``; returns (xml path, materials used, each with the
    ``shapes`` it covers).

    The buildings of one material go into one mesh (one shape is faster to trace than hundreds): ``buildings`` when
    they are all of one, ``buildings-<class>`` for each class of a mix. ``materials_of``: a building's class
    (``assign_materials``; None: all concrete). The ground is a rectangle ``ground_margin_m`` larger than
    ``bounds_m`` on each side.
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
    materials = [GROUND.at(frequency_hz) | {"shapes": ["ground"]}]
    shapes = [("ground", GROUND.id)]
    groups: dict[str, list[Block]] = {}
    for b in blocks:
        groups.setdefault("concrete" if materials_of is None else materials_of[b.building], []).append(b)
    for name in sorted(groups, key=list(MATERIALS).index):
        shape = BUILDINGS if len(groups) == 1 else f"{BUILDINGS}-{name}"
        meshes = [extrude(b.footprint, b.base_z_m, b.roof_z_m) for b in groups[name]]
        trimesh.util.concatenate(meshes).export(folder / "meshes" / f"{shape}.ply")
        materials.append(MATERIALS[name].at(frequency_hz) | {"shapes": [shape]})
        shapes.append((shape, MATERIALS[name].id))
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


def walls_of(materials: Sequence[Mapping]) -> dict[str, dict]:
    """The buildings' materials of ``write_scene``'s record by the shape they cover (what ``raytrace.direct_gains``
    takes); the ground is left out (a straight path into it ends there)."""
    return {shape: dict(m) for m in materials if m["id"] != GROUND.id for shape in m["shapes"]}

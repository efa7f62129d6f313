"""Buildings from a Mitsuba scene (the XML that Sionna RT and Blender exports use) and its PLY/OBJ meshes.

The scene is z-up in a local metric frame. Every ``<shape type="ply|obj">``
is loaded (its ``filename`` must stay inside the scene's folder; transforms
are refused rather than guessed), all meshes are merged with shared vertices
welded, and each connected body (faces joined through shared vertices) is a
building: a material split (walls in concrete, a roof in metal) does not split
a building. Flat bodies (the ground
plane, roads) are rejected and counted.

A building's parts are its roof tiers: its upward-facing triangles grouped by
height (a tier spans at most ``TIER_TOL_M``), each tier a part whose footprint is those
roof triangles seen from above and whose roof is the tier's highest point. A
tower on a podium is thus a small tall part on a lower one, and a map built
from it is tall only under the tower. A body without upward faces becomes one
part, its whole footprint at its top.

``crop`` (x_min, y_min, x_max, y_max) clips every footprint to the box and
drops what falls outside, counted.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from xml.parsers import expat

import numpy as np
import shapely

from uavplace.infra.files import regular_file_bytes
from uavplace.infra.limits import check_limit
from uavplace.ingest.buildings import MIN_AREA_M2, BuildingRecord, Part, crop_records
from uavplace.ingest.mesh import FLAT_M, bodies, load_mesh
from uavplace.schemas import InputError, Rejection

#: Shape types whose geometry is a mesh file.
MESH_SHAPES = ("ply", "obj")
#: A tier spans at most this height [m] (its roof is its highest point): a gently sloped roof is one
#: tier, and a row of buildings of different heights is never raised to the tallest.
TIER_TOL_M = 1.0
#: A triangle faces up when the z component of its unit normal exceeds this (about 60 degrees from vertical).
UP_NORMAL_Z = 0.5


@dataclass(frozen=True)
class SceneGeometry:
    """What a scene held: its buildings (parts = roof tiers), what was rejected, and counts."""

    buildings: list[BuildingRecord]
    rejected: list[Rejection]
    num_shapes: int
    num_bodies: int
    num_cropped: int  # bodies wholly outside the crop box


class _Declared(Exception):
    pass


def _declared(*_: object) -> None:
    raise _Declared


def refuse_declarations(raw: bytes, name: str) -> None:
    """Refuse an XML document that declares a DOCTYPE or entities, in whatever encoding it is written.

    The check runs in the parser (expat), after decoding: a byte search would miss ``<!ENTITY`` in UTF-16.
    """
    parser = expat.ParserCreate()
    parser.StartDoctypeDeclHandler = _declared
    parser.EntityDeclHandler = _declared
    try:
        parser.Parse(raw, True)
    except _Declared:
        raise InputError(
            name,
            "the scene declares a DOCTYPE or entities: refused (a scene needs neither)",
            line=parser.CurrentLineNumber,
            field="xml",
        ) from None
    except expat.ExpatError:
        return  # not well-formed: ElementTree's parse names the line
    except ValueError as exc:  # e.g. UTF-16 without a byte-order mark
        raise InputError(name, f"unsupported text encoding ({exc}): write the scene in UTF-8", field="xml") from None


def _scene_shapes(xml_path: Path, name: str) -> tuple[list[tuple[str, Path]], list[Rejection]]:
    """(shape id, mesh file) of every mesh shape, after the safety checks; other shapes rejected."""
    raw = regular_file_bytes(xml_path, name, "text_bytes")
    refuse_declarations(raw, name)
    try:
        root = ET.fromstring(raw)
    except ET.ParseError as exc:
        raise InputError(name, f"not a Mitsuba XML scene ({exc})", line=exc.position[0], field="xml") from None
    if root.tag != "scene":
        raise InputError(name, f"root element is <{root.tag}>, a Mitsuba scene's is <scene>", field="xml")
    # An instance's transform, or another file's shapes: neither is applied here. Mitsuba 3 writes a group as <shape
    # type="shapegroup"> and places it with <shape type="instance">; <shapegroup> and <include> are older spellings.
    groups = [e for e in root.iter() if e.tag in ("shapegroup", "include")]
    groups += [e for e in root.iter("shape") if e.get("type") in ("shapegroup", "instance")]
    if groups:
        found = groups[0]
        what = f"<{found.tag}>" if found.tag != "shape" else f'<shape type="{found.get("type")}">'
        raise InputError(
            name,
            f"{what} is not supported (instances are placed by transforms, includes read other files): "
            "export the scene with every mesh as a shape of its own",
            field=found.get("id") or found.tag,
        )
    folder = xml_path.parent.resolve()
    check_limit("buildings", sum(1 for _ in root.iter("shape")), name, "shapes of the scene (before any is read)")
    shapes, rejected = [], []
    for i, shape in enumerate(root.iter("shape")):
        sid = shape.get("id") or f"shape[{i}]"
        if shape.get("type") not in MESH_SHAPES:
            rejected.append(Rejection(file=name, field=sid, reason=f"shape type '{shape.get('type')}' is not a mesh file"))
            continue
        if shape.find(".//transform") is not None:
            raise InputError(name, f"shape '{sid}' has a transform: bake it into the mesh (not applied here)", field=sid)
        ref = shape.find("string[@name='filename']")
        if ref is None or not ref.get("value"):
            raise InputError(name, f"shape '{sid}' names no filename", field=sid)
        mesh = (folder / ref.get("value", "")).resolve()
        if not mesh.is_relative_to(folder):
            raise InputError(name, f"shape '{sid}' points outside the scene's folder ({ref.get('value')}): refused", field=sid)
        if not mesh.is_file():
            raise InputError(name, f"shape '{sid}': no such mesh file {ref.get('value')}", field=sid)
        shapes.append((sid, mesh))
    return shapes, rejected


def _tiers(tri: np.ndarray) -> list[Part]:
    """A body's roof tiers as parts (see the module docstring); ``tri`` its triangles ``[F, 3, 3]``."""
    base = float(tri[:, :, 2].min())
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normals, axis=1)
    up = normals[:, 2] > UP_NORMAL_Z * np.where(length > 0, length, np.inf)
    polys = shapely.polygons(tri[:, :, :2])
    area = shapely.area(polys)
    roof = up & (area > MIN_AREA_M2)
    if not roof.any():
        footprint = shapely.union_all(polys[area > MIN_AREA_M2])
        return [Part(footprint=footprint, base_z_m=base, roof_z_m=float(tri[:, :, 2].max()))]
    z = tri[roof][:, :, 2].max(axis=1)
    order = np.argsort(z)
    starts, low = [0], z[order[0]]
    for i, zi in enumerate(z[order]):  # a new tier once a roof is more than TIER_TOL_M above its tier's lowest
        if zi > low + TIER_TOL_M:
            starts.append(i)
            low = zi
    parts = []
    roof_polys = polys[roof]
    for group in np.split(order, starts[1:]):
        footprint = shapely.make_valid(shapely.union_all(roof_polys[group]))
        footprint = shapely.union_all([g for g in shapely.get_parts(footprint) if g.geom_type == "Polygon"])
        if footprint.area > MIN_AREA_M2:
            parts.append(Part(footprint=footprint, base_z_m=base, roof_z_m=float(z[group].max())))
    return parts


def read_mitsuba(
    path: str | Path, display: str | None = None, crop: tuple[float, float, float, float] | None = None
) -> SceneGeometry:
    """Buildings of a Mitsuba XML scene: one per connected body, its roof tiers as parts."""
    import trimesh  # heavy: only for mesh sources

    path = Path(path)
    name = display or str(path)
    shapes, rejected = _scene_shapes(path, name)
    if not shapes:
        raise InputError(name, "the scene has no mesh shape (ply or obj)", field="shape")
    meshes = []
    for sid, mesh_path in shapes:
        mesh = load_mesh(mesh_path, f"{mesh_path} (shape '{sid}')", process=False)
        if len(mesh.faces) == 0:
            rejected.append(Rejection(file=name, field=sid, reason="mesh has no faces"))
            continue
        meshes.append(mesh)
    merged = trimesh.util.concatenate(meshes)
    merged.merge_vertices()  # one building split over material meshes shares its vertices
    found = bodies(np.asarray(merged.vertices), np.asarray(merged.faces))
    records = []
    for i, tri in enumerate(found):
        zmin, zmax = float(tri[:, :, 2].min()), float(tri[:, :, 2].max())
        if zmax - zmin < FLAT_M:
            rejected.append(Rejection(file=name, field=f"body[{i}]", reason=f"flat body ({zmax - zmin:.2f} m tall): ground"))
            continue
        records.append(BuildingRecord(name=f"body{i}", source_file=f"{name}#body[{i}]", source_line=None, parts=_tiers(tri)))
    cropped = 0
    if crop is not None:
        records, cropped = crop_records(records, crop)
    return SceneGeometry(records, rejected, num_shapes=len(shapes), num_bodies=len(found), num_cropped=cropped)

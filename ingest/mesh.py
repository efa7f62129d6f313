"""Building meshes (OBJ, PLY, STL, GLB/GLTF) through trimesh.

The mesh is z-up in the local metric frame, read by ``load_mesh`` (regular files of at most
the limit ``mesh_bytes`` only, its references inside its folder). Each connected body is a
building: footprint = union of its triangles seen from above, base and roof =
its min and max z. Flat bodies (z extent below ``FLAT_M``, e.g. a ground
plane) are rejected and counted, not taken as buildings.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import shapely

from uavplace.infra.files import regular_file_bytes
from uavplace.ingest.buildings import MIN_AREA_M2, BuildingRecord, Part
from uavplace.schemas import InputError, Rejection

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")
#: Bodies thinner than this [m] are ground or road surfaces, not buildings.
FLAT_M = 0.5


#: The largest PLY header read [bytes].
_MAX_PLY_HEADER = 64 * 2**10
_PLY_SIZES = {
    "char": 1,
    "uchar": 1,
    "int8": 1,
    "uint8": 1,
    "short": 2,
    "ushort": 2,
    "int16": 2,
    "uint16": 2,
    "int": 4,
    "uint": 4,
    "int32": 4,
    "uint32": 4,
    "float": 4,
    "float32": 4,
    "double": 8,
    "float64": 8,
}


def _folder_resolver(folder: Path):  # noqa: ANN202 - a trimesh resolver
    """A trimesh resolver that reads only regular files inside ``folder``, each within the limit ``mesh_bytes``."""
    from trimesh.resolvers import FilePathResolver

    class FolderFiles(FilePathResolver):
        def get(self, name: str) -> bytes:
            path = (folder / name.strip()).resolve()  # checked here: trimesh 4's resolver reads anywhere
            if not path.is_relative_to(folder.resolve()):
                raise ValueError(f"'{name}' is outside the mesh's folder")
            try:
                return regular_file_bytes(path, name, "mesh_bytes")
            except InputError as exc:
                raise ValueError(str(exc)) from None

    return FolderFiles(str(folder / "_"))


def check_ply_header(data: bytes, name: str) -> None:
    """Refuse a PLY whose header declares more elements than its body can hold (each needs at least its properties'
    bytes, or two characters a value in ASCII): a header claiming 2e9 vertices is refused before any allocation."""
    end = data.find(b"end_header", 0, _MAX_PLY_HEADER)
    if not data.startswith(b"ply") or end < 0:
        raise InputError(name, f"not a PLY file, or a header over {_MAX_PLY_HEADER:,} bytes", field="header")
    body = len(data) - end - len(b"end_header\n")
    lines = data[:end].decode("ascii", "replace").splitlines()
    ascii_ = any(line.split()[:2] == ["format", "ascii"] for line in lines)
    elements: list[list] = []  # [name, count, line number, minimum bytes a row]
    for number, line in enumerate(lines, 1):
        words = line.split()
        if words[:1] == ["element"] and len(words) == 3:
            try:
                elements.append([words[1], int(words[2]), number, 0])
            except ValueError:
                raise InputError(name, f"element count {words[2]!r} is not an integer", line=number, field=words[1]) from None
        elif words[:1] == ["property"] and elements:
            size = 2 if ascii_ else _PLY_SIZES.get(words[2] if words[1:2] == ["list"] and len(words) > 2 else words[-2], 1)
            elements[-1][3] += size
    for element, count, number, row in elements:
        if count < 0 or count * max(row, 1) > body:
            raise InputError(
                name,
                f"declares {count:,} {element} rows of at least {max(row, 1)} bytes; the file holds {body:,}",
                line=number,
                field=element,
            )


def load_mesh(path: Path, name: str, *, process: bool):  # noqa: ANN201 - a trimesh.Trimesh
    """One mesh file as a single ``trimesh.Trimesh``, read safely: a regular file within the limit ``mesh_bytes``, a PLY
    header that fits its body, referenced files (materials, buffers) only regular files of its folder; faces that
    index existing vertices, finite vertices. ``InputError`` naming ``name`` otherwise."""
    import trimesh  # heavy (about 50 MB): only for cities that ship meshes

    data = regular_file_bytes(path, name, "mesh_bytes")
    kind = path.suffix.lower().lstrip(".")
    if kind == "ply":
        check_ply_header(data, name)
    try:
        loaded = trimesh.load(
            io.BytesIO(data), file_type=kind, force="mesh", process=process, resolver=_folder_resolver(path.parent)
        )
    except InputError:
        raise
    except Exception as exc:  # trimesh raises many types on malformed files
        raise InputError(name, f"unreadable mesh ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise InputError(name, "mesh has no faces", field="faces")
    faces, vertices = np.asarray(loaded.faces), np.asarray(loaded.vertices)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(
            name,
            f"vertices {list(vertices.shape)} and faces {list(faces.shape)}: a 3-D triangle mesh has [N, 3] and [F, 3]",
            field="vertices",
        )
    if len(faces) and (faces.min() < 0 or faces.max() >= len(loaded.vertices)):
        raise InputError(name, f"a face indexes vertex {int(faces.max())} of {len(loaded.vertices)}", field="faces")
    if not np.isfinite(loaded.vertices).all():
        raise InputError(name, "mesh has vertices that are not finite", field="vertices")
    return loaded


def bodies(vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """Connected bodies as triangle arrays ``[F_i, 3, 3]``: faces joined through shared (welded) vertices, not only
    shared edges, so the meshes of one building (a material split, tiers that touch) make one body. Linear in the
    faces, whatever the number of bodies."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(vertices)
    rows = np.concatenate([faces[:, 0], faces[:, 1]])
    cols = np.concatenate([faces[:, 1], faces[:, 2]])
    _, label = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)), directed=False)
    face_label = label[faces[:, 0]]
    order = np.argsort(face_label, kind="stable")
    triangles = vertices[faces[order]]
    return np.split(triangles, np.flatnonzero(np.diff(face_label[order])) + 1)


def _footprint(tri: np.ndarray) -> shapely.Geometry:
    polys = shapely.polygons(tri[:, :, :2])
    polys = polys[shapely.area(polys) > MIN_AREA_M2]
    return shapely.union_all(polys)


def read_mesh(path: str | Path, display: str | None = None) -> tuple[list[BuildingRecord], list[Rejection]]:
    path = Path(path)
    name = display or str(path)
    loaded = load_mesh(path, name, process=True)
    if len(loaded.faces) == 0:
        raise InputError(name, "mesh has no faces", field="faces")
    records, rejected = [], []
    for i, tri in enumerate(bodies(np.asarray(loaded.vertices), np.asarray(loaded.faces))):
        zmin, zmax = float(tri[:, :, 2].min()), float(tri[:, :, 2].max())
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
                parts=[Part(footprint=_footprint(tri), base_z_m=zmin, roof_z_m=zmax)],
            )
        )
    return records, rejected

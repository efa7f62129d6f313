"""Writers of Wireless InSite exports: what `uavdata simulate` (and the tests) produce for ingest to read.

Only the subset uavplace's parsers read is written, in InSite's own layout,
so a simulated city goes through exactly the ingest path of a real one:

- ``<project>.txrx``: a points set of users (transmitters) and one receiver
  grid (``begin_<grid>``: corner vertex, ``side1``/``side2``, ``spacing``);
- ``<project>.setup``: one waveform (carrier frequency), one antenna with the
  power threshold below which a receiver counts as unreached;
- ``<project>.<output>.t<PPP>_<SS>.r<RRR>.p2m``: one receiver output per user
  (new-style header; unreached receivers carry the threshold sentinel);
- ``<project>.city``: buildings as faces (a roof polygon and vertical walls);
- ``<project>.provenance.csv.gz``: where each receiver's value came from (``schemas.provenance``), a side file
  InSite-compatible readers do not read.
"""

from __future__ import annotations

import gzip
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely

from uavplace.infra.files import atomic_write_bytes
from uavplace.ingest.provenance import EXPORT_LINE, export_digest
from uavplace.schemas.provenance import CODES_PER_ROW, PROVENANCE_COLUMNS, SIDE_FILE_SUFFIX, code_table

#: Output kinds the writer knows: file name token -> (column titles after the position, format of one row's values).
P2M_OUTPUTS = {
    "power": "<Power(dBm)> <Phase(deg)>",
    "pl": "<PathLoss(dB)>",
}
#: Power written for a receiver no path reached, and the .setup threshold that says so [dBm].
UNREACHED_POWER_DBM = -250.0
#: Path loss written for a receiver no path reached [dB].
UNREACHED_PATH_LOSS_DB = 250.0


@dataclass(frozen=True)
class ReceiverGrid:
    """A receiver grid: corner (x0, y0), height z, nx x ny points spaced ``spacing_m``, x varying fastest."""

    x0_m: float
    y0_m: float
    z_m: float
    num_x: int
    num_y: int
    spacing_m: float

    def points(self) -> np.ndarray:
        """``[num_y * num_x, 3]`` receiver positions in InSite's order (x fastest)."""
        ix, iy = np.meshgrid(np.arange(self.num_x), np.arange(self.num_y))
        x = self.x0_m + ix.ravel() * self.spacing_m
        y = self.y0_m + iy.ravel() * self.spacing_m
        return np.c_[x, y, np.full(x.size, self.z_m)]

    def plane(self) -> tuple[tuple[float, float, float, float], tuple[float, float, float], tuple[float, float]]:
        """The plane of cells the ray tracer measures on, each point the centre of its cell: the box (xmin, ymin,
        xmax, ymax), the centre (x, y, z) and the size (x, y) [m]."""
        size = (self.num_x * self.spacing_m, self.num_y * self.spacing_m)
        corner = (self.x0_m - self.spacing_m / 2, self.y0_m - self.spacing_m / 2)
        box = (corner[0], corner[1], corner[0] + size[0], corner[1] + size[1])
        return box, (corner[0] + size[0] / 2, corner[1] + size[1] / 2, self.z_m), size


def _write(path: Path, text: str, *, gz: bool = False, crlf: bool = False) -> Path:
    if crlf:
        text = text.replace("\n", "\r\n")
    if gz:
        path = path.with_name(path.name + ".gz")
        with gzip.open(path, "wb") as f:
            f.write(text.encode())
    else:
        path.write_bytes(text.encode())
    return path


def _points_set(points_m: np.ndarray, points_set: tuple[int, str], tx_power_dbm: float) -> str:
    """A transmitter points set of a .txrx."""
    points = "\n".join(f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.asarray(points_m, dtype=float))
    return f"""begin_<points> {points_set[1]}
project_id {points_set[0]}
active
begin_<location>
nVertices {len(points_m)}
{points}
end_<location>
is_transmitter yes
is_receiver no
begin_<transmitter>
begin_<pattern>
antenna 0
waveform 0
end_<pattern>
power {tx_power_dbm:.5f}
end_<transmitter>
end_<points>
"""


def write_txrx(
    path: str | Path,
    users_m: np.ndarray,
    grid: ReceiverGrid,
    *,
    tx_power_dbm: float = 20.0,
    user_set: tuple[int, str] = (1, "User"),
    grid_set: tuple[int, str] = (2, "Drone_grid"),
    route_points_m: np.ndarray | None = None,
    route_set: tuple[int, str] = (3, "Route"),
) -> Path:
    """A .txrx with the users as one transmitter points set, the receiver grid, and the route points (``[P, 3]``, if
    any) as a second transmitter points set. ``users_m``: ``[N, 3]``."""
    text = _points_set(users_m, user_set, tx_power_dbm)
    text += f"""begin_<grid> {grid_set[1]}
project_id {grid_set[0]}
active
begin_<location>
side1 {(grid.num_x - 1) * grid.spacing_m:.6f}
side2 {(grid.num_y - 1) * grid.spacing_m:.6f}
spacing {grid.spacing_m:.6f}
nVertices 1
{grid.x0_m:.6f} {grid.y0_m:.6f} {grid.z_m:.6f}
end_<location>
is_transmitter no
is_receiver yes
begin_<receiver>
begin_<pattern>
antenna 0
waveform 0
end_<pattern>
end_<receiver>
end_<grid>
"""
    if route_points_m is not None and len(route_points_m):
        text += _points_set(route_points_m, route_set, tx_power_dbm)
    return _write(Path(path), text)


def write_setup(
    path: str | Path,
    project: str,
    *,
    frequency_hz: float = 800e6,
    bandwidth_hz: float = 1e6,
    threshold_dbm: float = UNREACHED_POWER_DBM,
    antenna: str = "HalfWaveDipole",
    longitude: float = 0.0,
    latitude: float = 0.0,
    features: Sequence[str] = (),
) -> Path:
    """A minimal .setup: origin, one antenna (with its power threshold), one waveform, the geometry files."""
    feats = "".join(
        f"begin_<feature>\nfeature {i}\ncity\nactive\nfilename {name}\nend_<feature>\n" for i, name in enumerate(features)
    )
    text = f"""Format type:keyword version: 1.1.0
begin_<project> {project}
begin_<globals>
longitude {longitude:.9f}
latitude {latitude:.9f}
end_<globals>
begin_<antenna> {antenna}
antenna 0
type {antenna}
polarization vertical
power_threshold {threshold_dbm:g}
end_<antenna>
begin_<Waveform> Sinusoid
waveform 0
CarrierFrequency {frequency_hz:.3f}
bandwidth {bandwidth_hz:.3f}
end_<Waveform>
{feats}end_<project>
"""
    return _write(Path(path), text)


def p2m_name(project: str, output: str, tx_point: int, tx_set_id: int, rx_set_id: int) -> str:
    """InSite's output file name, e.g. ``city.power.t001_01.r002.p2m``."""
    return f"{project}.{output}.t{tx_point:03d}_{tx_set_id:02d}.r{rx_set_id:03d}.p2m"


def write_p2m(
    folder: str | Path,
    project: str,
    output: str,
    *,
    tx_point: int,
    tx_set: tuple[int, str],
    rx_set: tuple[int, str],
    positions_m: np.ndarray,
    distance_m: np.ndarray,
    values: np.ndarray,
    phase_deg: np.ndarray | None = None,
    gz: bool = False,
    crlf: bool = False,
) -> Path:
    """One receiver output. ``values``: received power [dBm] for ``power``, path loss [dB] for ``pl``;
    NaN marks an unreached receiver (written as InSite's sentinel). Shapes ``[N, 3]``, ``[N]``."""
    if output not in P2M_OUTPUTS:
        raise ValueError(f"output {output!r}: expected one of {sorted(P2M_OUTPUTS)}")
    pos = np.asarray(positions_m, dtype=float)
    v = np.asarray(values, dtype=float)
    dead = np.isnan(v)
    idx = np.arange(1, len(pos) + 1)
    if output == "power":
        ph = np.zeros(len(v)) if phase_deg is None else np.asarray(phase_deg, dtype=float)
        body = np.char.add(
            np.char.mod("%.4f", np.where(dead, UNREACHED_POWER_DBM, v)), np.char.mod(" %.3f", np.where(dead, 0.0, ph))
        )
    else:
        body = np.char.mod("%.4f", np.where(dead, UNREACHED_PATH_LOSS_DB, v))
    rows = np.char.add(
        np.char.mod("%d", idx),
        np.char.add(
            np.char.mod(" %.4f", pos[:, 0]),
            np.char.add(
                np.char.mod(" %.4f", pos[:, 1]),
                np.char.add(np.char.mod(" %.4f", pos[:, 2]), np.char.add(np.char.mod(" %.4f ", distance_m), body)),
            ),
        ),
    )
    header = (
        f"# <Transmitter Set: Tx: {tx_set[0]} {tx_set[1]} - Point {tx_point}>\n"
        f"# <Receiver Set: Rx: {rx_set[0]} {rx_set[1]}>\n"
        f"# <X(m)> <Y(m)> <Z(m)> <Distance(m)> {P2M_OUTPUTS[output]}\n"
    )
    text = header + "\n".join(rows.tolist()) + "\n"
    path = Path(folder) / p2m_name(project, output, tx_point, tx_set[0], rx_set[0])
    return _write(path, text, gz=gz, crlf=crlf)


def write_provenance(
    folder: str | Path,
    project: str,
    rx_set_id: int,
    codes: dict[tuple[int, int], np.ndarray],
    p2m_files: list[Path] | None = None,
) -> Path:
    """The side file ``<project>.provenance.csv.gz`` (``schemas.provenance``): the provenance code of every receiver
    of set ``rx_set_id`` for each transmitter, ``codes`` ``{(tx_set, tx_point): [N] codes in the .p2m's order}``, a
    digit each, ``CODES_PER_ROW`` a row. InSite-compatible readers do not read it; uavplace's ingest does.
    ``p2m_files``: the export's receiver outputs, whose sha256 the file records (``ingest.provenance.export_digest``):
    ingest refuses the side file beside any other export."""
    lines = [
        f"# {line}"
        for line in (
            "uavplace cell provenance (docs/simulate.md): the code of every receiver, a digit each, from first_rx on",
            *code_table().splitlines(),
        )
    ]
    if p2m_files is not None:
        lines.append(EXPORT_LINE + export_digest(list(p2m_files)))
    lines.append(",".join(PROVENANCE_COLUMNS))
    for (tx_set, tx_point), c in sorted(codes.items()):
        digits = (np.asarray(c, np.uint8).ravel() + np.uint8(ord("0"))).tobytes().decode("ascii")
        rows = range(0, len(digits), CODES_PER_ROW)
        lines += [f"{tx_set},{tx_point},{rx_set_id},{i + 1},{digits[i : i + CODES_PER_ROW]}" for i in rows]
    path = Path(folder) / f"{project}{SIDE_FILE_SUFFIX}"
    # mtime 0: the same codes give the same bytes; written beside and renamed, so a reader never sees half of it
    atomic_write_bytes(path, gzip.compress(("\n".join(lines) + "\n").encode(), mtime=0))
    return path


def _prism_faces(poly: shapely.Polygon, base: float, roof: float) -> list[list[tuple[float, float, float]]]:
    """Roof face(s) at ``roof`` and one wall quad per edge of every ring of ``poly``."""
    rings = [np.asarray(shapely.get_coordinates(shapely.force_2d(r)))[:-1] for r in (poly.exterior, *poly.interiors)]
    if len(rings) == 1:
        faces = [[(x, y, roof) for x, y in rings[0]]]
    else:
        tris = shapely.get_parts(shapely.constrained_delaunay_triangles(poly))
        faces = [[(x, y, roof) for x, y in np.asarray(t.exterior.coords)[:3]] for t in tris]
    for ring in rings:
        for (x1, y1), (x2, y2) in zip(ring, np.roll(ring, -1, axis=0), strict=True):
            faces.append([(x1, y1, base), (x2, y2, base), (x2, y2, roof), (x1, y1, roof)])
    return faces


def write_city(
    path: str | Path, buildings: Sequence[Sequence[tuple[shapely.Geometry, float, float]]], *, name: str = "city"
) -> Path:
    """An InSite .city: per building a ``structure``, per part ``(footprint, base z, roof z)`` [m] a
    ``sub_structure`` (a roof tier) whose faces are the roof at roof z and one vertical wall per ring
    edge, holes (courtyards) included. A roof with holes is written as triangles (a face has one ring).
    z is above the terrain (``reference terrain``)."""
    out = [
        "Format type:keyword version: 1.1.0",
        f"begin_<city> {name}",
        "begin_<reference>",
        "cartesian",
        "terrain",
        "end_<reference>",
    ]
    for k, parts in enumerate(buildings):
        out += ["begin_<structure_group> ", f"begin_<structure> building_{k}"]
        for j, (footprint, base, roof) in enumerate(parts):
            out.append(f"begin_<sub_structure> {j + 1}")
            for poly in shapely.get_parts(footprint):
                for face in _prism_faces(poly, base, roof):
                    out += ["begin_<face> ", "Material 1", f"nVertices {len(face)}"]
                    out += [f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in face]
                    out.append("end_<face>")
            out.append("end_<sub_structure>")
        out += ["end_<structure>", "end_<structure_group>"]
    out.append("end_<city>")
    return _write(Path(path), "\n".join(out) + "\n")

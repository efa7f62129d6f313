"""The bad-input corpus: each case spoils one good input and names what the one error line must say.

A case is (id, CLI, maker, expected): the maker builds the spoiled input in a
``Workspace`` and returns the command's arguments; the test runs the real CLI
and asserts exit status 2, exactly one line starting ``error:`` that holds
``expected``, and no traceback. ``expected`` names the file, line and field
wherever the input has them.
"""

from __future__ import annotations

import json
import pickle
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tests.bad_inputs.workspace import PL1, POWER1, Workspace, row_line


@dataclass(frozen=True)
class Case:
    id: str
    cli: str  # "uavdata" or "uavrl"
    make: Callable[[Workspace], list[str]]
    expect: str


L5 = row_line(5)
POINTS = {"type": "Polygon", "coordinates": [[[0, 0], [20, 0], [20, 20], [0, 20], [0, 0]]]}
BOWTIE = {"type": "Polygon", "coordinates": [[[0, 0], [20, 20], [20, 0], [0, 20], [0, 0]]]}


PLY_HEAD = (
    "ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nelement face 2\n"
    "property list uchar int vertex_indices\nend_header\n"
)


def _train_with(setting: str) -> Callable[[Workspace], list[str]]:
    """``uavrl train`` of the fast preset on the built city with one ``--set``."""
    return lambda w: ["train", "--dataset", "city", "--root", str(w.root()), "--preset", "fast", "--out", str(w.tmp / "runs"),
                      "--set", setting]  # fmt: skip


def _edit_json(path, edit):  # noqa: ANN001, ANN202
    """``path`` (a JSON file) changed in place by ``edit(doc)``; returns the file's folder."""
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    return path.parent


def _fc(*features: object) -> dict:
    return {"type": "FeatureCollection", "features": list(features)}


def _feature(props: object, geometry: object = POINTS) -> dict:
    return {"type": "Feature", "geometry": geometry, "properties": props}


def _city_file(faces: str) -> str:
    return (
        f"begin_<city> c\nbegin_<structure> s\nbegin_<sub_structure> p\n{faces}end_<sub_structure>\nend_<structure>\nend_<city>\n"
    )


def _face(*vertices: tuple[float | str, float | str, float | str]) -> str:
    body = "".join(f"{x} {y} {z}\n" for x, y, z in vertices)
    return f"begin_<face> f\nnVertices {len(vertices)}\n{body}end_<face>\n"


SQUARE_ROOF = _face((0, 0, 20), (10, 0, 20), (10, 10, 20), (0, 10, 20))


def _named_folder(w: Workspace, name: str) -> list[str]:
    return w.ingest(w.city(name=name))


def _two_setups(w: Workspace) -> list[str]:
    city = w.city()
    (city / "b.setup").write_text((city / "city.setup").read_text())
    return w.ingest(city)


def _garbage_manifest(w: Workspace):  # noqa: ANN202 - a Path
    root = w.root()
    (root / "city" / "ingested" / "manifest.json").write_bytes(b"\xff\xfe\x00 not a manifest")
    return root


def _scene_escape(w: Workspace) -> list[str]:
    scene = w.tmp / "scene"
    scene.mkdir()
    (w.tmp / "outside.ply").write_bytes(b"ply\n")
    (scene / "s.xml").write_text(
        '<scene version="2.1.0"><shape type="ply" id="x"><string name="filename" value="../outside.ply"/></shape></scene>'
    )
    return ["simulate", str(scene / "s.xml"), "--name", "x", "--out", str(w.tmp / "raw")]


def _quantity_twice(w: Workspace) -> list[str]:
    city = w.city()
    (city / "other.pl.t001_01.r002.p2m").write_text((city / PL1).read_text())
    return w.ingest(city)


def _show(w: Workspace, root: object) -> list[str]:
    """``uavdata show city`` of the bundle under ``root`` (the workspace's root, or what ``forge`` returned)."""
    return ["show", "city", "--root", str(root), "--out", str(w.tmp / "s.png")]


def _npz(arrays: dict[str, np.ndarray]) -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _bundle_arrays(mutate: Callable[[dict[str, np.ndarray]], None]) -> Callable[[Workspace], list[str]]:
    """``uavdata show`` of a bundle whose maps ``mutate`` changed (in a copy of every array), hash updated."""

    def make(w: Workspace) -> list[str]:
        with np.load(w.bundle() / "maps.npz") as z:
            arrays = {k: z[k].copy() for k in z.files}
        mutate(arrays)
        return _show(w, w.forge("maps.npz", _npz(arrays)))

    return make


def _set(name: str, index: tuple[int, ...], value: float) -> Callable[[dict[str, np.ndarray]], None]:
    return lambda a: a[name].__setitem__(index, value)


def _huge_header(w: Workspace) -> list[str]:
    """A ``sinr_db.npy`` whose header claims 4 TB: refused from its header, never allocated."""
    import io
    import zipfile

    with np.load(w.bundle() / "maps.npz") as z:
        arrays = {k: z[k] for k in z.files}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, a in arrays.items():
            member = io.BytesIO()
            if name == "sinr_db":
                np.lib.format.write_array_header_1_0(
                    member, {"descr": "<f4", "fortran_order": False, "shape": (2**20, 2**10, 2**10)}
                )
            else:
                np.lib.format.write_array(member, a)
            zf.writestr(f"{name}.npy", member.getvalue())
    return _show(w, w.forge("maps.npz", buf.getvalue()))


def _users_edit(column: str, row: int, value: object) -> Callable[[Workspace], list[str]]:
    def make(w: Workspace) -> list[str]:
        import io

        import pandas as pd

        users = pd.read_parquet(w.bundle() / "users.parquet")
        users.loc[row, column] = value
        buf = io.BytesIO()
        users.to_parquet(buf, index=False)
        return _show(w, w.forge("users.parquet", buf.getvalue()))

    return make


def _manifest_edit(key: str, value: object) -> Callable[[Workspace], list[str]]:
    def make(w: Workspace) -> list[str]:
        path = w.bundle() / "manifest.json"
        doc = json.loads(path.read_text())
        doc[key] = value
        path.write_text(json.dumps(doc))
        return _show(w, w.root())

    return make


def _latest(text: str) -> Callable[[Workspace], list[str]]:
    def make(w: Workspace) -> list[str]:
        (w.root() / "city" / "latest").write_text(text)
        return _show(w, w.root())

    return make


def _forged(name: str, data: bytes) -> Callable[[Workspace], list[str]]:
    return lambda w: _show(w, w.forge(name, data))


def _agent_file(content: bytes | Callable[[Workspace], object]) -> Callable[[Workspace], list[str]]:
    def make(w: Workspace) -> list[str]:
        agent = w.agent()
        path = agent / "checkpoints" / "best.pt"
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            import torch

            torch.save(content(w), path)
        return w.report("--run", str(agent))

    return make


def _report_out_victim(w: Workspace) -> list[str]:
    victim = w.tmp / "thesis"
    victim.mkdir()
    (victim / "thesis.tex").write_text("\\documentclass{article}")
    return w.report("--run", str(w.agent()), "--out", str(victim))


def _simulate_victim(w: Workspace) -> list[str]:
    victim = w.tmp / "raw" / "mine"
    victim.mkdir(parents=True)
    (victim / "notes.txt").write_text("mine")
    return ["simulate", "procedural:tiny", "--name", "mine", "--out", str(w.tmp / "raw"), "--quiet"]


CASES: list[Case] = [
    # -- .p2m rows -------------------------------------------------------------------------------
    Case("p2m truncated row", "uavdata", lambda w: w.edit(PL1, "\n30 ", "\n30 1 "), f"{PL1}:33: row:"),
    Case("p2m missing header column", "uavdata", lambda w: w.edit(PL1, "<Distance(m)> ", ""), f"{PL1}:3: header:"),
    Case("p2m text in a number", "uavdata", lambda w: w.p2m(5, 1, "x26"), f"{PL1}:{L5}: x_m: 'x26' is not a number"),
    Case(
        "p2m duplicate receiver",
        "uavdata",
        lambda w: w.p2m(6, 0, "5"),
        f"{PL1}:{row_line(6)}: rx_index: duplicate receiver number 5",
    ),
    Case("p2m nan", "uavdata", lambda w: w.p2m(5, 5, "nan"), f"{PL1}:{L5}: path_loss_db: value nan is not a finite number"),
    Case("p2m inf", "uavdata", lambda w: w.p2m(5, 5, "inf"), f"{PL1}:{L5}: path_loss_db: "),
    Case(
        "p2m 5-million-digit number",
        "uavdata",
        lambda w: w.p2m(5, 5, "9" * 5_000_000),
        f"{PL1}:{L5}: a line of more than 65,536 bytes (a receiver row is a few dozen)",
    ),
    Case(
        "p2m underscore in a number",
        "uavdata",
        lambda w: w.p2m(5, 5, "-7_0.5"),
        f"{PL1}:{L5}: path_loss_db: '-7_0.5' is not a number",
    ),
    Case("p2m receiver number 0", "uavdata", lambda w: w.p2m(1, 0, "0"), f"{PL1}:{row_line(1)}: rx_index: receiver number 0 < 1"),
    Case(
        "p2m fractional receiver number",
        "uavdata",
        lambda w: w.p2m(5, 0, "5.5"),
        f"{PL1}:{L5}: rx_index: '5.5' is not a receiver number",
    ),
    Case(
        "p2m negative distance",
        "uavdata",
        lambda w: w.p2m(5, 4, "-3"),
        f"{PL1}:{L5}: distance_m: -3 is outside the physical range",
    ),
    Case("p2m x 1e300", "uavdata", lambda w: w.p2m(5, 1, "1e300"), f"{PL1}:{L5}: x_m: 1e+300 is outside the physical range"),
    Case("p2m z 1e5", "uavdata", lambda w: w.p2m(5, 3, "1e5"), f"{PL1}:{L5}: z_m: 100000 is outside the physical range"),
    Case(
        "p2m power 1e300 dBm",
        "uavdata",
        lambda w: w.p2m(5, 5, "1e300", ("power",), POWER1),
        f"{POWER1}:{L5}: power_dbm: 1e+300 is outside the physical range",
    ),
    Case(
        "p2m power 400 dBm",
        "uavdata",
        lambda w: w.p2m(5, 5, "400", ("power",), POWER1),
        f"{POWER1}:{L5}: power_dbm: 400 is outside the physical range",
    ),
    Case(
        "p2m power above tx + gains",
        "uavdata",
        lambda w: w.p2m(5, 5, "70.8", ("power",), POWER1),  # a sign dropped from -70.8 dBm (20 dBm, two dipoles)
        f"{POWER1}:{L5}: power_dbm: received power 70.8 dBm is beyond 30.3 dBm, the transmit power and both antennas' "
        "gains with 6 dB for paths in phase",
    ),
    Case(
        "p2m phase 720", "uavdata", lambda w: w.p2m(5, 6, "720", ("power",), POWER1), f"{POWER1}:{L5}: phase_deg: 720 is outside"
    ),
    Case("p2m too many columns", "uavdata", lambda w: w.p2m(5, 5, "1 2"), f"{PL1}:{L5}: row: expected 6 columns"),
    Case(
        "p2m receiver beyond the grid",
        "uavdata",
        lambda w: w.p2m(30, 0, "31"),
        f"{PL1}: rx_index: receiver 31, but grid 'Drone_grid'",
    ),
    Case(
        "p2m header and name disagree",
        "uavdata",
        lambda w: w.edit(PL1, "Point 1>", "Point 2>"),
        f"{PL1}:1: Transmitter Set: header says transmitter set 1 point 2",
    ),
    Case(
        "p2m unit mismatch",
        "uavdata",
        lambda w: w.edit(PL1, "<PathLoss(dB)>", "<PathLoss(dBm)>"),
        f"{PL1}:3: PathLoss: unit 'dBm' for PathLoss",
    ),
    Case(
        "p2m header only",
        "uavdata",
        lambda w: w.add_file("x.pl.t003_01.r002.p2m", "# <X(m)> <Y(m)> <Z(m)> <Distance(m)> <PathLoss(dB)>\n"),
        "x.pl.t003_01.r002.p2m:2: no receiver rows",
    ),
    Case(
        "p2m empty file",
        "uavdata",
        lambda w: w.add_file("x.pl.t003_01.r002.p2m", ""),
        "x.pl.t003_01.r002.p2m:1: no receiver rows",
    ),
    Case(
        "p2m binary garbage",
        "uavdata",
        lambda w: w.add_file("x.pl.t003_01.r002.p2m", bytes(range(256)) * 4),
        "x.pl.t003_01.r002.p2m: holds NUL bytes (first at byte 0)",
    ),
    Case(
        "p2m utf-16 without a byte-order mark",
        "uavdata",
        lambda w: w.add_file("x.pl.t003_01.r002.p2m", "1 0 0 10 3 60\n".encode("utf-16-le")),
        "UTF-16 text without a byte-order mark",
    ),
    Case(
        "p2m utf-16 mark, odd bytes",
        "uavdata",
        lambda w: w.add_file("x.pl.t003_01.r002.p2m", b"\xff\xfe1\x00 \x00\x00"),
        "not UTF-16 text",
    ),
    Case(
        "p2m corrupt gzip body",
        "uavdata",
        lambda w: w.gz_body(lambda b: b[:20] + b"\x00garbage" * 40),
        f"{PL1}.gz: not a readable gzip file",
    ),
    Case(
        "p2m gz that is not gzip",
        "uavdata",
        lambda w: w.gz_body(lambda b: b"plain text, not gzip\n"),
        f"{PL1}.gz: not a readable gzip file",
    ),
    Case(
        "p2m grid row count",
        "uavdata",
        lambda w: w.edit("city.txrx", "side2 16.000000", "side2 20.000000"),
        f"{PL1}: rows: 30 rows, but grid 'Drone_grid' (city.txrx:19) is 6 x 6 = 36",
    ),
    Case(
        "p2m off the lattice",
        "uavdata",
        lambda w: w.edit("city.txrx", "\n10.000000 -20.000000 10.000000", "\n11.000000 -20.000000 10.000000"),
        "x_m: receiver 1 at x_m=10.0, off grid",
    ),
    Case("p2m quantity given twice", "uavdata", _quantity_twice, "path_loss_db for t001_01 r002 is also given by"),
    Case(
        "txrx spacing 0",
        "uavdata",
        lambda w: w.edit("city.txrx", "spacing 4.000000", "spacing 0"),
        "city.txrx:25: spacing: spacing 0 m: must be > 0 and finite",
    ),
    Case(
        "txrx spacing 1e-300",
        "uavdata",
        lambda w: w.edit("city.txrx", "spacing 4.000000", "spacing 1e-300"),
        "city.txrx:25: spacing: spacing 1e-300 m for a side of 20 m: over 10,000,000 receivers a side",
    ),
    Case(
        "txrx project id 1e30",
        "uavdata",
        lambda w: w.edit("city.txrx", "project_id 1\n", "project_id 1000000000000000000000000000000\n"),
        "city.txrx:1: project_id: Input should be less than or equal to 2147483647",
    ),
    Case(
        "txrx negative spacing",
        "uavdata",
        lambda w: w.edit("city.txrx", "spacing 4.000000", "spacing -4"),
        "city.txrx:25: spacing: spacing -4 m: must be > 0",
    ),
    Case(
        "txrx negative side",
        "uavdata",
        lambda w: w.edit("city.txrx", "side1 20.000000", "side1 -20"),
        "city.txrx:23: side1: side1 -20 m: must be >= 0",
    ),
    Case(
        "txrx power inf",
        "uavdata",
        lambda w: w.edit("city.txrx", "power 20.00000", "power inf"),
        "city.txrx:16: power: inf is not a finite number",
    ),
    Case(
        "txrx power nan",
        "uavdata",
        lambda w: w.edit("city.txrx", "power 20.00000", "power nan"),
        "city.txrx:16: power: nan is not a finite number",
    ),
    Case(
        "txrx power 1e300",
        "uavdata",
        lambda w: w.edit("city.txrx", "power 20.00000", "power 1e300"),
        "city.txrx:16: power: 1e300 is outside the physical range [-400, 100] dBm",
    ),
    Case(
        "txrx power text",
        "uavdata",
        lambda w: w.edit("city.txrx", "power 20.00000", "power loud"),
        "city.txrx:16: power: 'loud' is not a number",
    ),
    Case(
        "txrx no project_id",
        "uavdata",
        lambda w: w.edit("city.txrx", "project_id 1\n", ""),
        "city.txrx:1: project_id: set 'User' has no project_id",
    ),
    Case(
        "txrx duplicate project_id",
        "uavdata",
        lambda w: w.edit("city.txrx", "project_id 2", "project_id 1"),
        "city.txrx:19: project_id: project_id 1 already used by the set at city.txrx:1",
    ),
    Case(
        "txrx project_id text",
        "uavdata",
        lambda w: w.edit("city.txrx", "project_id 1", "project_id one"),
        "city.txrx:2: project_id: 'one' is not a number",
    ),
    Case(
        "txrx vertex with two numbers",
        "uavdata",
        lambda w: w.edit("city.txrx", "13.000000 -18.000000 1.500000", "13.000000 -18.000000"),
        "city.txrx:7: vertex: vertex needs 3 numbers",
    ),
    Case(
        "txrx vertex 1e400",
        "uavdata",
        lambda w: w.edit("city.txrx", "13.000000 -18.000000 1.500000", "1e400 -18.000000 1.500000"),
        "city.txrx:7: x: vertex coordinate inf is not finite",
    ),
    Case(
        "txrx truncated",
        "uavdata",
        lambda w: w.edit("city.txrx", "end_<grid>\n", ""),
        "city.txrx:19: begin_<grid> at line 19 is never closed",
    ),
    Case(
        "txrx mismatched end",
        "uavdata",
        lambda w: w.edit("city.txrx", "end_<location>", "end_<grid>"),
        "city.txrx:8: end_<grid> closes location",
    ),
    Case("txrx NUL bytes", "uavdata", lambda w: w.add_file("b.txrx", b"begin_<points> x\x00\n"), "b.txrx: holds NUL bytes"),
    # -- .setup ------------------------------------------------------------------------------------
    Case(
        "setup negative frequency",
        "uavdata",
        lambda w: w.edit("city.setup", "CarrierFrequency 800000000.000", "CarrierFrequency -8e8"),
        "city.setup:15: CarrierFrequency: -8e8 is outside the physical range [1, 1e+13] Hz",
    ),
    Case(
        "setup frequency 0",
        "uavdata",
        lambda w: w.edit("city.setup", "CarrierFrequency 800000000.000", "CarrierFrequency 0"),
        "city.setup:15: CarrierFrequency: 0 is outside the physical range",
    ),
    Case(
        "setup frequency nan",
        "uavdata",
        lambda w: w.edit("city.setup", "CarrierFrequency 800000000.000", "CarrierFrequency nan"),
        "city.setup:15: CarrierFrequency: nan is not a finite number",
    ),
    Case(
        "setup power_threshold nan",
        "uavdata",
        lambda w: w.edit("city.setup", "power_threshold -250", "power_threshold nan"),
        "city.setup:11: power_threshold: nan is not a finite number",
    ),
    Case(
        "setup power_threshold inf",
        "uavdata",
        lambda w: w.edit("city.setup", "power_threshold -250", "power_threshold -inf"),
        "city.setup:11: power_threshold: -inf is not a finite number",
    ),
    Case(
        "setup no project",
        "uavdata",
        lambda w: w.add_file("city.setup", "begin_<globals>\nend_<globals>\n"),
        "city.setup: project: no begin_<project> block",
    ),
    Case(
        "setup waveform without frequency",
        "uavdata",
        lambda w: w.edit("city.setup", "CarrierFrequency 800000000.000\n", ""),
        "city.setup:13: CarrierFrequency: Waveform 'Sinusoid' has no CarrierFrequency",
    ),
    Case(
        "setup antenna number text",
        "uavdata",
        lambda w: w.edit("city.setup", "antenna 0", "antenna zero"),
        "city.setup:8: antenna: 'zero' is not a number",
    ),
    Case("setup two files", "uavdata", _two_setups, "file: several .setup files"),
    # -- .city -------------------------------------------------------------------------------------
    Case(
        "city face with 2 vertices",
        "uavdata",
        lambda w: w.add_file("b.city", _city_file(_face((0, 0, 0), (1, 1, 1)))),
        "b.city:5: nVertices: face has 2 vertices",
    ),
    Case(
        "city self-intersecting roof",
        "uavdata",
        lambda w: w.add_file("b.city", _city_file(_face((0, 0, 20), (10, 10, 20), (10, 0, 20), (0, 10, 20)))),
        "b.city:5: face: face is not a simple polygon seen from above (Self-intersection",
    ),
    Case(
        "city roof z 1e300",
        "uavdata",
        lambda w: w.add_file("b.city", _city_file(_face((0, 0, "1e300"), (10, 0, 20), (10, 10, 20)))),
        "b.city:6: z: vertex coordinate 1e+300 is not finite or outside",
    ),
    Case(
        "city 2000 m tower",
        "uavdata",
        lambda w: w.add_file(
            "b.city", _city_file(_face((0, 0, 0), (10, 0, 0), (10, 10, 0)) + SQUARE_ROOF.replace(" 20\n", " 2000\n"))
        ),
        "b.city:2: height: height 2000 m is outside the physical range [0, 1000] m",
    ),
    Case(
        "city vertex text",
        "uavdata",
        lambda w: w.add_file("b.city", _city_file(_face((0, 0, 0), (10, "x", 0), (10, 10, 0)))),
        "b.city:7: vertex: vertex '10 x 0' holds text",
    ),
    Case(
        "city too few vertex lines",
        "uavdata",
        lambda w: w.add_file("b.city", _city_file(SQUARE_ROOF.replace("nVertices 4", "nVertices 9"))),
        "b.city:5: nVertices: nVertices 9 but only 4 vertex lines follow",
    ),
    # -- GeoJSON -----------------------------------------------------------------------------------
    Case(
        "geojson a list", "uavdata", lambda w: w.geojson([1, 2]), "b.geojson: type: not a GeoJSON FeatureCollection (a JSON list)"
    ),
    Case(
        "geojson a string feature",
        "uavdata",
        lambda w: w.geojson(_fc("building")),
        "b.geojson: features[0]: feature 0 is a JSON str",
    ),
    Case(
        "geojson 100 k nested brackets",
        "uavdata",
        lambda w: w.geojson("[" * 100_000 + "]" * 100_000),
        "b.geojson: json: JSON nested too deeply",
    ),
    Case(
        "geojson latin-1 text",
        "uavdata",
        lambda w: w.geojson(json.dumps(_fc(_feature({"height": 10, "name": "X"}))).replace("X", "\xe9").encode("latin-1")),
        "b.geojson: encoding: not UTF-8 text (byte 0xe9",
    ),
    Case(
        "geojson invalid json",
        "uavdata",
        lambda w: w.geojson('{"type": "FeatureCollection",\n "features": [}'),
        "b.geojson:2: column 15: invalid JSON",
    ),
    Case(
        "geojson height nan",
        "uavdata",
        lambda w: w.geojson(_fc(_feature({"height": "nan"}))),
        "b.geojson: features[0].properties.height: feature 0: nan is outside the physical range [0, 1000] m",
    ),
    Case(
        "geojson height 1e400",
        "uavdata",
        lambda w: w.geojson(
            '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"height": 1e400}, "geometry": '
            + json.dumps(POINTS)
            + "}]}"
        ),
        "features[0].properties.height: feature 0: inf is outside",
    ),
    Case(
        "geojson top below its base",
        "uavdata",
        lambda w: w.geojson(_fc(_feature({"height": "5 m", "min_height": 9}))),
        "features[0].properties: feature 0: top 5 m below its base 9 m (height)",
    ),
    Case(
        "geojson negative height",
        "uavdata",
        lambda w: w.geojson(_fc(_feature({"height": -5}))),
        "features[0].properties.height: feature 0: -5 is outside the physical range",
    ),
    Case(
        "geojson a million levels",
        "uavdata",
        lambda w: w.geojson(_fc(_feature({"building:levels": 1e6}))),
        "features[0].properties.building:levels: feature 0: 1000000.0 is outside the physical range",
    ),
    Case(
        "geojson self-intersecting",
        "uavdata",
        lambda w: w.geojson(_fc(_feature({"height": 10}, BOWTIE))),
        "features[0].geometry: feature 0: invalid polygon (Self-intersection",
    ),
    Case(
        "geojson in degrees",
        "uavdata",
        lambda w: w.geojson(
            _fc(
                _feature(
                    {"height": 10},
                    {"type": "Polygon", "coordinates": [[[2.1, 48.8], [2.1001, 48.8], [2.1001, 48.8001], [2.1, 48.8]]]},
                )
            )
        ),
        "footprints look like longitude/latitude degrees",
    ),
    Case(
        "geojson properties a list",
        "uavdata",
        lambda w: w.geojson(_fc(_feature([1]))),
        "features[0].properties: feature 0: properties is a JSON list",
    ),
    Case(
        "geojson geometry a string",
        "uavdata",
        lambda w: w.geojson(_fc(_feature({"height": 1}, "square"))),
        "features[0].geometry: feature 0: geometry is a JSON str",
    ),
    Case(
        "geojson infinite coordinate",
        "uavdata",
        lambda w: w.geojson(
            '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"height": 5}, "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [1e400, 0], [5, 5], [0, 0]]]}}]}'
        ),
        "features[0].geometry: feature 0: empty geometry or coordinates that are not finite",
    ),
    Case(
        "geojson malformed coordinates",
        "uavdata",
        lambda w: w.geojson(_fc(_feature({"height": 5}, {"type": "Polygon", "coordinates": "abc"}))),
        "features[0].geometry: feature 0: malformed geometry",
    ),
    # -- folders and names -------------------------------------------------------------------------
    Case(
        "ingest folder named with a space",
        "uavdata",
        lambda w: _named_folder(w, "my city"),
        "city name (the folder's; or pass --name): 'my city' is not a safe name",
    ),
    Case("ingest folder named in unicode", "uavdata", lambda w: _named_folder(w, "zürich"), "'zürich' is not a safe name"),
    Case(
        "ingest --name ../../evil",
        "uavdata",
        lambda w: [*w.ingest(w.city()), "--name", "../../evil"],
        "city name: '../../evil' is not a safe name",
    ),
    Case(
        "ingest --name /abs/path", "uavdata", lambda w: [*w.ingest(w.city()), "--name", str(w.tmp / "abs")], "is not a safe name"
    ),
    Case(
        "ingest empty folder",
        "uavdata",
        lambda w: w.ingest((w.tmp / "empty").mkdir() or w.tmp / "empty"),
        "empty folder: nothing to ingest",
    ),
    Case(
        "ingest unknown files only",
        "uavdata",
        lambda w: w.ingest(((w.tmp / "junk").mkdir(), (w.tmp / "junk" / "a.jpg").write_bytes(b"\xff"))[0] or w.tmp / "junk"),
        "no receiver output, .txrx, .setup or geometry file",
    ),
    Case("ingest a missing folder", "uavdata", lambda w: w.ingest(w.tmp / "nowhere"), "nowhere: not a folder"),
    Case(
        "ingest --out is a file",
        "uavdata",
        lambda w: ["ingest", str(w.city()), "--out", str((w.tmp / "f").write_text("x") and w.tmp / "f")],
        "is a file",
    ),
    # -- build -------------------------------------------------------------------------------------
    Case(
        "build --city ../x",
        "uavdata",
        lambda w: ["build", "--root", str(w.root()), "--city", "../x"],
        "city name: '../x' is not a safe name",
    ),
    Case(
        "build unknown city", "uavdata", lambda w: ["build", "--root", str(w.root()), "--city", "nosuch", "--quiet"], "nosuch: "
    ),
    Case(
        "build bad --split",
        "uavdata",
        lambda w: ["build", "--root", str(w.root()), "--split", "city=maybe"],
        "expected CITY=train, CITY=val, CITY=test or CITY=none",
    ),
    Case(
        "build --grid four",
        "uavdata",
        lambda w: ["build", "--root", str(w.root()), "--grid", "four"],
        "'four' is not a length in metres",
    ),
    Case(
        "build altitude without receivers",
        "uavdata",
        lambda w: ["build", "--root", str(w.root()), "--alt", "30", "--quiet"],
        "heights present: 10 m (60 rx)",
    ),
    Case(
        "build tampered ingested table",
        "uavdata",
        lambda w: [
            "build",
            "--root",
            str((lambda r: ((r / "city" / "ingested" / "receivers.parquet").write_bytes(b"PAR1junk"), r)[1])(w.root())),
            "--quiet",
        ],
        "receivers.parquet: sha256: sha256 differs from the ingest manifest",
    ),
    Case(
        "build garbage ingest manifest",
        "uavdata",
        lambda w: [
            "build",
            "--root",
            str((lambda r: ((r / "city" / "ingested" / "manifest.json").write_bytes(b"\xff\xfe\x00garbage"), r)[1])(w.root())),
            "--city",
            "city",
            "--quiet",
        ],
        "manifest.json: not UTF-8 text",
    ),
    Case(
        "list with a garbage ingest manifest",
        "uavdata",
        lambda w: ["list", "--root", str(_garbage_manifest(w))],
        "manifest.json: not UTF-8 text",
    ),
    Case(
        "datasets with a garbage ingest manifest",
        "uavrl",
        lambda w: ["datasets", "--root", str(_garbage_manifest(w))],
        "manifest.json: not UTF-8 text",
    ),
    Case("schema of an unknown contract", "uavdata", lambda w: ["schema", "nosuch"], "'nosuch' is not one of 'build_config'"),
    # -- show and bundles --------------------------------------------------------------------------
    Case(
        "show unknown city",
        "uavdata",
        lambda w: ["show", "nosuchcity", "--root", str(w.root())],
        "no city 'nosuchcity' is built here",
    ),
    Case(
        "show a mistyped city",
        "uavdata",
        lambda w: ["show", "cyty", "--root", str(w.root())],
        "no city 'cyty' is built here: did you mean city?",
    ),
    Case(
        "show city@../..",
        "uavdata",
        lambda w: ["show", "city@../..", "--root", str(w.root())],
        "bundle version: '../..' is not a safe name",
    ),
    Case(
        "show garbage maps.npz",
        "uavdata",
        _forged("maps.npz", b"not a zip archive at all"),
        "maps.npz: not a readable map archive",
    ),
    Case("show pickled maps.npz", "uavdata", _forged("maps.npz", pickle.dumps({"x": 1})), "maps.npz: not a readable map archive"),
    Case(
        "show object array in maps.npz",
        "uavdata",
        _bundle_arrays(lambda a: a.__setitem__("sinr_db", np.array([{"evil": 1}], dtype=object))),
        "maps.npz: sinr_db: array object[1], expected float32",
    ),
    Case(
        "show non-finite map",
        "uavdata",
        _bundle_arrays(_set("sinr_db", (0, 1, 2), np.inf)),
        "maps.npz: sinr_db: value inf at [0, 1, 2] is not finite",
    ),
    Case(
        "show SINR of 1e30",
        "uavdata",
        _bundle_arrays(_set("sinr_db", (1, 0, 3), 1e30)),
        "sinr_db: value 1e+30 at [1, 0, 3] is outside",
    ),
    Case(
        "show height of 1e30",
        "uavdata",
        _bundle_arrays(_set("height_rel_m", (2, 2), 1e30)),
        "height_rel_m: value 1e+30 at [2, 2]",
    ),
    Case(
        "show SINR under the floor",
        "uavdata",
        _bundle_arrays(_set("sinr_db", (0, 0, 0), -300.0)),
        "SINR below the manifest's floor",
    ),
    Case(
        "show provenance not a code",
        "uavdata",
        _bundle_arrays(_set("provenance", (0, 0, 0), 200)),
        "provenance: cell [0, 0, 0]: 200 is not a provenance code (0 .. 8",
    ),
    Case(
        "show live cell said unreached",
        "uavdata",
        _bundle_arrays(lambda a: a["provenance"].__setitem__(~a["dead"], 0)),
        "code 0 (unreached) but the cell is live",
    ),
    Case("show all blocked", "uavdata", _bundle_arrays(lambda a: a["blocked"].fill(True)), "blocked: every cell is blocked"),
    Case(
        "show building id -7",
        "uavdata",
        _bundle_arrays(_set("building_id", (0, 0), -7)),
        "building_id: building id outside -1 .. -1 (the manifest's 0 buildings)",
    ),
    Case("show cell centres moved", "uavdata", _bundle_arrays(_set("x_m", (3,), 1e4)), "x_m: cell centre 10000.0 at 3 is off"),
    Case("show npy header of 4 TB", "uavdata", _huge_header, "sinr_db: array float32[1048576, 1024, 1024], expected float32[2"),
    Case(
        "show user id out of range", "uavdata", _users_edit("user", 1, 7), "users.parquet: user: user ids are not 0..1 in order"
    ),
    Case("show user cell off the grid", "uavdata", _users_edit("ix", 0, 99), "users.parquet: ix: row 0: cell 99 is off the grid"),
    Case(
        "show manifest city renamed",
        "uavdata",
        _manifest_edit("city", "elsewhere"),
        "manifest.json: city: city 'elsewhere' is not",
    ),
    Case(
        "show manifest version edited",
        "uavdata",
        _manifest_edit("version", "0123456789ab"),
        "version: version 0123456789ab is not its folder",
    ),
    Case(
        "show latest escapes the root", "uavdata", _latest("../../.."), "city/latest: latest: '../../..' is not a bundle version"
    ),
    Case("show latest is garbage", "uavdata", _latest("\x00\x01zz"), "is not a bundle version (12 hex digits)"),
    Case(
        "show tampered users table",
        "uavdata",
        lambda w: [
            "show",
            "city",
            "--root",
            str((lambda b: ((b / "users.parquet").write_bytes(b"junk"), w.root())[1])(w.bundle())),
            "--out",
            str(w.tmp / "s.png"),
        ],
        "users.parquet: sha256: sha256",
    ),
    Case(
        "show garbage bundle manifest",
        "uavdata",
        lambda w: [
            "show",
            "city",
            "--root",
            str((lambda b: ((b / "manifest.json").write_text("[1, 2]"), w.root())[1])(w.bundle())),
        ],
        "manifest.json: schema_version: bundle schema version None",
    ),
    Case(
        "show to a FIFO",  # never a device of the machine's: a node of the probe's own
        "uavdata",
        lambda w: (
            __import__("os").mkfifo(w.tmp / "out.png")
            or ["show", "city", "--root", str(w.root()), "--out", str(w.tmp / "out.png")]
        ),
        "exists and is not a regular file: refusing to replace it",
    ),
    # -- simulate ----------------------------------------------------------------------------------
    Case(
        "simulate --name ../..",
        "uavdata",
        lambda w: ["simulate", "procedural:tiny", "--name", "../..", "--out", str(w.tmp / "raw")],
        "city name: '../..' is not a safe name",
    ),
    Case(
        "simulate --name /abs/path",
        "uavdata",
        lambda w: ["simulate", "procedural:tiny", "--name", str(w.tmp / "victim"), "--out", str(w.tmp)],
        "is not a safe name",
    ),
    Case(
        "simulate over a folder it did not make",
        "uavdata",
        _simulate_victim,
        "exists and is not a simulated city made by uavplace (it has no simulation.json)",
    ),
    Case(
        "simulate unknown preset",
        "uavdata",
        lambda w: ["simulate", "procedural:huge", "--name", "x", "--out", str(w.tmp / "raw")],
        "unknown procedural preset or style 'huge'",
    ),
    Case(
        "simulate missing source file",
        "uavdata",
        lambda w: ["simulate", str(w.tmp / "none.city"), "--name", "x", "--out", str(w.tmp / "raw")],
        "none.city: source: no such file",
    ),
    Case(
        "simulate a bad style size",
        "uavdata",
        lambda w: ["simulate", "procedural:perimeter:abc", "--name", "x", "--out", str(w.tmp / "raw")],
        "size 'abc': expected WIDTHxHEIGHT in metres",
    ),
    Case(
        "simulate a tiny style size",
        "uavdata",
        lambda w: ["simulate", "procedural:grid:10x10", "--name", "x", "--out", str(w.tmp / "raw")],
        "size 10 x 10 m: each side must be 48 to 5000 m",
    ),
    Case(
        "simulate sources and --count",
        "uavdata",
        lambda w: ["simulate", "procedural:tiny", "procedural:test", "--count", "2", "--name", "x", "--out", str(w.tmp / "raw")],
        "count: give several SOURCES or --count N, not both",
    ),
    Case(
        "simulate --crop on a procedural city",
        "uavdata",
        lambda w: ["simulate", "procedural:tiny", "--crop", "0,0,50,50", "--name", "x", "--out", str(w.tmp / "raw")],
        "crop: --crop applies to real geometry",
    ),
    Case(
        "simulate an unknown Sionna scene",
        "uavdata",
        lambda w: ["simulate", "sionna:atlantis", "--name", "x", "--out", str(w.tmp / "raw")],
        "sionna:atlantis: source: ",
    ),
    Case("simulate a scene outside its folder", "uavdata", _scene_escape, "points outside the scene's folder"),
    Case(
        "ingest PLY header of 2e9 vertices",
        "uavdata",
        lambda w: w.add_file("b.ply", PLY_HEAD.format(n=2_000_000_000, fmt="binary_little_endian") + "\0" * 64),
        "b.ply:3: vertex: declares 2,000,000,000 vertex rows of at least 12 bytes; the file holds 64",
    ),
    Case(
        "ingest PLY face index out of range",
        "uavdata",
        lambda w: w.add_file("b.ply", PLY_HEAD.format(n=4, fmt="ascii") + "0 0 0\n10 0 0\n0 10 20\n10 10 20\n3 0 1 2\n3 1 3 9\n"),
        "b.ply: unreadable mesh (IndexError: index 9 is out of bounds",
    ),
    # -- report ------------------------------------------------------------------------------------
    Case(
        "report unknown dataset",
        "uavrl",
        lambda w: [
            "report",
            "--dataset",
            "nosuchcity",
            "--root",
            str(w.root()),
            "--run",
            str(w.agent()),
            "--out",
            str(w.tmp / "r"),
        ],
        "no city 'nosuchcity' is built here",
    ),
    Case(
        "report run without best.pt",
        "uavrl",
        lambda w: w.report("--run", str((w.tmp / "empty_run").mkdir() or w.tmp / "empty_run")),
        "empty_run: no checkpoints/best.pt",
    ),
    Case(
        "report pickle payload in best.pt",
        "uavrl",
        lambda w: (lambda a: w.payload(a / "checkpoints" / "best.pt") and w.report("--run", str(a)))(w.agent()),
        "best.pt: pickle: refused: the checkpoint holds Python objects other than tensors",
    ),
    Case("report garbage best.pt", "uavrl", _agent_file(b"garbage"), "best.pt: not a readable PyTorch checkpoint"),
    Case(
        "report agent trained on the test bundle renamed",
        "uavrl",
        lambda w: w.report("--run", str(w.agent("renamed", w.bundle().name))),
        "trained or selected on bundle",
    ),
    Case(
        "report a run whose run.json is a FIFO",  # never waited on, never taken for a bare checkpoint folder
        "uavrl",
        lambda w: (lambda a: (a / "run.json").unlink() or __import__("os").mkfifo(a / "run.json") or w.report("--run", str(a)))(
            w.agent()
        ),
        "run.json: not a regular file: a run's record",
    ),
    Case(
        "report a run twice",
        "uavrl",
        lambda w: (lambda a: w.report("--run", str(a), "--run", str(a) + "/"))(w.agent()),
        "is given twice: give each run once",
    ),
    Case(
        "report a run and a link to it",
        "uavrl",
        lambda w: (lambda a: (w.tmp / "link").symlink_to(a) or w.report("--run", str(a), "--run", str(w.tmp / "link")))(
            w.agent()
        ),
        "are one run: give each run once",
    ),
    Case(
        "report two runs of one folder name",
        "uavrl",
        lambda w: (lambda a, b: w.report("--run", str(a), "--run", str(b)))(
            w.agent(), __import__("shutil").copytree(w.agent(), w.tmp / "other" / "agent")
        ),
        "are both named agent: their methods would share a name",
    ),
    Case(
        "report a group of one run twice",
        "uavrl",
        lambda w: (lambda a: w.report("--run", str(a), "--group", f"g={a},{a}"))(w.agent()),
        "--group g: ",
    ),
    Case(
        "report a group named genie",
        "uavrl",
        lambda w: (lambda a: w.report("--run", str(a), "--group", f"genie={a}"))(w.agent()),
        "--group genie: the name of a method of the report",
    ),
    Case(
        "report a group given twice",
        "uavrl",
        lambda w: (lambda a: w.report("--run", str(a), "--group", f"g={a}", "--group", f"g={a}"))(w.agent()),
        "--group g is given twice",
    ),
    Case(
        "tracking report one city at two versions",
        "uavrl",
        lambda w: w.report("--task", "tracking", "--dataset", "city@0123456789ab"),
        "--dataset names city more than once (city, city@0123456789ab): one report per city",
    ),
    Case(
        "report one city twice",
        "uavrl",
        lambda w: w.report("--dataset", "city@0123456789ab"),
        "--dataset names city more than once (city, city@0123456789ab): one report per city",
    ),
    Case(
        "report best.pt holding a list",
        "uavrl",
        _agent_file(lambda w: [1, 2]),
        "best.pt: a checkpoint holds a dict, this one a list",
    ),
    Case(
        "report best.pt without weights",
        "uavrl",
        _agent_file(lambda w: {"config": {}}),
        "best.pt: online: checkpoint lacks online",
    ),
    Case(
        "report best.pt with a bad config",
        "uavrl",
        _agent_file(lambda w: {"online": {}, "config": {"bogus": 1}}),
        "best.pt: bogus: checkpoint config: Extra inputs are not permitted",
    ),
    Case(
        "report weights that do not fit",
        "uavrl",
        _agent_file(lambda w: {"online": {}, "config": {"preset": "fast"}}),
        "best.pt: online: weights do not fit",
    ),
    Case(
        "report malformed run.json",
        "uavrl",
        lambda w: (lambda a: (a / "run.json").write_text("{not json") and w.report("--run", str(a)))(w.agent()),
        "run.json: json: Invalid JSON",
    ),
    Case(
        "report agent trained in the test city",
        "uavrl",
        lambda w: w.report("--run", str(w.agent(trained_on="city"))),
        "datasets: was trained in city, the test city",
    ),
    Case(
        "report --out over a thesis",
        "uavrl",
        _report_out_victim,
        "exists and is not a report made by uavplace (it has no report.json)",
    ),
    Case(
        "report --out over a file",
        "uavrl",
        lambda w: w.report("--run", str(w.agent()), "--out", str((w.tmp / "f.txt").write_text("x") and w.tmp / "f.txt")),
        "is a file",
    ),
    Case("report zero episodes", "uavrl", lambda w: w.report("--episodes", "0"), "Invalid value for '--episodes'"),
    Case(
        "report agents dir with a payload",
        "uavrl",
        lambda w: (lambda a: w.payload(a / "checkpoints" / "best.pt") and w.report("--agents-dir", str(a.parent)))(w.agent()),
        "refused: the checkpoint holds Python objects",
    ),
    # -- train -------------------------------------------------------------------------------------
    Case(
        "train unknown dataset",
        "uavrl",
        lambda w: ["train", "--dataset", "nowhere", "--root", str(w.root()), "--out", str(w.tmp / "runs")],
        "nowhere: dataset: no ingested city or corpus of that name",
    ),
    Case(
        "train --name ../x",
        "uavrl",
        lambda w: ["train", "--dataset", "city", "--root", str(w.root()), "--out", str(w.tmp / "runs"), "--name", "../x"],
        "run name: '../x' is not a safe name",
    ),
    Case(
        "train resume without run.json",
        "uavrl",
        lambda w: ["train", "--resume", str((w.tmp / "r").mkdir() or w.tmp / "r"), "--root", str(w.root())],
        "run.json: no run.json",
    ),
    Case(
        "train resume a pickle payload",
        "uavrl",
        lambda w: ["train", "--resume", str(w.run_folder(payload=True)), "--root", str(w.root())],
        "networks.pt: pickle: refused",
    ),
    Case(
        "train resume an old pickled last.pt",
        "uavrl",
        lambda w: ["train", "--resume", str(w.run_folder(old_last=True)), "--root", str(w.root())],
        "no complete checkpoint to resume from (an old pickled last.pt is not loaded",
    ),
    Case(
        "train resume garbage networks",
        "uavrl",
        lambda w: ["train", "--resume", str(w.run_folder(networks=b"junk")), "--root", str(w.root())],
        "networks.pt: not a readable PyTorch checkpoint",
    ),
    Case(
        "train resume a step of 1e12",
        "uavrl",
        lambda w: ["train", "--resume", str(w.run_folder(step=1e12)), "--root", str(w.root())],
        "checkpoint.json: step: step 1,000,000,000,000 is beyond the run's 68 steps",
    ),
    Case(
        "train unknown preset",
        "uavrl",
        lambda w: ["train", "--dataset", "city", "--preset", "huge"],
        "Invalid value for '--preset'",
    ),
    Case("train without a dataset", "uavrl", lambda w: ["train"], "give --dataset CITY (or --resume RUN_FOLDER)"),
    Case(
        "baselines unknown dataset",
        "uavrl",
        lambda w: ["baselines", "--dataset", "nosuch", "--root", str(w.root())],
        "no city 'nosuch' is built here",
    ),
    # found by the second probe pass (tests/probes.py, experiments/log/probes.md)
    Case(
        "build a grid past the limit grid_cells",
        "uavdata",
        lambda w: ["build", "--root", str(w.root()), "--grid", "0.001m", "--alt", "10", "--quiet"],
        "is over the limit grid_cells = 4,000,000; raise it with `--limit grid_cells=VALUE`",
    ),
    Case(
        "build a grid of 1e-300 m",
        "uavdata",
        lambda w: ["build", "--root", str(w.root()), "--grid", "1e-300m", "--alt", "10", "--quiet"],
        "inf is over the limit grid_cells",
    ),
    Case(
        "build an infinite noise",
        "uavdata",
        lambda w: ["build", "--root", str(w.root()), "--grid", "4m", "--alt", "10", "--noise-dbm", "inf", "--quiet"],
        "Invalid value for '--noise-dbm': 'inf' is not a finite number",
    ),
    Case(
        "build a negative seed",
        "uavdata",
        lambda w: ["build", "--root", str(w.root()), "--grid", "4m", "--alt", "10", "--seed", "-1"],
        "Invalid value for '--seed'",
    ),
    Case(
        "a limit of nan",
        "uavdata",
        lambda w: ["--limit", "grid_cells=nan", "list"],
        "grid_cells: Input should be a finite number",
    ),
    Case("an unknown limit", "uavrl", lambda w: ["--limit", "cells=3", "datasets"], "expected NAME=VALUE with NAME one of"),
    Case(
        "train a replay past the limit replay_bytes",
        "uavrl",
        _train_with("buffer_size=1000000000000"),
        "is over the limit replay_bytes",
    ),
    Case(
        "train a network past the limit network_params",
        "uavrl",
        _train_with("hidden=1000000000"),
        "is over the limit network_params",
    ),
    Case(
        "baselines at a P_T no cell is below",
        "uavrl",
        lambda w: ["baselines", "--dataset", "city", "--root", str(w.root()), "--episodes", "4", "--p-t-db", "-100"],
        "city: p_t_db: no user has a start cell at P_T = -100 dB",
    ),
    Case(
        "city face of -4 vertices",
        "uavdata",
        lambda w: w.add_file("b.city", _city_file(SQUARE_ROOF.replace("nVertices 4", "nVertices -4"))),
        "b.city:5: nVertices: nVertices -4: a count of at least 1",
    ),
    Case(
        "simulate 1e300 rays",
        "uavdata",
        lambda w: ["simulate", "procedural:tiny", "--name", "t", "--out", str(w.tmp / "sim"), "--samples", "1e300"],
        "--samples: samples: value: 1e+300 is over the limit samples = 10,000,000,000",
    ),
    Case(
        "train --set seed, which --seed would override",
        "uavrl",
        _train_with("seed=3"),
        "--set seed and --seed set the same field: give it once, with the option",
    ),
    Case(
        "report of a run whose run.json holds another config than best.pt",
        "uavrl",
        lambda w: w.report("--run", str(_edit_json(w.agent() / "run.json", lambda d: d["config"].update(hidden=7)))),
        "run.json: config: its config is not the one checkpoints/best.pt was trained with (hidden differ)",
    ),
]

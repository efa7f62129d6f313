"""Real geometry as a simulate source: Mitsuba scenes (Sionna's etoile and florence), tiers, courtyards, crops."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest
import shapely
import trimesh

from uavplace.ingest.buildings import buildings_tables
from uavplace.ingest.mitsuba import read_mitsuba
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas import InputError
from uavplace.simulate.insite import write_city
from uavplace.simulate.scene import extrude
from uavplace.simulate.sources import load_geometry

SCENE = """<scene version="2.1.0">
  <bsdf type="itu-radio-material" id="concrete"><string name="type" value="concrete"/></bsdf>
  {shapes}
</scene>
"""


def _shape(sid: str, file: str, extra: str = "") -> str:
    return f'<shape type="ply" id="{sid}"><string name="filename" value="{file}"/>{extra}<ref id="concrete" name="bsdf"/></shape>'


def _tower_on_podium(folder):
    """A 40 x 40 m podium 20 m tall with a 10 x 10 m tower to 60 m, its faces split over two material meshes,
    and a ground plane: one building, two tiers."""
    podium = extrude(shapely.box(0, 0, 40, 40).difference(shapely.box(15, 15, 25, 25)), 0.0, 20.0)
    tower = extrude(shapely.box(15, 15, 25, 25), 0.0, 60.0)
    whole = trimesh.util.concatenate([podium, tower])
    whole.merge_vertices()
    half = len(whole.faces) // 2  # the same body, written as two meshes (as a material split does)
    (folder / "meshes").mkdir(parents=True)
    trimesh.Trimesh(whole.vertices, whole.faces[:half], process=False).export(folder / "meshes" / "a.ply")
    trimesh.Trimesh(whole.vertices, whole.faces[half:], process=False).export(folder / "meshes" / "b.ply")
    ground = trimesh.Trimesh([[-50, -50, 0], [90, -50, 0], [90, 90, 0], [-50, 90, 0]], [[0, 1, 2], [0, 2, 3]])
    ground.export(folder / "meshes" / "ground.ply")
    shapes = _shape("a", "meshes/a.ply") + _shape("b", "meshes/b.ply") + _shape("ground", "meshes/ground.ply")
    (folder / "scene.xml").write_text(SCENE.format(shapes=shapes))
    return folder / "scene.xml"


def test_a_tower_on_a_podium_is_two_tiers_of_one_building(tmp_path):
    scene = read_mitsuba(_tower_on_podium(tmp_path / "s"))
    assert len(scene.buildings) == 1 and scene.num_shapes == 3
    assert [r.reason for r in scene.rejected] == ["flat body (0.00 m tall): ground"]
    parts = sorted(scene.buildings[0].parts, key=lambda p: p.roof_z_m)
    assert [p.roof_z_m for p in parts] == [20.0, 60.0]
    assert parts[0].footprint.area == pytest.approx(40 * 40 - 10 * 10) and parts[1].footprint.area == pytest.approx(100)
    cropped = read_mitsuba(tmp_path / "s" / "scene.xml", crop=(30, 30, 100, 100))
    assert len(cropped.buildings) == 1 and [p.roof_z_m for p in cropped.buildings[0].parts] == [20.0]
    assert read_mitsuba(tmp_path / "s" / "scene.xml", crop=(200, 200, 300, 300)).num_cropped == 1


@pytest.mark.parametrize(
    "shapes,message",
    [
        (_shape("x", "../outside.ply"), "points outside the scene's folder"),
        (_shape("x", "meshes/a.ply", '<transform name="to_world"><scale value="2"/></transform>'), "has a transform"),
        (_shape("x", "meshes/none.ply"), "no such mesh file"),
        (  # a mesh placed by an instance's translate: used untranslated once
            '<shapegroup id="g">' + _shape("x", "meshes/a.ply") + '</shapegroup><shape type="instance" id="i">'
            '<ref id="g"/><transform name="to_world"><translate x="500"/></transform></shape>',
            "<shapegroup> is not supported",
        ),
        ('<include filename="other.xml"/>', "<include> is not supported"),
        (  # Mitsuba 3's own spelling: the group is a shape of type shapegroup, placed by an instance with a transform
            '<shape type="shapegroup" id="g">' + _shape("x", "meshes/a.ply") + '</shape><shape type="instance" id="i">'
            '<ref id="g"/><transform name="to_world"><translate x="500"/></transform></shape>',
            '<shape type="shapegroup"> is not supported',
        ),
        (
            _shape("a", "meshes/a.ply") + '<shape type="instance" id="i"><ref id="a"/>'
            '<transform name="to_world"><translate x="500"/></transform></shape>',
            '<shape type="instance"> is not supported',
        ),
    ],
)
def test_unsafe_or_unsupported_scenes_are_refused(tmp_path, shapes, message):
    _tower_on_podium(tmp_path / "s")
    (tmp_path / "outside.ply").write_bytes((tmp_path / "s" / "meshes" / "a.ply").read_bytes())
    xml = tmp_path / "s" / "bad.xml"
    xml.write_text(SCENE.format(shapes=shapes))
    with pytest.raises(InputError, match=message):
        read_mitsuba(xml)
    declared = '<!DOCTYPE scene [<!ENTITY a "aaaa">]>' + SCENE.format(shapes=_shape("a", "meshes/a.ply"))
    for encoding in ("utf-8", "utf-16"):  # after decoding: UTF-16 bytes hide '<!ENTITY' from a byte search
        header = "" if encoding == "utf-8" else f'<?xml version="1.0" encoding="{encoding}"?>'
        xml.write_bytes((header + declared).encode(encoding))
        with pytest.raises(InputError, match="DOCTYPE"):
            read_mitsuba(xml)
    xml.write_bytes(('<?xml version="1.0" encoding="utf-16-le"?>' + declared).encode("utf-16-le"))  # no byte-order mark
    with pytest.raises(InputError, match="unsupported text encoding"):
        read_mitsuba(xml)


def test_courtyards_survive_the_city_export(tmp_path):
    """A perimeter block with a courtyard: the .city keeps the hole, so the height map leaves it open."""
    block = shapely.box(0, 0, 60, 60).difference(shapely.box(20, 20, 40, 40))
    (tmp_path / "c").mkdir()
    write_city(tmp_path / "c" / "c.city", [[(block, 0.0, 25.0), (shapely.box(0, 0, 10, 10), 0.0, 40.0)]])
    _, manifest, _ = ingest_city(tmp_path / "c", tmp_path / "p")
    parts = pq.read_table(tmp_path / "p" / "c" / "ingested" / "building_parts.parquet").to_pandas()
    assert manifest.counts["buildings"] == 1 and len(parts) == 2
    footprints = shapely.from_wkb(parts["footprint_wkb"].to_numpy())
    assert footprints[0].area == pytest.approx(block.area) and len(footprints[0].interiors) == 1
    assert sorted(parts["roof_z_m"]) == [25.0, 40.0]


def test_sionna_scenes_crop_into_tiered_cities():
    pytest.importorskip("sionna.rt")
    box = (-200.0, -200.0, 200.0, 200.0)
    blocks, bounds, described = load_geometry("sionna:etoile", 0, crop=box)
    assert bounds == box and "cropped to x -200..200" in described
    buildings = {b.building for b in blocks}
    assert 20 < len(buildings) < len(blocks)  # city blocks, most of several roof tiers
    heights = np.array([b.roof_z_m - b.base_z_m for b in blocks])
    assert 3 < np.median(heights) < 40 and heights.max() <= 60
    inside = shapely.box(*box)
    assert all(inside.covers(b.footprint) for b in blocks)
    b_table, _, _ = buildings_tables(read_mitsuba(__import__("sionna.rt").rt.scene.florence, crop=box).buildings)
    assert b_table.num_rows > 30

"""CityJSON buildings (ingest/cityjson.py): a file of each form (0.2's CityModel with per-surface semantics, 1.x and 2.0
with a transform, Solid semantics and BuildingParts, LoD1 without semantics), the real districts shipped in
data/geometry/, and refusals that name the file and the field."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.conftest import REPO, write_grid_city
from uavplace.ingest.cityjson import read_cityjson
from uavplace.schemas import InputError

#: A box 10 x 20 m from (0, 0), ground at z = 1, flat roof at z = 13, and a pitched part from x = 10 to 16 whose roof
#: rises from 7 (eaves) to 11 (ridge): its tier at the mean of its roof's vertices, 9.
BOX = [[0, 0, 1], [10, 0, 1], [10, 20, 1], [0, 20, 1], [0, 0, 13], [10, 0, 13], [10, 20, 13], [0, 20, 13]]
SHED = [[10, 0, 1], [16, 0, 1], [16, 20, 1], [10, 20, 1], [10, 0, 11], [16, 0, 7], [16, 20, 7], [10, 20, 11]]


def _solid(offset: int) -> list:
    """The six faces of a prism of vertices ``offset..offset+7`` (bottom 0-3, top 4-7)."""
    o = offset
    bottom, top = [o + 3, o + 2, o + 1, o], [o + 4, o + 5, o + 6, o + 7]
    walls = [[o + i, o + (i + 1) % 4, o + 4 + (i + 1) % 4, o + 4 + i] for i in range(4)]
    return [[bottom], [top], *[[w] for w in walls]]


def _v2(version: str = "2.0") -> dict:
    scale = 0.001
    vertices = [[round(c / scale) for c in v] for v in BOX + SHED]
    types = ["GroundSurface", "RoofSurface", "WallSurface", "WallSurface", "WallSurface", "WallSurface"]
    semantics = {"surfaces": [{"type": t} for t in types], "values": [[0, 1, 2, 3, 4, 5]]}
    return {
        "type": "CityJSON",
        "version": version,
        "transform": {"scale": [scale] * 3, "translate": [1000.0, 2000.0, 0.0]},
        "CityObjects": {
            "b1": {"type": "Building", "children": ["b1-1", "b1-2"]},
            "b1-1": {"type": "BuildingPart", "parents": ["b1"], "geometry": [
                {"type": "Solid", "lod": "2.2", "boundaries": [_solid(0)], "semantics": semantics}]},
            "b1-2": {"type": "BuildingPart", "parents": ["b1"], "geometry": [
                {"type": "Solid", "lod": "2.2", "boundaries": [_solid(8)], "semantics": semantics}]},
            "t": {"type": "TINRelief", "geometry": []},
        },
        "vertices": vertices,
    }  # fmt: skip


def _v02() -> dict:
    """The 0.2 form: a CityModel, vertices as they are, a MultiSurface per semantic list, TerrainHeight."""
    faces = _solid(0)
    types = ["GroundSurface", "RoofSurface", "WallSurface", "WallSurface", "WallSurface", "WallSurface"]
    return {
        "type": "CityModel",
        "version": "http://www.cityjson.org/version/0.2",
        "CityObjects": {
            "{A}": {"type": "Building", "attributes": {"TerrainHeight": "0.5"}, "geometry": [
                {"type": "MultiSurface", "lod": 2, "boundaries": faces, "semantics": [{"type": t} for t in types]}]},
        },
        "vertices": BOX,
    }  # fmt: skip


def _lod1() -> dict:
    """LoD1 without semantics (1.1): the roof is the face above the ground."""
    return {
        "type": "CityJSON",
        "version": "1.1",
        "transform": {"scale": [1, 1, 1], "translate": [0, 0, 0]},
        "CityObjects": {"x": {"type": "Building", "geometry": [{"type": "Solid", "lod": "1", "boundaries": [_solid(0)]}]}},
        "vertices": BOX,
    }


def _write(tmp_path, doc: dict, name: str = "city.json"):  # noqa: ANN202
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def test_a_file_of_each_version_gives_its_buildings(tmp_path):
    records, rejected, how = read_cityjson(_write(tmp_path, _v2()))
    parts = sorted((p for r in records for p in r.parts), key=lambda p: p.roof_z_m)
    assert [r.name for r in records] == ["b1-1", "b1-2"] and len(rejected) == 1  # the relief, counted
    assert [p.roof_z_m - p.base_z_m for p in parts] == pytest.approx([8.0, 12.0])  # the shed at its roof's mean
    assert parts[1].footprint.area == pytest.approx(200.0) and parts[0].footprint.area == pytest.approx(120.0)
    assert parts[1].footprint.bounds == pytest.approx((1000.0, 2000.0, 1010.0, 2020.0))  # under the transform
    assert "lowest vertex" in how
    for version in ("1.0", "1.1"):
        assert len(read_cityjson(_write(tmp_path, _v2(version)))[0]) == 2
    (old,), _, how = read_cityjson(_write(tmp_path, _v02()))
    assert old.parts[0].base_z_m == 0.5 and old.parts[0].roof_z_m == 13.0 and "1 by TerrainHeight" in how
    (flat,), _, _ = read_cityjson(_write(tmp_path, _lod1()))
    assert flat.parts[0].roof_z_m - flat.parts[0].base_z_m == 12.0


def test_the_shipped_districts_read():
    """The two districts of data/geometry/ (CityJSON 0.2 and 0.8): every building read or counted as left out."""
    for name, version, objects in (("rotterdam-delfshaven.json", "0.2", 853), ("denhaag-01.json", "0.8", 2498)):
        path = REPO / "data" / "geometry" / name
        doc = json.loads(path.read_text())
        assert version in doc["version"] and len(doc["CityObjects"]) == objects
        records, rejected, _ = read_cityjson(path)
        with_geometry = sum(1 for o in doc["CityObjects"].values() if o.get("geometry"))
        assert len(records) + len(rejected) == with_geometry + sum(
            1 for o in doc["CityObjects"].values() if o["type"] not in ("Building", "BuildingPart") and not o.get("geometry")
        )
        heights = np.array([p.roof_z_m - p.base_z_m for r in records for p in r.parts])
        assert len(records) > 0.9 * with_geometry and 2 < np.median(heights) < 20 and heights.max() < 80


def test_bad_cityjson_is_refused_naming_the_file_and_field(tmp_path):
    with pytest.raises(InputError, match="not CityJSON"):
        read_cityjson(_write(tmp_path, {"type": "FeatureCollection", "features": []}))
    bad = _v2()
    bad["CityObjects"]["b1-1"]["geometry"][0]["boundaries"][0][0][0] = [0, 1, 99]
    with pytest.raises(InputError, match="indexes no vertex") as err:
        read_cityjson(_write(tmp_path, bad))
    assert "city.json" in str(err.value)
    bad = _v2()
    bad["transform"] = {"scale": [1, 1]}
    with pytest.raises(InputError, match="transform"):
        read_cityjson(_write(tmp_path, bad))


def test_simulate_reads_cityjson_and_says_how_heights_were_taken(tmp_path):
    from uavplace.simulate.sources import load_geometry

    blocks, bounds, described = load_geometry(str(_write(tmp_path, _v2())), 0)
    assert len(blocks) == 2 and bounds == pytest.approx((1000.0, 2000.0, 1016.0, 2020.0))
    assert "heights: CityJSON" in described and "mean height of its vertices" in described


def test_ingest_and_simulate_read_through_one_reader_table(tmp_path):
    """The reader table (ingest/formats.py): a CityJSON file dropped in a city folder is ingested as buildings, a JSON
    file that is neither CityJSON nor GeoJSON is listed and passed over, and `uavdata simulate` picks the same entry
    for each geometry file that ingest does."""
    from uavplace.ingest.formats import FORMATS, format_of, geometry_format
    from uavplace.ingest.pipeline import ingest_city

    city = write_grid_city(tmp_path / "c")
    for f in city.glob("*.city"):
        f.unlink()
    _write(city, _v2())  # city.json
    (city / "notes.json").write_text(json.dumps({"author": "me", "CityObjects": "not a model"}))
    _, manifest, report = ingest_city(city, tmp_path / "out")
    kinds = {f.path: (f.kind, f.status) for f in report.files}
    assert kinds["city.json"][0] == "cityjson" and kinds["notes.json"][0] == "other"
    assert manifest.counts["buildings"] == 2
    message = next(f.message for f in report.files if f.path == "city.json")
    assert message.startswith("2 building(s); heights: CityJSON")
    geo = city / "b.geojson"
    geo.write_text(json.dumps({"type": "FeatureCollection", "features": []}))
    also_geo = city / "b2.json"
    also_geo.write_text(json.dumps({"type": "FeatureCollection", "features": []}))
    for path in (city / "city.json", geo, also_geo):
        assert format_of(path) is geometry_format(path)
    assert geometry_format(also_geo).kind == "geojson"
    with pytest.raises(InputError, match="not a geometry format uavplace reads"):
        geometry_format(city / "notes.json")
    assert {f.kind for f in FORMATS if f.read} == {"city", "geojson", "cityjson", "mesh", "mitsuba"}

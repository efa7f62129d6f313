"""Keyword files (.city, .ter, .txrx, .setup), GeoJSON and meshes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely
import trimesh

from uavplace.ingest.buildings import buildings_tables
from uavplace.ingest.geojson import read_geojson
from uavplace.ingest.mesh import read_mesh
from uavplace.ingest.wireless_insite.city import read_city, read_terrain
from uavplace.ingest.wireless_insite.keyword import parse_keyword_file
from uavplace.ingest.wireless_insite.setup import read_setup
from uavplace.ingest.wireless_insite.txrx import read_txrx
from uavplace.schemas import InputError


def test_rosslyn_buildings(rosslyn):
    b, parts, rejected = buildings_tables(read_city(rosslyn / "Rosslyn.city"))
    d = b.to_pandas()
    assert len(d) == 29 and len(parts) == 67 and rejected == []
    assert d.height_m.min() == pytest.approx(9.0) and d.height_m.max() == pytest.approx(100.95, abs=1e-3)
    assert (d.base_z_m == 0).all()
    first = d.iloc[0]
    assert first["name"] == "small building #2" and first.source == f"{rosslyn / 'Rosslyn.city'}:65"
    fp = shapely.from_wkb(first.footprint_wkb)
    assert fp.is_valid and fp.area == pytest.approx(476, rel=0.01)
    # each building's footprint holds all of its parts
    p = parts.to_pandas()
    for bid, group in p.groupby("building_id"):
        whole = shapely.from_wkb(d.footprint_wkb[bid])
        assert all(whole.buffer(1e-6).contains(shapely.from_wkb(w)) for w in group.footprint_wkb)
        assert group.roof_z_m.max() == pytest.approx(d.roof_z_m[bid])


def test_boxes_buildings(boxes):
    b, _, _ = buildings_tables(read_city(boxes / "newCity(2).city"))
    d = b.to_pandas()
    assert len(d) == 6
    assert sorted(d.roof_z_m.round(3)) == [15.0, 20.0, 20.0, 25.0, 25.0, 35.0]
    first = shapely.from_wkb(d.footprint_wkb[0])
    assert first.bounds == (10.0, 110.0, 60.0, 190.0) and first.area == pytest.approx(4000)


def test_terrain(rosslyn, boxes):
    v, t = read_terrain(rosslyn / "Rosslyn_DTED.ter")
    assert v.shape == (86, 3) and t.shape == (119, 3)
    assert v[:, 2].min() == pytest.approx(16.366584) and v[:, 2].max() == pytest.approx(58.0)
    mesh = trimesh.Trimesh(v, t, process=False)
    assert mesh.area > 0
    v, t = read_terrain(boxes / "newTerrain(3).ter")
    assert t.shape == (2, 3) and trimesh.Trimesh(v, t).area == pytest.approx(200 * 307.8, rel=0.01)


CITY = """Format type:keyword version: 1.1.0
begin_<city> Synthetic
begin_<structure_group>
begin_<structure> tower
begin_<sub_structure> 1
begin_<face> roof
nVertices 4
0.000e+000 0.000e+000 3.000e+001
1.000e+001 0.000e+000 3.000e+001
1.000e+001 8.000e+000 3.000e+001
0.000e+000 8.000e+000 3.000e+001
end_<face>
begin_<face> wall
nVertices 4
0.0 0.0 0.0
10.0 0.0 0.0
10.0 0.0 3.0e+01
0.0 0.0 3.0e+01
end_<face>
end_<sub_structure>
begin_<sub_structure> 2
begin_<face> w1
nVertices 4
10.0 0.0 0.0
14.0 0.0 0.0
14.0 0.0 5.0e+00
10.0 0.0 5.0e+00
end_<face>
begin_<face> w2
nVertices 4
14.0 0.0 0.0
14.0 8.0 0.0
14.0 8.0 5.0e+00
14.0 0.0 5.0e+00
end_<face>
begin_<face> w3
nVertices 4
14.0 8.0 0.0
10.0 8.0 0.0
10.0 8.0 5.0e+00
14.0 8.0 5.0e+00
end_<face>
begin_<face> w4
nVertices 4
10.0 8.0 0.0
10.0 0.0 0.0
10.0 0.0 5.0e+00
10.0 8.0 5.0e+00
end_<face>
end_<sub_structure>
end_<structure>
end_<structure_group>
end_<city>
"""


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_city_exponents_crlf_and_walls_only(tmp_path, newline):
    path = tmp_path / "s.city"
    path.write_bytes(CITY.replace("\n", newline).encode())
    b, parts, _ = buildings_tables(read_city(path))
    assert len(b) == 1 and len(parts) == 2
    row = b.to_pylist()[0]
    assert row["roof_z_m"] == 30.0 and row["n_parts"] == 2
    assert shapely.from_wkb(row["footprint_wkb"]).area == pytest.approx(14 * 8)
    # the tier with walls only gets its footprint from the walls' enclosure
    tier = parts.to_pylist()[1]
    assert shapely.from_wkb(tier["footprint_wkb"]).area == pytest.approx(4 * 8) and tier["roof_z_m"] == 5.0


@pytest.mark.parametrize(
    "old,new,line,field,words",
    [
        ("nVertices 4\n0.000e+000 0.000e+000", "nVertices 2\n0.000e+000 0.000e+000", 7, "nVertices", "face has 2 vertices"),
        ("10.0 0.0 0.0\n10.0 0.0 3.0e+01", "10.0 zero 0.0\n10.0 0.0 3.0e+01", 16, "vertex", "holds text"),
        ("end_<city>\n", "", 59, None, "never closed"),
        ("end_<face>\nbegin_<face> wall", "end_<faces>\nbegin_<face> wall", 12, None, "end_<faces> closes face"),
    ],
)
def test_bad_city(tmp_path, old, new, line, field, words):
    path = tmp_path / "bad.city"
    assert old in CITY
    path.write_text(CITY.replace(old, new, 1))
    with pytest.raises(InputError) as exc:
        read_city(path)
    err = exc.value
    assert (err.path, err.field) == (str(path), field) and words in err.message
    if words != "never closed":
        assert err.line == line
    else:
        assert err.line is not None


def test_txrx_grid_and_points(deepmimo, boxes, rosslyn):
    sets = {s.project_id: s for s in read_txrx(deepmimo / "insite.txrx")}
    grid = sets[4]
    assert grid.kind == "grid" and grid.name == "UE_grid" and grid.grid_shape == (81, 57)
    assert grid.spacing_m == 2.5 and grid.vertices_m[0] == pytest.approx((-100.370016434637364, -70.998860641382635, 2.0))
    assert sets[1].is_transmitter and sets[1].vertices_m[0] == pytest.approx((42.682474834960885, 5.727145023178309, 6.0))
    box = {s.project_id: s for s in read_txrx(boxes / "sim1.txrx")}
    assert [box[i].tx_power_dbm for i in (4, 5, 6)] == [30.0, 30.0, 30.0]
    assert box[13].kind == "polygon" and not box[13].active and len(box[13].vertices_m) == 5 and box[15].active
    ross = read_txrx(rosslyn / "base.txrx")
    assert [(s.name, s.is_transmitter, s.is_receiver) for s in ross] == [("Tx", True, False), ("Rx", False, True)]


def test_setup(deepmimo, boxes, rosslyn):
    s = read_setup(boxes / "sim1.setup")
    assert s.waveforms[0].carrier_frequency_hz == 2.395e9 and s.waveforms[0].bandwidth_hz == 2e7
    assert s.antenna(0).power_threshold_dbm == -150 and s.antenna(0).type == "HalfWaveDipole"
    assert s.antenna(1).name == "2.4GHz MIMO"  # the nested element antenna is not a top-level antenna
    assert [a.number for a in s.antennas] == [0, 1, 2]
    assert [(c.name, c.noise_power_density_dbm_hz, c.base_stations, c.receivers) for c in s.comm_systems][0] == (
        "cs1",
        -174.0,
        (4,),
        (13, 14, 15),
    )
    assert read_setup(deepmimo / "insite.setup").waveforms[0].carrier_frequency_hz == 3.5e9
    r = read_setup(rosslyn / "model.setup")
    assert (r.longitude, r.latitude) == (-77.0787, 38.8907)
    assert [f.filename for f in r.features if f.kind == "city"] == ["./Rosslyn.city"]


def test_keyword_entries_keep_lines(rosslyn):
    root = parse_keyword_file(rosslyn / "Rosslyn.city")
    face = next(root.walk("face"))
    assert face.line == 67 and face.find_entry("Material") == (68, "6")


def _feature(coords, **props):
    return {"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": [coords]}}


def test_geojson(tmp_path):
    square = [[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]
    doc = {
        "type": "FeatureCollection",
        "features": [
            _feature(square, height_m=12.5),
            _feature([[20, 0], [30, 0], [30, 5], [20, 0]], height=8, min_height=2),
            {"type": "Feature", "properties": {"height": 3}, "geometry": {"type": "Point", "coordinates": [5, 5]}},
        ],
    }
    path = tmp_path / "b.geojson"
    path.write_text(json.dumps(doc))
    recs, rejected = read_geojson(path)
    b, _, _ = buildings_tables(recs)
    rows = b.to_pylist()
    # height_m is the building's own height; OSM's height is the top above the ground, min_height its bottom
    assert [(r["base_z_m"], r["roof_z_m"]) for r in rows] == [(0.0, 12.5), (2.0, 8.0)]
    assert len(rejected) == 1 and rejected[0].field == "features[2].geometry" and "Point" in rejected[0].reason


def test_geojson_as_openstreetmap_exports_it(tmp_path):
    """Heights with units, building:levels x 3 m, min_height and building:min_level; no usable height is counted."""
    square = [[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]
    props = [
        {"height": "12 m"},
        {"height": "40 ft"},
        {"height": "15'", "min_height": "3 m"},
        {"building:levels": "4"},
        {"building:levels": 6, "building:min_level": 2},
        {"building": "yes"},
        {"height": "tall"},
        {"building:levels": "several"},
    ]
    doc = {"type": "FeatureCollection", "features": [_feature(square, **p) for p in props]}
    (tmp_path / "osm.geojson").write_text(json.dumps(doc))
    recs, rejected = read_geojson(tmp_path / "osm.geojson")
    got = [(p.base_z_m, round(p.roof_z_m, 3)) for r in recs for p in r.parts]
    assert got == [(0.0, 12.0), (0.0, 12.192), (3.0, 4.572), (0.0, 12.0), (6.0, 18.0)]
    assert [r.field for r in rejected] == [f"features[{i}].properties" for i in (5, 6, 7)]
    assert "no height" in rejected[0].reason and "'tall' is not a length" in rejected[1].reason
    assert "'several' is not a number" in rejected[2].reason


@pytest.mark.parametrize(
    "feature,words",
    [
        (_feature([[0, 0], [10, 10], [10, 0], [0, 10], [0, 0]], height=3), "invalid polygon"),
        (_feature([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], height=3, min_height="low"), "'low' is not a length"),
        (_feature([[2.35, 48.85], [2.351, 48.85], [2.351, 48.851], [2.35, 48.85]], height=3), "longitude/latitude"),
    ],
)
def test_bad_geojson(tmp_path, feature, words):
    path = tmp_path / "b.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    with pytest.raises(InputError, match=words):
        read_geojson(path)


@pytest.mark.parametrize("suffix", ["obj", "ply", "stl", "glb"])
def test_mesh_buildings(tmp_path, suffix):
    a = trimesh.creation.box(extents=(10, 8, 20))
    a.apply_translation((5, 4, 10))
    b = trimesh.creation.box(extents=(6, 6, 7))
    b.apply_translation((30, 3, 3.5))
    ground = trimesh.Trimesh(vertices=[[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], faces=[[0, 1, 2], [0, 2, 3]])
    ground.apply_translation((0, 0, -0.1))
    path = tmp_path / f"city.{suffix}"
    trimesh.util.concatenate([a, b, ground]).export(path)
    recs, rejected = read_mesh(path)
    table, _, _ = buildings_tables(recs)
    rows = sorted(table.to_pylist(), key=lambda r: r["roof_z_m"])
    assert [(round(r["base_z_m"], 3), round(r["roof_z_m"], 3)) for r in rows] == [(0.0, 7.0), (0.0, 20.0)]
    assert [round(shapely.from_wkb(r["footprint_wkb"]).area, 3) for r in rows] == [36.0, 80.0]
    assert len(rejected) == 1 and "flat body" in rejected[0].reason


def test_bad_mesh(tmp_path):
    path = tmp_path / "broken.ply"
    path.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n")
    with pytest.raises(InputError, match="broken.ply"):
        read_mesh(path)


def test_footprint_vertices_round_trip(rosslyn):
    """Every footprint vertex of a Rosslyn building is one of its .city vertices."""
    root = parse_keyword_file(rosslyn / "Rosslyn.city")
    structure = next(root.walk("structure"))
    verts = np.vstack([f.vertices()[:, :2] for f in structure.walk("face")])
    b, _, _ = buildings_tables(read_city(rosslyn / "Rosslyn.city"))
    fp = shapely.from_wkb(b.column("footprint_wkb")[0].as_py())
    coords = np.asarray(fp.exterior.coords)
    assert np.abs(coords[:, None, :] - verts[None, :, :]).sum(-1).min(axis=1).max() < 1e-6

"""`uavdata build` and `load_bundle`: SINR against the raw points, resampling, versions, safety, bad input."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time

import duckdb
import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from tests.conftest import REPO, UAVDATA, write_grid_city
from uavplace.cli import uavdata
from uavplace.dataset.build import build_city
from uavplace.dataset.bundle import load_bundle, read_latest
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas import SCHEMA_VERSION, InputError
from uavplace.schemas.bundle import EMBEDDED_NOISE_DBM, BuildConfig

NOISE = EMBEDDED_NOISE_DBM  # the build's default
FLOOR = -40.0


def ingest(folder, root, name="city"):
    ingest_city(folder, root, name=name)
    return name


def cfg(**kw) -> BuildConfig:
    return BuildConfig(**({"grid_m": 4.0, "altitude_m": 10.0} | kw))


def raw_receivers(root, city="city") -> pd.DataFrame:
    return pq.read_table(root / city / "ingested" / "receivers.parquet").to_pandas()


def test_sinr_matches_raw_points(tmp_path):
    """Same grid as the export: each cell is one receiver, SINR = power - noise, floor where dead."""
    root = tmp_path / "p"
    city = ingest(write_grid_city(tmp_path / "raw", nx=7, ny=5, outputs=("power",), n_tx=3), root)
    b = load_bundle(city, root=root) if build_city(city, cfg(), root).built else None
    assert b is not None and b.shape == (5, 7) and b.num_users == 3
    rx = raw_receivers(root).sort_values(["tx_point", "rx_index"])
    for u in range(3):
        r = rx[rx.tx_point == u + 1]
        expected = np.where(r.reached, np.maximum(r.power_dbm.fillna(0) - NOISE, FLOOR), FLOOR).reshape(5, 7)
        np.testing.assert_allclose(b.sinr_db[u], expected, atol=1e-3)
        np.testing.assert_array_equal(b.dead[u], ~r.reached.to_numpy().reshape(5, 7))
    np.testing.assert_allclose(b.x_m, 10.0 + 4.0 * np.arange(7))
    assert b.manifest.sinr.source == "power" and not b.manifest.sinr.resampled
    assert not b.sinr_db.flags.writeable


def test_path_loss_and_power_give_the_same_sinr(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "a", outputs=("pl",), seed=3), root, "a")
    ingest(write_grid_city(tmp_path / "b", outputs=("power",), seed=3), root, "b")
    a = load_bundle(build_city("a", cfg(), root).path)
    b = load_bundle(build_city("b", cfg(), root).path)
    assert a.manifest.sinr.source == "path_loss"
    np.testing.assert_allclose(a.sinr_db, b.sinr_db, atol=1e-3)
    # --tx-dbm overrides the export's power: 10 dB more everywhere that is above the floor.
    c = load_bundle(build_city("b", cfg(tx_dbm=30.0), root).path)
    live = ~b.dead & (b.sinr_db > FLOOR + 1)
    np.testing.assert_allclose(c.sinr_db[live], b.sinr_db[live] + 10.0, atol=1e-3)


def test_resampling_averages_milliwatts_not_decibels(tmp_path):
    """A 2 m export on a 4 m grid: each cell is the mean mW of its 4 receivers (unreached ones as 0 mW)."""
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw", nx=8, ny=6, spacing=2.0, outputs=("power",), dead_share=0.3), root)
    b = load_bundle(build_city("city", cfg(), root).path)
    assert b.shape == (3, 4) and b.manifest.sinr.resampled and b.manifest.sinr.export_spacing_m == 2.0
    assert b.manifest.grid.x_min_m == pytest.approx(9.0)  # the export's cell edge: corner - spacing / 2
    rx = raw_receivers(root)
    r = rx[rx.tx_point == 1].sort_values("rx_index")
    mw = np.where(r.reached, 10 ** (r.power_dbm.fillna(-np.inf) / 10), 0.0).reshape(6, 8)
    blocks = mw.reshape(3, 2, 4, 2).transpose(0, 2, 1, 3).reshape(3, 4, 4)  # [iy, ix, 4 receivers]
    reached = r.reached.to_numpy().reshape(6, 8).reshape(3, 2, 4, 2).transpose(0, 2, 1, 3).reshape(3, 4, 4).any(-1)
    with np.errstate(divide="ignore"):
        expected = np.where(reached, np.maximum(10 * np.log10(blocks.mean(-1)) - NOISE, FLOOR), FLOOR)
    np.testing.assert_allclose(b.sinr_db[0], expected, atol=1e-3)
    np.testing.assert_array_equal(b.num_rx[0], 4)
    db = r.power_dbm.to_numpy().reshape(6, 8).reshape(3, 2, 4, 2).transpose(0, 2, 1, 3).reshape(3, 4, 4)
    full = ~np.isnan(db).any(-1)
    assert full.any() and not np.allclose(b.sinr_db[0][full], db.mean(-1)[full] - NOISE, atol=0.1)


def test_coarser_export_fills_from_nearest_receiver(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw", nx=4, ny=3, spacing=8.0, outputs=("power",), dead_share=0.0), root)
    b = load_bundle(build_city("city", cfg(), root).path)
    assert b.shape == (6, 8)
    assert not b.dead.any()
    assert set(np.unique(b.num_rx)) == {0, 1}
    assert set(np.round(np.unique(b.sinr_db[0]), 3)) <= set(np.round(b.sinr_db[0][b.num_rx[0] == 1], 3))


def test_interference_is_seeded(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw", outputs=("power",), dead_share=0.0), root)
    base = load_bundle(build_city("city", cfg(), root).path)
    a = load_bundle(build_city("city", cfg(interference_std_db=3.0, seed=1), root).path)
    a2 = load_bundle(build_city("city", cfg(interference_std_db=3.0, seed=1), root, force=True).path)
    c = load_bundle(build_city("city", cfg(interference_std_db=3.0, seed=2), root).path)
    np.testing.assert_array_equal(a.sinr_db, a2.sinr_db)
    assert not np.allclose(a.sinr_db, c.sinr_db)
    offset = base.sinr_db - a.sinr_db  # the interference offset of each cell, shared by all users
    np.testing.assert_allclose(offset[0], offset[1], atol=1e-3)
    assert 1.5 < offset.std() < 6


def test_altitude_mismatch_lists_heights(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw", z=30.0), root)
    with pytest.raises(InputError, match=r"receivers.parquet: z_m: no receiver at 10 \+/- 0.5 m .* 30 m \(60 rx\)"):
        build_city("city", cfg(), root)
    assert build_city("city", cfg(altitude_m=29.8), root).manifest.num_users == 2


def test_path_loss_without_tx_power_needs_tx_dbm(tmp_path):
    raw = write_grid_city(tmp_path / "raw", outputs=("pl",))
    txrx = raw / "city.txrx"
    txrx.write_text(txrx.read_text().replace("power 20.00000\n", ""))
    root = tmp_path / "p"
    ingest(raw, root)
    with pytest.raises(InputError, match="transmitters.parquet: power_dbm: user t001_01 has no transmit power.*--tx-dbm"):
        build_city("city", cfg(), root)
    b = load_bundle(build_city("city", cfg(tx_dbm=20.0), root).path)
    assert b.manifest.sinr.tx_power_dbm == (20.0,)


def test_versions_noop_latest_and_old_versions(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw"), root)
    first = build_city("city", cfg(), root)
    again = build_city("city", cfg(), root)
    assert first.built and not again.built and again.manifest == first.manifest
    other = build_city("city", cfg(noise_dbm=NOISE + 4.0), root)
    assert other.built and other.manifest.version != first.manifest.version
    assert read_latest("city", root) == other.manifest.version
    locks = sorted(p.name for p in root.rglob(".*.lock"))  # one lock for the city's bundles, none per version
    assert not any(v in name for name in locks for v in (first.manifest.version, other.manifest.version)), locks
    old = load_bundle(f"city@{first.manifest.version}", root=root)
    np.testing.assert_allclose(old.sinr_db[~old.dead], load_bundle("city", root=root).sinr_db[~old.dead] + 4.0, atol=1e-3)
    # Re-ingesting the same exports gives the same tables, hence the same version.
    ingest(tmp_path / "raw", root)
    assert not build_city("city", cfg(), root).built


def test_tampered_file_is_detected_and_rebuilt(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw"), root)
    path = build_city("city", cfg(), root).path
    cells = path / "cells.parquet"
    data = bytearray(cells.read_bytes())
    data[len(data) // 2] ^= 0xFF
    cells.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"cells.parquet: sha256: .* the file was changed after the build"):
        load_bundle("city", root=root)
    assert build_city("city", cfg(), root).built  # a damaged bundle is rebuilt, not trusted
    load_bundle("city", root=root)


def test_cells_that_disagree_with_the_maps_are_refused(tmp_path):
    """The bundle's long table and its arrays are two copies of one map: a cells.parquet rewritten with another SINR
    (its sha256 updated in the manifest, so the file check passes) is refused, naming the row, the user and the cell."""
    import hashlib
    import json

    import pyarrow as pa

    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw"), root)
    path = build_city("city", cfg(), root).path
    cells = path / "cells.parquet"
    table = pq.read_table(cells)
    sinr = table.column("sinr_db").to_numpy().copy()
    sinr[7] += 3.0
    pq.write_table(table.set_column(table.schema.get_field_index("sinr_db"), "sinr_db", pa.array(sinr)), cells)
    manifest = json.loads((path / "manifest.json").read_text())
    manifest["files"]["cells.parquet"] = hashlib.sha256(cells.read_bytes()).hexdigest()
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(InputError, match=r"cells.parquet: sinr_db: row 7 \(user 0, cell \(1, 1\)\): .* the bundle's two copies"):
        load_bundle("city", root=root)


def test_tampered_ingested_table_is_refused(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw"), root)
    tx = root / "city" / "ingested" / "transmitters.parquet"
    tx.write_bytes(tx.read_bytes() + b"\0")
    with pytest.raises(InputError, match="transmitters.parquet: sha256: .* changed after ingest"):
        build_city("city", cfg(), root)


def test_schema_version_mismatch(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw"), root)
    path = build_city("city", cfg(), root).path
    m = json.loads((path / "manifest.json").read_text())
    m["schema_version"] = "0.9"
    (path / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(InputError, match=f"schema_version: bundle schema version '0.9', this uavplace reads '{SCHEMA_VERSION}'"):
        load_bundle("city", root=root)
    # an ingest of an earlier schema (its receivers table lacks columns the build reads) is refused, not half-read
    ingested = root / "city" / "ingested" / "manifest.json"
    m = json.loads(ingested.read_text())
    m["schema_version"] = "1.0"
    ingested.write_text(json.dumps(m))
    with pytest.raises(InputError, match="ingested with schema version '1.0'.*run `uavdata ingest` again"):
        build_city("city", cfg(seed=1), root)


def test_half_written_bundle_is_never_loaded(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw"), root)
    good = build_city("city", cfg(), root)
    # What a build killed while writing leaves: a temporary folder with some files, no rename, latest unchanged.
    partial = root / "city" / ".0123456789ab.tmp-xyz"
    partial.mkdir()
    (partial / "maps.npz").write_bytes(b"half")
    assert load_bundle("city", root=root).version == good.manifest.version
    with pytest.raises(InputError, match="no bundle version '0123456789ab'"):
        load_bundle("city@0123456789ab", root=root)
    # A folder with files but no manifest is not a bundle either.
    (root / "city" / "fedcba987654").mkdir()
    (root / "city" / "fedcba987654" / "maps.npz").write_bytes(b"x")
    with pytest.raises(InputError, match="no bundle manifest"):
        load_bundle("city@fedcba987654", root=root)


@pytest.mark.slow
def test_kill_9_during_build_leaves_a_loadable_latest(tmp_path):
    """A real `uavdata build` killed with SIGKILL at several moments: latest always loads, every bundle folder is whole."""
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw", nx=150, ny=120, n_tx=16, spacing=2.0, outputs=("power",)), root)
    first = build_city("city", cfg(), root).manifest.version
    env = os.environ | {"PYTHONPATH": str(REPO)}
    killed = 0
    for k, delay in enumerate(np.linspace(0.3, 1.6, 8)):
        cmd = [
            *UAVDATA,
            "build",
            "--root",
            str(root),
            "--quiet",
            "--noise-dbm",
            str(-90 - k),
        ]
        proc = subprocess.Popen(cmd, env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        killed += proc.wait() == -signal.SIGKILL
        latest = load_bundle("city", root=root)
        assert latest.version in {first} | {p.name for p in (root / "city").iterdir()}
        for folder in (root / "city").iterdir():
            if folder.is_dir() and not folder.name.startswith(".") and folder.name != "ingested":
                load_bundle(str(folder))
    assert killed >= 3
    assert build_city("city", cfg(), root).manifest.version == first


def _points_city(folder, shift_second: float):
    """Two users measured on point receivers; the second user's points shifted by ``shift_second`` metres."""
    from uavplace.simulate.insite import write_p2m, write_setup

    folder.mkdir(parents=True)
    write_setup(folder / "c.setup", "c")
    pts = np.array([[x, y, 10.0] for x in (0.0, 8.0, 16.0) for y in (0.0, 8.0)])
    for t, shift in ((1, 0.0), (2, shift_second)):
        p = pts + [shift, 0, 0]
        write_p2m(folder, "c", "power", tx_point=t, tx_set=(1, "U"), rx_set=(2, "R"), positions_m=p,
                  distance_m=np.full(6, 10.0), values=np.full(6, -70.0))  # fmt: skip
    return folder


def test_users_with_different_coverage(tmp_path):
    root = tmp_path / "p"
    ingest(_points_city(tmp_path / "raw", shift_second=100.0), root)
    with pytest.raises(InputError, match="users' receivers do not cover the same area: user t00[12]_01 spans x"):
        build_city("city", cfg(), root)
    root2 = tmp_path / "p2"
    ingest(_points_city(tmp_path / "raw2", shift_second=0.0), root2)
    assert build_city("city", cfg(), root2).manifest.num_users == 2


def _with_buildings(folder, features):
    fc = {
        "type": "FeatureCollection",
        "features": [
            {"type": "Feature", "properties": {"height_m": h}, "geometry": {"type": "Polygon", "coordinates": [ring]}}
            for ring, h in features
        ],
    }
    (folder / "b.geojson").write_text(json.dumps(fc))
    return folder


def test_buildings_outside_the_grid(tmp_path):
    inside = [[12, -18], [20, -18], [20, -10], [12, -10], [12, -18]]  # holds 4 cell centres of the 6 x 5 grid
    far = [[500, 500], [510, 500], [510, 510], [500, 510], [500, 500]]
    raw = _with_buildings(write_grid_city(tmp_path / "raw"), [(inside, 25.0), (far, 5.0)])
    root = tmp_path / "p"
    ingest(raw, root)
    with pytest.raises(
        InputError, match=r"buildings.parquet: footprint_wkb: 1 building\(s\) lie wholly outside the grid .*--crop"
    ):
        build_city("city", cfg(), root)
    b = load_bundle(build_city("city", cfg(crop=True), root).path)
    assert b.manifest.counts["buildings_cropped"] == 1 and b.manifest.counts["buildings_in_grid"] == 1
    assert b.blocked.sum() == 4 and np.all(b.height_rel_m[b.blocked] == 15.0)
    assert np.all(b.height_rel_m[~b.blocked] == -10.0)
    # On the command line --crop-city CITY crops that city alone: the other keeps the check (and its bundle version).
    ingest(write_grid_city(tmp_path / "raw2"), root, name="plain")
    run = CliRunner().invoke
    base = ["build", "--root", str(root), "--grid", "4m", "--alt", "10"]
    res = run(uavdata, [*base, "--crop-city", "city"])
    assert res.exit_code == 0, res.output
    assert load_bundle("city", root=root).version == b.version and not load_bundle("plain", root=root).manifest.config.crop
    assert run(uavdata, [*base, "--crop-city", "elsewhere"]).exit_code == 2
    assert run(uavdata, [*base, "--city", "city"]).exit_code != 0
    wide = load_bundle(build_city("city", cfg(bounds="buildings"), root).path)
    assert wide.manifest.counts["buildings_in_grid"] == 2 and wide.shape[1] > 100
    low = (wide.building_id == 1) & ~wide.blocked  # the 5 m building is below the 10 m altitude: flyable
    assert low.any() and np.all(wide.height_rel_m[low] == -5.0)


def test_empty_cities(tmp_path, boxes):
    root = tmp_path / "p"
    ingest(boxes, root, "boxes")
    with pytest.raises(InputError, match="no receiver outputs: nothing to build a SINR map from"):
        build_city("boxes", cfg(), root)
    ingest(write_grid_city(tmp_path / "raw"), root)
    with pytest.raises(InputError, match="no receiver at the altitude lies inside the grid bounds"):
        build_city("city", cfg(bounds=(1000.0, 1000.0, 1100.0, 1100.0)), root)


def test_long_table_opens_in_pandas_and_duckdb(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw", nx=9, ny=4, n_tx=3), root)
    b = load_bundle(build_city("city", cfg(), root).path)
    cells = pd.read_parquet(b.path / "cells.parquet")
    assert len(cells) == 3 * 9 * 4
    row = cells[(cells.user == 2) & (cells.ix == 5) & (cells.iy == 3)].iloc[0]
    assert row.sinr_db == pytest.approx(b.sinr_db[2, 3, 5]) and row.x_m == pytest.approx(b.x_m[5])
    con = duckdb.connect()
    q = f"SELECT user, avg(sinr_db), sum(dead::INT) FROM '{b.path / 'cells.parquet'}' GROUP BY user ORDER BY user"
    rows = con.sql(q).fetchall()
    assert [r[0] for r in rows] == [0, 1, 2]
    np.testing.assert_allclose([r[1] for r in rows], b.sinr_db.reshape(3, -1).mean(1), rtol=1e-5)
    assert [r[2] for r in rows] == b.dead.reshape(3, -1).sum(1).tolist()
    users = con.sql(f"SELECT user, tx_point, ix, iy FROM '{b.path / 'users.parquet'}'").fetchall()
    assert [u[1] for u in users] == [1, 2, 3]


def test_splits(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw", n_tx=5), root)
    b = load_bundle(build_city("city", cfg(role="train", val_users=2, seed=7), root).path)
    assert b.manifest.split == {"train": 3, "val": 2, "test": 0} and len(b.user_indices("val")) == 2
    t = load_bundle(build_city("city", cfg(role="test"), root).path)
    assert t.manifest.split == {"train": 0, "val": 0, "test": 5}
    v = load_bundle(build_city("city", cfg(role="val"), root).path)  # a validation city: all its users
    assert v.manifest.split == {"train": 0, "val": 5, "test": 0} and len(v.user_indices("val")) == 5
    with pytest.raises(ValueError, match="val_users is for train cities"):
        cfg(role="test", val_users=1)


def test_rosslyn_height_map_matches_buildings(tmp_path, rosslyn):
    root = tmp_path / "p"
    ingest(rosslyn, root, "rosslyn")
    b = load_bundle(build_city("rosslyn", cfg(grid_m=2.0, altitude_m=1.59, altitude_tol_m=3.0), root).path)
    buildings = pq.read_table(root / "rosslyn" / "ingested" / "buildings.parquet").to_pandas()
    assert len(buildings) == 29
    ids = np.unique(b.building_id[b.building_id >= 0])
    assert ids.tolist() == sorted(buildings.building_id.tolist())
    top = pd.Series(b.height_rel_m.ravel() + b.altitude_m).groupby(b.building_id.ravel()).max().drop(-1)
    np.testing.assert_allclose(top.sort_index().to_numpy(), buildings.sort_values("building_id").height_m, atol=1e-4)
    assert top.min() == pytest.approx(9.0) and top.max() == pytest.approx(100.95)
    assert b.manifest.counts["receivers_used"] == 10 and b.manifest.sinr.source == "power"


def test_deepmimo_grid_builds_and_resamples(tmp_path, deepmimo):
    root = tmp_path / "p"
    ingest(deepmimo, root, "dm")
    same = load_bundle(build_city("dm", cfg(grid_m=2.5, altitude_m=2.0), root).path)
    assert same.shape == (57, 81) and same.dead.sum() == 4160 and same.manifest.sinr.source == "path_loss"
    coarse = load_bundle(build_city("dm", cfg(grid_m=4.0, altitude_m=2.0), root).path)
    assert coarse.manifest.sinr.resampled and coarse.num_rx.sum() == 81 * 57


def test_cli_build_list_show(tmp_path):
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw"), root)
    run = CliRunner().invoke
    for cmd in (["build", "--help"], ["show", "--help"]):
        res = run(uavdata, cmd)
        assert res.exit_code == 0 and "--root" in res.output
    res = run(uavdata, ["build", "--root", str(root), "--grid", "4m", "--alt", "10", "--split", "city=train"])
    assert res.exit_code == 0, res.output
    assert "built city@" in res.output
    res = run(uavdata, ["build", "--root", str(root), "--grid", "4m", "--alt", "10", "--split", "city=train"])
    assert "up to date (nothing to do) city@" in res.output
    res = run(uavdata, ["list", "--root", str(root)])
    assert "bundles (* latest)" in res.output and "train" in res.output
    import io

    from rich.console import Console

    from uavplace.dataset.catalog import list_cities
    from uavplace.dataset.cli import list_tables

    for width in (100, 120):  # a narrow terminal: the city and its version whole, as --dataset city@version needs them
        text = io.StringIO()
        for table in list_tables(list_cities(root), root):
            Console(file=text, width=width).print(table)
        assert f"│ city │ {read_latest('city', root)} * │" in text.getvalue(), text.getvalue()
    png = tmp_path / "show.png"
    res = run(uavdata, ["show", "city", "--root", str(root), "--user", "1", "--out", str(png)])
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    first = read_latest("city", root)
    res = run(uavdata, ["build", "--root", str(root), "--noise-dbm", "-90"])  # would drop the train role: refused
    assert res.exit_code == 2 and "city (a train city)" in res.output and "--split CITY=none" in res.output
    assert read_latest("city", root) == first
    res = run(uavdata, ["build", "--root", str(root), "--noise-dbm", "-90", "--split", "city=train"])  # moves `latest`, says so
    assert res.exit_code == 0 and f"(it was city@{first}); to keep using the other, name it: --dataset city@{first}" in res.output
    res = run(uavdata, ["build", "--root", str(root), "--split", "city=none", "--noise-dbm", "-90"])  # dropped when asked
    assert res.exit_code == 0 and load_bundle("city", root=root).manifest.config.role is None
    res = run(uavdata, ["build", "--root", str(root), "--alt", "30"])
    assert res.exit_code == 2 and "heights present: 10 m (60 rx)" in res.output
    res = run(uavdata, ["build", "--root", str(root), "--grid", "four"])
    assert res.exit_code == 2 and "is not a length in metres" in res.output


def test_p2m_without_txrx_puts_one_cell_on_each_receiver(tmp_path, deepmimo):
    """Public datasets often publish the .p2m alone: the lattice is found from the receiver positions."""
    root = tmp_path / "p"
    ingest(deepmimo, root, "dm")
    power = pq.read_table(root / "dm" / "ingested" / "transmitters.parquet").column("power_dbm").to_pylist()[0]
    bare = tmp_path / "bare"
    shutil.copytree(deepmimo, bare, ignore=shutil.ignore_patterns("*.txrx"))
    ingest(bare, root, "bare")
    with_txrx = load_bundle(build_city("dm", cfg(grid_m=2.5, altitude_m=2.0), root).path)
    without = load_bundle(build_city("bare", cfg(grid_m=2.5, altitude_m=2.0, tx_dbm=power), root).path)
    assert without.shape == with_txrx.shape == (57, 81)
    assert without.dead.sum() == with_txrx.dead.sum() == 4160
    assert without.num_rx.max() == 1 and without.manifest.sinr.export_spacing_m == pytest.approx(2.5)
    np.testing.assert_allclose(without.sinr_db, with_txrx.sinr_db, atol=1e-4)


def test_roles_declared_beside_the_data_and_overridden_by_options(tmp_path):
    """A roles file gives the cities it lists their role, crop and validation users, exactly as the options do (the
    same bundle version); an option overrides it; a bad file is one line naming it and the field."""
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw" / "alpha"), root, name="alpha")
    ingest(write_grid_city(tmp_path / "raw" / "beta", seed=3), root, name="beta")
    roles = tmp_path / "raw" / "cities.toml"
    roles.write_text('train = ["alpha"]\ntest = ["beta", "elsewhere"]\ncrop = ["beta"]\nval_users = 1\n')
    run = CliRunner().invoke
    base = ["build", "--root", str(root), "--grid", "4m", "--alt", "10", "--quiet"]
    res = run(uavdata, [*base, "--roles", str(roles)])  # a city listed but not ingested here is no matter
    assert res.exit_code == 0, res.output
    alpha, beta = (load_bundle(c, root=root).manifest for c in ("alpha", "beta"))
    assert (alpha.config.role, alpha.config.val_users, alpha.config.crop) == ("train", 1, False)
    assert (beta.config.role, beta.config.val_users, beta.config.crop) == ("test", 0, True)
    from uavplace.eval.cities import release_cities

    assert release_cities(root) == ["beta"]  # what `uavrl report` plays without --dataset
    with pytest.raises(InputError, match="no test city with routes is built"):
        release_cities(root, routes=True)
    other = tmp_path / "q"
    ingest(tmp_path / "raw" / "alpha", other, name="alpha")
    ingest(tmp_path / "raw" / "beta", other, name="beta")
    flags = ["--split", "alpha=train", "--split", "beta=test", "--crop-city", "beta", "--val-users", "1"]
    res = run(
        uavdata,
        ["build", "--root", str(other), "--grid", "4m", "--alt", "10", "--quiet", "--roles", str(tmp_path / "none.toml"), *flags],
    )
    assert res.exit_code == 2 and "no such roles file" in res.output
    res = run(uavdata, ["build", "--root", str(other), "--grid", "4m", "--alt", "10", "--quiet", *flags])
    assert res.exit_code == 0, res.output
    assert read_latest("alpha", other) == alpha.version and read_latest("beta", other) == beta.version  # the same bundles
    res = run(uavdata, [*base, "--roles", str(roles), "--split", "beta=val", "--city", "beta"])  # the option wins
    assert res.exit_code == 0 and load_bundle("beta", root=root).manifest.config.role == "val"
    for text, message in (('train = ["alpha"]\nval = ["alpha"]\n', "alpha is both a train and a val city"),
                          ('tests = ["beta"]\n', "tests: Extra inputs are not permitted")):  # fmt: skip
        roles.write_text(text)
        res = run(uavdata, [*base, "--roles", str(roles)])
        assert res.exit_code == 2 and str(roles) in res.output and message in res.output, res.output


def test_build_warnings_are_one_line_per_kind():
    """A kind of warning met in several cities is one line: the first city's text, then the others with counts."""
    from uavplace.dataset.cli import warning_lines

    small = "{} building(s) cover no cell centre (smaller than a 4 m cell)"
    crop = "{} building(s) lie wholly outside the grid x 72..328, y 72..328: ids [{}] (building_{}): dropped (the city is cropped: --crop, or `crop` in data/raw/cities.toml)"
    warned = [("a", small.format(2)), ("b", crop.format(31, "0, 1", "0, building_1")), ("c", small.format(5)),
              ("d", crop.format(11, "7", "7")), ("e", small.format(1)), ("f", "the export carries SINR")]  # fmt: skip
    assert warning_lines(warned) == [
        f"a: {small.format(2)}; the same in 2 more cities: c (5), e (1)",
        f"b: {crop.format(31, '0, 1', '0, building_1')}; the same in 1 more city: d (11)",
        "f: the export carries SINR",
    ]


def test_show_leaves_buildings_out_of_the_sinr_panel_and_the_dead_count(tiny):
    from uavplace.dataset.preview import sinr_panel

    b = load_bundle("tiny", root=tiny)
    assert b.blocked.any()
    for user in range(b.num_users):
        sinr, dead_open = sinr_panel(b, user)
        assert sinr.mask[b.blocked].all() and not sinr.mask[~b.blocked & ~b.dead[user]].any()
        assert dead_open == int((b.dead[user] & ~b.blocked).sum()) <= int(b.dead[user].sum())


def test_show_hatches_only_what_is_known_to_be_estimated(tiny, tmp_path):
    """The embedded tiny city's side file says every live receiver was ray-traced; the same export without it reads
    "not recorded" (an export that predates the side file), with the same maps: `uavdata show` hatches neither."""
    from uavplace.dataset.preview import HATCHES, estimated_cells
    from uavplace.schemas.provenance import NOT_RECORDED, RAY_TRACED, SIDE_FILE_SUFFIX

    b = load_bundle("tiny", root=tiny)
    assert (b.provenance[0][~b.blocked & ~b.dead[0]] == RAY_TRACED).all() and estimated_cells(b, 0) == {}
    bare = tmp_path / "raw" / "tiny"
    shutil.copytree(REPO / "data" / "raw" / "tiny", bare, ignore=shutil.ignore_patterns(f"*{SIDE_FILE_SUFFIX}"))
    ingest_city(bare, tmp_path / "p")
    old = load_bundle(build_city("tiny", cfg(), tmp_path / "p").path)
    np.testing.assert_array_equal(old.sinr_db, b.sinr_db)
    assert old.version != b.version and (old.provenance[0][~old.blocked & ~old.dead[0]] == NOT_RECORDED).all()
    assert NOT_RECORDED not in HATCHES and estimated_cells(old, 0) == {}


def test_the_grid_is_the_exports_unless_given(tmp_path):
    """`uavdata build --alt 10` takes each city's receiver-grid spacing from its .txrx: the same bundle as `--grid`
    with that spacing; a city of point receivers needs `--grid`, said in one line."""
    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "raw", spacing=2.0), root)
    run = CliRunner().invoke
    res = run(uavdata, ["build", "--root", str(root), "--alt", "10", "--quiet"])
    assert res.exit_code == 0, res.output
    assert load_bundle("city", root=root).manifest.config.grid_m == 2.0
    res = run(uavdata, ["build", "--root", str(root), "--alt", "10", "--grid", "2m", "--quiet"])
    assert "up to date" in res.output  # the same bundle
    from uavplace.dataset.catalog import export_spacing

    manifest = root / "city" / "ingested" / "manifest.json"
    doc = json.loads(manifest.read_text())
    doc["txrx_sets"] = [s for s in doc["txrx_sets"] if s["kind"] != "grid"]
    manifest.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="no receiver grid in its .txrx: give the grid spacing"):
        export_spacing("city", root)


def test_a_city_nothing_can_be_played_in_warns_at_build(tmp_path, tiny):
    """A city whose maps leave no user a start cell (here no cell reaches P_T) builds, and the build says at once that
    training and reports will refuse it; the embedded tiny city, which plays, is not warned of."""
    from click.testing import CliRunner

    from uavplace.cli import uavdata

    root = tmp_path / "p"
    ingest(write_grid_city(tmp_path / "weak", outputs=("power",), tx_power_dbm=-60.0), root, "weak")
    res = CliRunner().invoke(uavdata, ["build", "--root", str(root), "--grid", "4m", "--alt", "10"])
    assert res.exit_code == 0, res.output
    assert load_bundle("weak", root=root).manifest.difficulty["num_starts"] == 0
    (warned,) = [line for line in res.output.splitlines() if "nothing can be played here" in line]
    assert warned.startswith("warning: weak: nothing can be played here: 0.0 % of legal user-cells reach P_T 5 dB")
    assert "will refuse the city (do the receivers cover the streets?" in warned
    assert not any("played" in w or "no ray reached" in w for w in load_bundle("tiny", root=tiny).manifest.warnings)

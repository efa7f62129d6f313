"""`uavdata simulate`: the city generator, scene meshes, InSite writers, and (with Sionna RT) physics and round trip."""

from __future__ import annotations

import gzip
import importlib.util
import json
import os
import subprocess

import numpy as np
import pandas as pd
import pytest
import shapely
from click.testing import CliRunner

from tests.conftest import REPO, UAVDATA
from uavplace.cli import uavdata
from uavplace.dataset.build import build_city
from uavplace.dataset.bundle import load_bundle
from uavplace.ingest.pipeline import ingest_city
from uavplace.ingest.wireless_insite.city import read_city
from uavplace.schemas import InputError
from uavplace.schemas.bundle import EMBEDDED_NOISE_DBM, BuildConfig
from uavplace.simulate.config import SimulationSpec
from uavplace.simulate.fill import fill_gaps
from uavplace.simulate.pipeline import place_users, receiver_grid
from uavplace.simulate.procedural import PRESETS, generate_city
from uavplace.simulate.raytrace import LLVM_19, RayTraceConfig
from uavplace.simulate.scene import ALL_CONCRETE, GROUND, MATERIALS, assign_materials, extrude, parse_mix
from uavplace.simulate.sources import load_geometry
from uavplace.simulate.trace_cache import spec_record, trace_key

HAS_SIONNA = importlib.util.find_spec("sionna") is not None and importlib.util.find_spec("mitsuba") is not None
HAS_LLVM = bool(os.environ.get("DRJIT_LIBLLVM_PATH")) or os.path.exists(LLVM_19)
needs_sionna = pytest.mark.skipif(
    not (HAS_SIONNA and HAS_LLVM),
    reason="Sionna RT or LLVM >= 16 missing (pip install -e '.[raytrace]'; apt-get install libllvm19)",
)


def test_generator_is_seeded_and_mixed():
    a = generate_city(PRESETS["train"], 27, seed=5)
    b = generate_city(PRESETS["train"], 27, seed=5)
    c = generate_city(PRESETS["train"], 27, seed=6)
    assert [f.wkt for f in a.footprints] == [f.wkt for f in b.footprints] and np.array_equal(a.users_m, b.users_m)
    assert [f.wkt for f in a.footprints] != [f.wkt for f in c.footprints]
    h = np.array(a.heights_m)
    assert 0.15 < (h < 10).mean() < 0.45 and h.max() > 20  # some below the 10 m altitude, most above
    union = shapely.union_all(list(a.footprints))
    assert 0.2 < union.area / (552 * 500) < 0.6
    assert not shapely.intersects(union.buffer(1.9), shapely.points(a.users_m[:, :2])).any()
    assert np.all(a.users_m[:, 2] == 1.5) and len(a.users_m) == 27


def test_extruded_meshes_are_closed():
    poly = shapely.box(0, 0, 10, 6).difference(shapely.box(3, 2, 5, 4))
    m = extrude(poly, 2.0, 14.0)
    assert m.is_watertight and m.volume == pytest.approx(poly.area * 12.0)
    assert m.bounds.tolist() == [[0, 0, 2], [10, 6, 14]]


def test_material_law_at_800_mhz():
    g = GROUND.at(800e6)
    assert g["relative_permittivity"] == pytest.approx(15 * 0.8**-0.1, abs=1e-3)
    assert g["conductivity_s_m"] == pytest.approx(0.035 * 0.8**1.63, abs=1e-4)


def test_a_material_mix_is_read_checked_and_dealt_to_the_buildings_by_the_seed(tmp_path):
    """``--materials``: one class or CLASS=SHARE words whose shares sum to 1; each building gets one class, the
    shares of the buildings' count met to the building (largest remainder), the same by the same seed. The default
    leaves the spec's record, and with it the trace cache's key, as before the option."""
    assert parse_mix(("concrete",)) == ALL_CONCRETE
    mix = parse_mix(("concrete=0.4", "brick=0.3", "glass=0.2", "metal=0.1"))
    assert mix == (("concrete", 0.4), ("brick", 0.3), ("glass", 0.2), ("metal", 0.1))
    for words, message in (
        (("concrete=0.5",), "sum to 0.5"), (("adamantium",), "not a material class"), (("glass=x", "metal=1"), "not a number"),
        (("glass=0.5", "glass=0.5"), "given twice"), (("glass=0", "metal=1"), "in \\(0, 1\\]"), (("glass", "metal"), "CLASS=SHARE"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=message):
            parse_mix(words)
    buildings = [7, 3, 3, 12, *range(20, 38)]  # 21 buildings, one of them in two parts
    dealt = assign_materials(buildings, mix, seed=5)
    assert sorted(dealt) == sorted(set(buildings))
    assert {m: list(dealt.values()).count(m) for m, _ in mix} == {"concrete": 9, "brick": 6, "glass": 4, "metal": 2}
    assert dealt == assign_materials(buildings[::-1], mix, seed=5) and dealt != assign_materials(buildings, mix, seed=6)
    assert set(assign_materials(buildings, ALL_CONCRETE, seed=5).values()) == {"concrete"}
    assert set(MATERIALS) >= {"concrete", "brick", "glass", "metal", "wood"}
    plain = SimulationSpec(source="procedural:tiny", name="t")
    words = ("concrete=0.4", "brick=0.3", "glass=0.2", "metal=0.1")
    mixed = SimulationSpec(source="procedural:tiny", name="t", materials=words)
    assert "materials" not in spec_record(plain) and spec_record(mixed)["materials"] == words
    for concrete in (plain, SimulationSpec(source="procedural:tiny", name="t", materials=("concrete=1",))):
        assert "materials" not in json.loads(trace_key(concrete, RayTraceConfig()))["spec"]
    assert json.loads(trace_key(mixed, RayTraceConfig()))["spec"]["materials"] == list(words)
    res = CliRunner().invoke(
        uavdata, ["simulate", "procedural:tiny", "--name", "t", "--out", str(tmp_path), "--materials", "glass=0.5"]
    )
    assert res.exit_code == 2 and "--materials" in res.output and "sum to 0.5" in res.output, res.output
    assert not (tmp_path / "t").exists()


def test_fill_gaps_takes_the_parent_cell():
    fine = np.zeros((1, 5, 6))
    fine[0, 0, 0] = 2.0
    coarse = np.array([[[1.0, 0.0], [3.0, 4.0]]])  # factor 4: parents of 4 x 4 fine cells
    out = fill_gaps(fine, coarse, 4)
    assert out[0, 0, 0] == 2.0 and out[0, 1, 1] == 1.0 and out[0, 0, 5] == 0.0 and out[0, 4, 5] == 4.0


def test_smooth_fill_varies_from_cell_to_cell_and_never_crosses_a_building():
    from uavplace.simulate.fill import fill_smooth
    from uavplace.simulate.raytrace import constant_patch_share

    fine = np.zeros((1, 8, 8))
    fine[0, 0, 0], fine[0, 0, 7] = 1e-3, 1e-6  # a strong hit left of a wall, a weak one right of it
    coarse = np.full((1, 1, 1), 1e-4)  # factor 8: one parent, which saw rays, so every cell is live
    open_cells = np.ones((8, 8), bool)
    open_cells[:7, 4] = False  # the wall down column 4, open at the bottom row
    iy, ix = np.mgrid[0:8, 0:8]
    d2 = ((iy * 4.0 - 14.0) ** 2 + (ix * 4.0 - 14.0) ** 2 + 8.5**2)[None]  # a user below the middle, 8.5 m lower
    out = fill_smooth(fine, [coarse], (8,), open_cells, d2)
    assert (out > 0).all() and out[0, 0, 0] == 1e-3 and out[0, 0, 7] == 1e-6  # hits exactly as traced
    rel = out * d2  # relative to free space: each side is filled from its own hit, never across the wall
    assert rel[0, 0, 3] / rel[0, 0, 5] == pytest.approx((1e-3 * d2[0, 0, 0]) / (1e-6 * d2[0, 0, 7]))
    gaps = fine == 0
    assert out[gaps].mean() == pytest.approx(1e-4)  # the gaps at the level of the coarse map
    assert constant_patch_share(out, out > 0) == 0.0  # no mosaic, where the parent copy is one
    assert constant_patch_share(np.full((1, 8, 8), 1e-4), out > 0) == 1.0
    dead = fill_smooth(np.zeros((1, 8, 8)), [np.zeros((1, 1, 1))], (8,), open_cells, d2)
    assert not dead.any()  # no ray at any scale: unreached stays unreached


def test_smooth_fill_takes_each_parents_level():
    """The gaps of each parent cell average to the coarse map's value there (more rays, less noise)."""
    from uavplace.simulate.fill import fill_smooth

    rng = np.random.default_rng(0)
    fine = np.where(rng.random((1, 8, 8)) < 0.5, rng.uniform(1, 2, (1, 8, 8)), 0.0)
    coarse = np.array([[[3.0, 1.5], [1.0, 0.0]]])  # the last parent saw no ray
    fine[0, 4:, 4:] = 0.0
    d2 = np.full((1, 8, 8), 100.0)
    out = fill_smooth(fine, [coarse], (4,), np.ones((8, 8), bool), d2)
    for py, px in ((0, 0), (0, 1), (1, 0)):
        block = (slice(4 * py, 4 * py + 4), slice(4 * px, 4 * px + 4))
        gaps = fine[0][block] == 0
        assert out[0][block][gaps].mean() == pytest.approx(coarse[0, py, px])
    assert not out[0, 4:, 4:].any()  # unreached at every scale
    assert (out[fine > 0] == fine[fine > 0]).all()


def test_city_file_round_trips_through_ingest(tmp_path):
    from uavplace.simulate.insite import write_city

    city = generate_city(PRESETS["tiny"], 0, seed=3)
    write_city(tmp_path / "c.city", [[(f, 0.0, h)] for f, h in zip(city.footprints, city.heights_m, strict=True)])
    back = read_city(tmp_path / "c.city")
    assert len(back) == len(city.footprints)
    for rec, f, h in zip(back, city.footprints, city.heights_m, strict=True):
        assert rec.parts[0].roof_z_m == pytest.approx(h) and rec.parts[0].footprint.equals_exact(f, 1e-4)


def test_bad_simulation_inputs(tmp_path):
    blocks, bounds, _ = load_geometry("procedural:tiny", 0)
    spec = SimulationSpec(source="procedural:tiny", name="t")
    grid = receiver_grid(bounds, spec)
    inside = blocks[0].footprint.representative_point()
    with pytest.raises(InputError, match=r"user: user 1 at .* is inside a building"):
        place_users(blocks, grid, SimulationSpec(source="procedural:tiny", name="t", users_m=((inside.x, inside.y),)))
    with pytest.raises(InputError, match="extent: the grid .* does not overlap the city's buildings"):
        s = SimulationSpec(source="procedural:tiny", name="t", extent_m=(1000.0, 1000.0, 1100.0, 1100.0))
        place_users(blocks, receiver_grid(bounds, s), s)
    with pytest.raises(InputError, match="extent: a 6 x 6 m extent holds fewer than 2 x 2 cells"):
        receiver_grid(bounds, SimulationSpec(source="procedural:tiny", name="t", extent_m=(0.0, 0.0, 6.0, 6.0)))
    bowtie = {"type": "Polygon", "coordinates": [[[0, 0], [10, 10], [10, 0], [0, 10], [0, 0]]]}
    gj = tmp_path / "bad.geojson"
    gj.write_text(
        json.dumps(
            {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"height_m": 20}, "geometry": bowtie}]}
        )
    )
    with pytest.raises(InputError, match="bad.geojson"):
        load_geometry(str(gj), 0)
    with pytest.raises(InputError, match="unknown procedural preset or style 'huge'"):
        load_geometry("procedural:huge", 0)
    res = CliRunner().invoke(
        uavdata, ["simulate", "procedural:tiny", "--name", "t", "--out", str(tmp_path), "--user", f"{inside.x},{inside.y}"]
    )
    assert res.exit_code == 2 and "is inside a building" in res.output
    assert not (tmp_path / "t").exists()
    res = CliRunner().invoke(uavdata, ["simulate", "procedural:tiny", "--name", "t", "--out", str(tmp_path), "--gap-fill", "1"])
    assert res.exit_code == 2 and "factors must be >= 2" in res.output
    res = CliRunner().invoke(
        uavdata, ["simulate", "procedural:tiny", "--name", "t", "--out", str(tmp_path), "--gap-fill-method", "smooth"]
    )
    assert res.exit_code == 2 and "takes its levels from coarse maps: add --gap-fill 4,16" in res.output
    assert not (tmp_path / "t").exists()
    for args, option in (
        (["--grid", "0"], "--grid"), (["--grid", "nan"], "--grid"), (["--samples", "nan"], "--samples"),
        (["--samples", "inf"], "--samples"), (["--extent", "nan,0,100,100"], "--extent"), (["--freq", "0"], "--freq"),
        (["--freq", "-8e8"], "--freq"), (["--crop=-inf,0,100,100"], "--crop"), (["--alt", "-10"], "--alt"),
        (["--count", "1000000000"], "--count"), (["--users", "100000000"], "--users"), (["--tx-dbm", "nan"], "--tx-dbm"),
        (["--depth", "99"], "--depth"), (["--extent", "0,0,50000,100"], "--extent"), (["--user", "nan,3"], "--user"),
        (["--grid", "0.5", "--extent", "0,0,4000,4000", "--users", "27"], "--extent"),  # 64 M cells: grid_cells
        (["--grid", "2", "--extent", "0,0,2000,2000", "--users", "1000"], "--extent with --grid and --users"),
    ):  # fmt: skip
        res = CliRunner().invoke(uavdata, ["simulate", "procedural:tiny", "--name", "t", "--out", str(tmp_path), *args])
        named = f"error: {option}:" in res.output or f"Invalid value for '{option}'" in res.output  # by click or by the check
        assert res.exit_code == 2 and named and "internal error" not in res.output, (args, res.output)
        assert not (tmp_path / "t").exists()


def test_a_missing_raytrace_extra_is_one_clear_line(tmp_path, monkeypatch):
    """Without the raytrace extra, simulate says which extra and packages to install, in one line (it printed the child
    process's whole traceback)."""
    from uavplace.simulate import raytrace

    monkeypatch.setattr(raytrace, "RAYTRACE_MODULES", {"uavplace_absent.rt": "sionna-rt", "json": "-"})
    res = CliRunner().invoke(uavdata, ["simulate", "procedural:tiny", "--name", "t", "--out", str(tmp_path)])
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert "needs the raytrace extra (missing: sionna-rt): pip install -e '.[raytrace]'" in lines[0]
    assert not (tmp_path / "t").exists()


def test_slab_transmission_has_p2040s_known_values():
    """ITU-R P.2040's single-layer slab: transparent when thin or matched, and at half a wavelength inside (a
    resonance); ((1 - r^2) / (1 + r^2))^2 at a quarter wavelength, r = (1 - n) / (1 + n); lossy slabs attenuate."""
    from uavplace.simulate.transmission import slab_transmission

    cos = np.array([1.0, 0.7, 0.2])
    for eta, thickness in ((4.0, 0.0), (1.0, 0.3)):
        te, tm = slab_transmission(cos, eta, thickness, 0.375)
        np.testing.assert_allclose([te, tm], 1.0, atol=1e-12)
    n, lam = 2.0, 0.375
    te, tm = slab_transmission(np.array([1.0]), n**2, lam / (2 * n), lam)
    np.testing.assert_allclose([te, tm], 1.0, atol=1e-12)
    r = (1 - n) / (1 + n)
    te, tm = slab_transmission(np.array([1.0]), n**2, lam / (4 * n), lam)
    np.testing.assert_allclose([te, tm], ((1 - r**2) / (1 + r**2)) ** 2, rtol=1e-12)
    te, _ = slab_transmission(np.array([1.0, 0.1]), complex(5.24, -0.9), 0.2, lam)
    assert 0 < te[1] < te[0] < 1  # grazing costs more than normal incidence


def test_lattice_measures_see_a_mosaic_and_not_a_city():
    """Dead regions made of 64 m blocks put every boundary on the 64 m lines; a disc of dead cells about 1 in 16 and
    1 in 4 (16 m lines). Levels constant per 16 m block step only across the 16 m lines; a smooth ramp steps evenly."""
    from uavplace.simulate.fidelity import lattice_boundary_shares, lattice_step_ratios

    opened = np.ones((96, 96), bool)
    blocks = np.zeros((96, 96), bool)
    blocks[16:48, 32:80] = True  # whole 64 m blocks (16 cells of 4 m)
    shares = lattice_boundary_shares(~blocks[None], opened)
    assert shares == {"16 m": 1.0, "64 m": 1.0}
    yy, xx = np.mgrid[:96, :96]
    disc = np.hypot(yy - 47.3, xx - 50.1) < 30.7
    shares = lattice_boundary_shares(~disc[None], opened)
    assert shares["64 m"] < 0.12 and 0.15 < shares["16 m"] < 0.35
    ramp = (0.1 * xx + 0.07 * yy)[None]
    steps = lattice_step_ratios(ramp, np.ones_like(ramp, bool), opened)
    assert steps["16 m"] == pytest.approx(1.0, abs=0.02) and steps["64 m"] == pytest.approx(1.0, abs=0.02)
    mosaic = ramp + 5.0 * np.random.default_rng(0).random((24, 24)).repeat(4, 0).repeat(4, 1)[None]
    steps = lattice_step_ratios(mosaic, np.ones_like(mosaic, bool), opened)
    assert steps["16 m"] > 3 and steps["64 m"] > 3


def test_error_quantiles_count_a_dead_estimate_of_a_live_pair_as_infinite():
    from uavplace.simulate.fidelity import error_quantiles

    ref = np.array([1e-9, 1e-9, 1e-9, 0.0])
    est = np.array([1e-9, 2e-9, 0.0, 1e-9])
    q = error_quantiles(est, ref, np.ones(4, bool))
    assert q["pairs"] == 3 and q["median_db"] == pytest.approx(10 * np.log10(2)) and q["p90_db"] == np.inf


def test_fill_scores_split_hit_and_missed_pairs():
    """Known answers: a hit pair 10 dB off, a missed pair left dead (infinite error), the SINR at the embedded level
    (95 dB above the gain, floored at -40 dB) and the dead/live agreement."""
    from uavplace.simulate.fidelity import SINR_FLOOR_DB, fill_scores, sinr_db

    ref = np.array([1e-10, 1e-10, 1e-12, 0.0])
    est = np.array([1e-10, 1e-9, 0.0, 1e-14])
    hit = np.array([True, True, False, False])
    s = fill_scores(est, ref, hit)
    assert s["hit_pairs"] == 2 and s["missed_pairs"] == 1 and s["missed_median_db"] == np.inf
    assert s["hit_p90_db"] == pytest.approx(10.0)
    np.testing.assert_allclose(sinr_db(ref), [-5.0, -5.0, -25.0, SINR_FLOOR_DB])
    assert s["sinr_missed_median_db"] == pytest.approx(7.5)  # |floor - (-25)| = 15 and |(-45 floored) - floor| = 0
    assert s["dead_live_agreement"] == pytest.approx(0.5)


def test_walk_fronts_record_the_cells_walked_around_a_wall():
    """``_walk_fronts``' front record is the walk through open cells from the known ones: around a wall, not across."""
    from uavplace.simulate.fill import _walk_fronts

    spread = np.ones((5, 7), bool)
    spread[0:4, 3] = False  # a wall down column 3, open at the bottom row
    known = np.zeros((5, 7), bool)
    known[0, 0] = True
    front = np.zeros((5, 7), int)
    _walk_fronts(np.zeros((5, 7)), known, spread, spread, 20, front=front)
    assert front[0, 1] == 1 and front[4, 3] == 7  # down 4, right 3
    assert front[0, 4] == 4 + 4 + 4  # around the wall's end: down 4, right 4, up 4
    assert front[1, 3] == 0 and not known[1, 3]  # the wall itself is never reached


def test_the_receiver_plane_has_a_cell_around_each_grid_point():
    """``ReceiverGrid.plane``: the box, centre and size of the cells the ray tracer measures, each grid point the
    centre of its cell (the cell-centre maths of ``RadioMapJob.cell_centres`` gives the grid's points back)."""
    from uavplace.simulate.insite import ReceiverGrid
    from uavplace.simulate.raytrace import RadioMapJob

    grid = ReceiverGrid(x0_m=2.0, y0_m=6.0, z_m=10.0, num_x=3, num_y=2, spacing_m=4.0)
    box, centre, size = grid.plane()
    assert box == (0.0, 4.0, 12.0, 12.0) and centre == (6.0, 8.0, 10.0) and size == (12.0, 8.0)
    job = RadioMapJob("unused.xml", ((0.0, 0.0, 1.5),), centre, size, grid.spacing_m)
    np.testing.assert_allclose(job.cell_centres(), grid.points())


def _simulate(tmp_path, *args: str, quiet: bool = True) -> subprocess.CompletedProcess:
    cmd = [
        *UAVDATA,
        "simulate",
        *args,
        "--out",
        str(tmp_path / "raw"),
        *(["--quiet"] if quiet else []),
    ]
    env = os.environ | {"PYTHONPATH": str(REPO)}
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    return res


@needs_sionna
def test_open_scene_follows_friis_plus_ground_reflection(tmp_path):
    """Ground only, LoS + one reflection: the cell powers match the incoherent two-ray model within 1 dB (median 0.3 dB)."""
    _simulate(
        tmp_path, "procedural:open", "--name", "open", "--user", "2,20", "--depth", "1", "--no-diffraction", "--samples", "2e6"
    )
    root = tmp_path / "p"
    ingest_city(tmp_path / "raw" / "open", root)
    rx = pd.read_parquet(root / "open" / "ingested" / "receivers.parquet")
    f, lam = 800e6, 3e8 / 800e6
    r = np.hypot(rx.x_m - 2.0, rx.y_m - 20.0)
    h1, h2 = 10.0 - 1.5, 10.0 + 1.5
    d1, d2 = np.hypot(r, h1), np.hypot(r, h2)

    def dipole(cos_zenith):  # half-wave dipole gain, Balanis 4-84
        return 1.643 * (np.cos(np.pi / 2 * cos_zenith) / np.sqrt(1 - cos_zenith**2)) ** 2

    g = GROUND.at(f)
    eps = g["relative_permittivity"] - 1j * g["conductivity_s_m"] / (2 * np.pi * f * 8.854e-12)
    s, c = h2 / d2, r / d2  # sine and cosine of the grazing angle
    gamma_v = (eps * s - np.sqrt(eps - c**2)) / (eps * s + np.sqrt(eps - c**2))
    gain = (lam / (4 * np.pi)) ** 2 * (dipole(h1 / d1) / d1**2 + np.abs(gamma_v) ** 2 * dipole(h2 / d2) / d2**2)
    expected = 20.0 + 10 * np.log10(gain)
    sel = (r > 20) & (r < 150)
    err = (rx.power_dbm - expected)[sel]
    assert err.notna().all()
    assert np.median(np.abs(err)) < 0.3 and np.abs(err).max() < 1.0


@needs_sionna
def test_exact_paths_behind_a_knife_edge_follow_itu_r_p526(tmp_path):
    """The fidelity benchmark's reference (``point_path_gains``, Sionna's PathSolver): behind a conducting screen
    12 m tall in free space, the path gain is free space minus P.526's single knife-edge loss J(v), within 3 dB."""
    from uavplace.simulate.knife_edge import BEHIND_M, EXACT_CONFIG, p526_path_gain_db, points, write_knife_edge_scene
    from uavplace.simulate.raytrace import point_path_gains_isolated

    job = write_knife_edge_scene(tmp_path)
    gain_db = 10 * np.log10(point_path_gains_isolated(job, points(), EXACT_CONFIG)[0])
    expected_db = p526_path_gain_db(BEHIND_M, EXACT_CONFIG.frequency_hz)
    assert np.abs(gain_db - expected_db).max() < 3.0, (gain_db, expected_db)


@needs_sionna
def test_direct_paths_through_walls_equal_the_exact_paths(tmp_path):
    """``direct_gains`` (Mitsuba crossings, P.2040 slabs) against Sionna's PathSolver in a scene where the straight
    path through a 20 m box is the only one (two refractions, no diffraction, depth 2): within 0.2 dB. A cell behind
    two boxes needs four crossings: none at depth 2, and the same path, 4 crossings, at depth 5."""
    from uavplace.simulate.raytrace import RadioMapJob, RayTraceConfig, direct_gains_isolated, point_path_gains_isolated
    from uavplace.simulate.scene import CONCRETE, Block, write_scene
    from uavplace.simulate.transmission import EVERY_SHAPE

    blocks = [Block(shapely.box(-15, -15, 15, 15), 0.0, 20.0, 0), Block(shapely.box(45, -15, 75, 15), 0.0, 20.0, 1)]
    xml, _ = write_scene(tmp_path, blocks, (-100, -100, 100, 100), 800e6)
    walls = {EVERY_SHAPE: CONCRETE.at(800e6)}
    job = RadioMapJob(str(xml), ((-40.0, 2.0, 1.5),), (0.0, 0.0, 10.0), (200.0, 200.0), 4.0)
    cells = [(25, 30), (27, 33), (23, 35), (26, 48)]  # (iy, ix): behind the first box; the last behind both
    pts = np.array([[-100 + (ix + 0.5) * 4, -100 + (iy + 0.5) * 4, 10.0] for iy, ix in cells])
    config = RayTraceConfig(max_depth=2, diffraction=False, samples_per_tx=200_000, seed=1)
    exact = point_path_gains_isolated(job, pts, config)[0]
    out = direct_gains_isolated(job, config, walls)
    got = np.array([out["direct"][0, iy, ix] for iy, ix in cells])
    crossings = [out["crossings"][0, iy, ix] for iy, ix in cells]
    assert crossings == [2, 2, 2, 3]  # the last: 4 crossings, more than depth 2
    np.testing.assert_allclose(10 * np.log10(got[:3]), 10 * np.log10(exact[:3]), atol=0.2)
    assert got[3] == 0 and exact[3] == 0
    deep = direct_gains_isolated(job, RayTraceConfig(max_depth=5), walls)
    assert deep["crossings"][0, 26, 48] == 4 and 0 < deep["direct"][0, 26, 48] < got[0]


@needs_sionna
def test_direct_paths_cross_each_wall_through_its_own_material(tmp_path):
    """A mix: the first box glass, the second brick, each its own mesh. The straight path through each box equals
    Sionna's PathSolver's (which reads each shape's material) within 0.2 dB; glass lets more through than the
    concrete it replaces at 3.5 GHz, and a path through both boxes loses the product of what each box alone takes from it."""
    from uavplace.simulate.raytrace import RadioMapJob, RayTraceConfig, direct_gains_isolated, point_path_gains_isolated
    from uavplace.simulate.scene import CONCRETE, Block, walls_of, write_scene
    from uavplace.simulate.transmission import EVERY_SHAPE

    blocks = [Block(shapely.box(-15, -15, 15, 15), 0.0, 20.0, 0), Block(shapely.box(45, -15, 75, 15), 0.0, 20.0, 1)]
    xml, materials = write_scene(tmp_path, blocks, (-100, -100, 100, 100), 3.5e9, materials_of={0: "glass", 1: "brick"})
    assert sorted(walls_of(materials)) == ["buildings-brick", "buildings-glass"]
    assert sorted(p.name for p in (tmp_path / "meshes").iterdir()) == ["buildings-brick.ply", "buildings-glass.ply", "ground.ply"]
    job = RadioMapJob(str(xml), ((-40.0, 2.0, 1.5), (100.0, 2.0, 1.5)), (0.0, 0.0, 10.0), (200.0, 200.0), 4.0)
    glass_cell, brick_cell = (25, 30), (25, 39)  # behind the glass box from the first user; behind the brick one from the second
    pts = np.array([[-100 + (ix + 0.5) * 4, -100 + (iy + 0.5) * 4, 10.0] for iy, ix in (glass_cell, brick_cell)])
    config = RayTraceConfig(frequency_hz=3.5e9, max_depth=2, diffraction=False, samples_per_tx=200_000, seed=1)
    exact = point_path_gains_isolated(job, pts, config)
    out = direct_gains_isolated(job, config, walls_of(materials))
    got = np.array([out["direct"][0][glass_cell], out["direct"][1][brick_cell]])
    np.testing.assert_allclose(10 * np.log10(got), 10 * np.log10([exact[0, 0], exact[1, 1]]), atol=0.2)
    concrete = direct_gains_isolated(job, config, {EVERY_SHAPE: CONCRETE.at(3.5e9)})
    assert concrete["direct"][0][glass_cell] < got[0] / 10  # two concrete walls take over 10 dB more than glass
    deep = RayTraceConfig(frequency_hz=3.5e9, max_depth=5)
    glass, brick = (walls_of(materials)[f"buildings-{name}"] for name in ("glass", "brick"))
    vacuum = {"relative_permittivity": 1.0, "conductivity_s_m": 0.0, "thickness_m": 0.2}  # a wall that is not there

    def through(walls: dict) -> float:  # the path from the first user through both boxes, over free space
        return direct_gains_isolated(job, deep, walls)["direct"][0, 25, 48]

    free = through({EVERY_SHAPE: vacuum})
    mixed = through(walls_of(materials)) / free
    glass_only = through({"buildings-glass": glass, "buildings-brick": vacuum}) / free
    brick_only = through({"buildings-glass": vacuum, "buildings-brick": brick}) / free
    assert 0 < mixed < glass_only < 1 and mixed < brick_only < 1
    np.testing.assert_allclose(mixed, glass_only * brick_only, rtol=1e-9)


@needs_sionna
def test_simulate_with_exact_paths_at_every_open_cell(tmp_path):
    """--solver paths: every open cell of a corner of the tiny city from PathSolver, as a direct call gives it; the
    cells under a building unreached; nothing filled; the record says so, and the same command resumes."""
    from uavplace.simulate.insite import ReceiverGrid
    from uavplace.simulate.pipeline import open_cells
    from uavplace.simulate.raytrace import RadioMapJob, RayTraceConfig, exact_path_maps
    from uavplace.simulate.scene import write_scene

    args = ["procedural:tiny", "--name", "tp", "--user", "70,46", "--extent", "52,38,76,54", "--solver", "paths",
            "--samples", "1e5", "--seed", "4"]  # fmt: skip
    _simulate(tmp_path, *args)
    record = json.loads((tmp_path / "raw" / "tp" / "simulation.json").read_text())
    assert record["raytrace"]["solver"] == "paths" and record["cells"]["monte_carlo_gaps_filled"] == 0
    assert record["cells"]["gap_fill"].startswith("none: every open cell from exact paths")
    assert "already done with the same settings" in _simulate(tmp_path, *args).stdout
    root = tmp_path / "p"
    ingest_city(tmp_path / "raw" / "tp", root)
    b = load_bundle(build_city("tp", BuildConfig(grid_m=4.0, altitude_m=10.0, crop=True), root).path)
    assert b.shape == (4, 6)

    blocks, _, _ = load_geometry("procedural:tiny", 4)
    xml, _ = write_scene(tmp_path / "scene", blocks, (52.0, 38.0, 76.0, 54.0), 800e6)
    grid = ReceiverGrid(x0_m=54.0, y0_m=40.0, z_m=10.0, num_x=6, num_y=4, spacing_m=4.0)
    opened = open_cells(blocks, grid)
    assert 0 < opened.sum() < opened.size  # the corner holds a building's edge
    job = RadioMapJob(str(xml), ((70.0, 46.0, 1.5),), (64.0, 46.0, 10.0), (24.0, 16.0), 4.0)
    gain = exact_path_maps(job, RayTraceConfig(samples_per_tx=100_000, seed=4, solver="paths"), opened)[0]
    assert (gain[~opened] == 0).all() and (gain[opened] > 0).all()
    expected = np.maximum(20.0 + 10 * np.log10(np.where(opened, gain, 1.0)) - EMBEDDED_NOISE_DBM, -40.0)
    np.testing.assert_allclose(b.sinr_db[0][opened], expected[opened], atol=0.01)
    np.testing.assert_array_equal(b.dead[0], ~opened)


@needs_sionna
def test_surround_traces_the_buildings_around_a_crop_and_writes_the_crops_only(tmp_path):
    """``--surround M``: the buildings within M of a ``--crop`` are traced too (a wall 4 m beyond the crop's edge
    reflects rays into the block's shadow: cells there gain power, those far from it hardly), while the city written, its
    grid, users and buildings, is the crop's, as without it; the record says so. Without --crop it is refused."""
    block = shapely.box(36, 36, 44, 44)  # inside the crop
    wall = shapely.box(64, -40, 70, 100)  # outside the crop (0..60), within 20 m of it
    features = [{"type": "Feature", "properties": {"height_m": h}, "geometry": shapely.geometry.mapping(g)}
                for g, h in ((block, 20.0), (wall, 40.0))]  # fmt: skip
    source = tmp_path / "two.geojson"
    source.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    common = [str(source), "--crop=0,0,60,60", "--user", "20,20", "--samples", "1e5", "--seed", "3"]
    _simulate(tmp_path, *common, "--name", "bare")
    _simulate(tmp_path, *common, "--name", "walled", "--surround", "20")
    bundles = {}
    for name in ("bare", "walled"):
        raw = tmp_path / "raw" / name
        assert len(read_city(raw / f"{name}.city")) == 1  # the crop's building only
        ingest_city(raw, tmp_path / "p")
        bundles[name] = load_bundle(build_city(name, BuildConfig(grid_m=4.0, altitude_m=10.0), tmp_path / "p").path)
    record = json.loads((tmp_path / "raw" / "walled" / "simulation.json").read_text())
    assert record["spec"]["surround_m"] == 20.0 and "traced with the buildings within 20 m around it" in record["geometry"]
    assert "surround_m" not in json.loads((tmp_path / "raw" / "bare" / "simulation.json").read_text())["spec"]
    bare, walled = bundles["bare"], bundles["walled"]
    assert bare.shape == walled.shape == (15, 15)
    np.testing.assert_array_equal(bare.blocked, walled.blocked)
    np.testing.assert_array_equal(bare.height_rel_m, walled.height_rel_m)
    gained = np.where(bare.dead[0] | walled.dead[0], np.nan, walled.sinr_db[0] - bare.sinr_db[0])
    assert np.nanmax(gained[:, -4:]) > 3.0  # near the wall, behind the block: its reflections light the shadow
    assert np.nanmedian(np.abs(gained[:, :7])) < 0.2  # the crop's far half: about the same values
    res = CliRunner().invoke(uavdata, ["simulate", "procedural:tiny", "--name", "t", "--out", str(tmp_path), "--surround", "20"])
    assert res.exit_code == 2 and "--surround" in res.output and "give --crop too" in res.output, res.output


@needs_sionna
def test_simulate_with_a_material_mix_records_each_buildings_class_and_paths_go_through_it(tmp_path):
    """``--materials glass=0.5,metal=0.5`` on the tiny city: simulation.json names each building's class (half each)
    and the materials with their meshes; the trace differs from the all-concrete one (another key). With every
    building metal, no straight path through a wall carries power; through concrete, they do."""
    common = ["procedural:tiny", "--users", "2", "--samples", "3e3", "--seed", "4", "--depth", "2",
              "--trace-cache", str(tmp_path / "cache")]  # fmt: skip
    _simulate(tmp_path, *common, "--name", "mix", "--materials", "glass=0.5,metal=0.5")
    record = json.loads((tmp_path / "raw" / "mix" / "simulation.json").read_text())
    classes = list(record["building_materials"].values())
    assert len(classes) == record["num_buildings"] and classes.count("glass") - classes.count("metal") in (-1, 0, 1)
    assert {m["itu_name"]: m["shapes"] for m in record["materials"]} == {
        "medium_dry_ground": ["ground"], "glass": ["buildings-glass"], "metal": ["buildings-metal"]
    }  # fmt: skip
    assert record["spec"]["materials"] == ["glass=0.5", "metal=0.5"]
    direct = {}
    for name, words in (("plain", []), ("metal", ["--materials", "metal"])):
        _simulate(tmp_path, *common, "--name", name, *words)
        with np.load(tmp_path / "cache" / f"{name}.npz", allow_pickle=False) as z:
            direct[name], crossings = z["direct"], z["crossings"]
    through = (crossings >= 1) & (crossings <= 2)
    assert through.sum() > 20 and (direct["plain"][through] > 0).all()
    assert (direct["metal"][through] < 1e-30).all() and (direct["metal"][crossings == 0] == direct["plain"][crossings == 0]).all()
    assert "materials" not in json.loads((tmp_path / "raw" / "plain" / "simulation.json").read_text())["spec"]


@needs_sionna
def test_simulate_ingest_build_round_trip(tmp_path):
    """The tiny city through the real commands; the bundle's SINR equals the radio map's, computed here again."""
    from uavplace.simulate.fill import fill
    from uavplace.simulate.insite import ReceiverGrid
    from uavplace.simulate.pipeline import direct_maps, open_cells, squared_distances
    from uavplace.simulate.raytrace import RadioMapJob, RayTraceConfig, path_gain_maps_isolated
    from uavplace.simulate.scene import write_scene

    res = _simulate(tmp_path, "procedural:tiny", "--name", "tiny", "--users", "3", "--samples", "2e5", "--seed", "4", quiet=False)
    assert "simulate tiny: ray tracing 3/3" in res.stderr  # not a terminal: a line per step, for logs
    record = json.loads((tmp_path / "raw" / "tiny" / "simulation.json").read_text())
    assert record["cells"]["user_cells"] == 3 * 24 * 20 and record["packages"]["sionna-rt"] != "not installed"
    again = _simulate(tmp_path, "procedural:tiny", "--name", "tiny", "--users", "3", "--samples", "2e5", "--seed", "4")
    assert "tiny: already done with the same settings" in again.stdout, again.stdout  # one city resumes too
    assert json.loads((tmp_path / "raw" / "tiny" / "simulation.json").read_text()) == record
    root = tmp_path / "p"
    ingest_city(tmp_path / "raw" / "tiny", root)
    b = load_bundle(build_city("tiny", BuildConfig(grid_m=4.0, altitude_m=10.0), root).path)
    assert b.shape == (20, 24) and b.num_users == 3 and b.manifest.counts["buildings"] == record["num_buildings"]

    blocks, bounds, _ = load_geometry("procedural:tiny", 4)
    xml, _ = write_scene(tmp_path / "scene", blocks, bounds, 800e6)
    users = np.array(record["users_m"])
    cfg = RayTraceConfig(samples_per_tx=200_000, seed=4)
    job = RadioMapJob(str(xml), tuple(map(tuple, users.tolist())), (48.0, 40.0, 10.0), (96.0, 80.0), 4.0)
    grid = ReceiverGrid(x0_m=2.0, y0_m=2.0, z_m=10.0, num_x=24, num_y=20, spacing_m=4.0)
    maps = path_gain_maps_isolated(job, cfg) | direct_maps(job, cfg)
    gain, _ = fill(maps, cfg, open_cells(blocks, grid), squared_distances(users, grid))
    live = gain > 0
    expected = 20.0 + 10 * np.log10(np.where(live, gain, 1.0)) - EMBEDDED_NOISE_DBM  # the build's default noise
    cells = [(0, 3, 4), (1, 10, 12), (2, 17, 20), (0, 0, 0)]
    for u, iy, ix in cells:
        if live[u, iy, ix]:
            assert b.sinr_db[u, iy, ix] == pytest.approx(max(expected[u, iy, ix], -40.0), abs=0.01)
        else:
            assert b.dead[u, iy, ix]
    np.testing.assert_array_equal(b.dead, ~live)


@needs_sionna
@pytest.mark.slow
def test_a_corpus_runs_on_local_ray_and_resumes(tmp_path):
    """Two tiny cities of generator v2 as Ray tasks; the same command again skips them; seeds make the cities."""
    pytest.importorskip("ray")
    args = ("procedural:mixed:96x96", "--count", "2", "--name", "c", "--users", "2", "--samples", "1e5", "--seed", "10")
    res = _simulate(tmp_path, *args)
    assert "simulated 2 of 2 cities" in res.stdout, res.stdout
    records = [json.loads((tmp_path / "raw" / f"c-00{i}" / "simulation.json").read_text()) for i in (0, 1)]
    assert [r["spec"]["seed"] for r in records] == [10, 11] and [r["raytrace"]["seed"] for r in records] == [10, 11]
    assert records[0]["spec"]["source"] == "procedural:mixed:96x96" and "procedural style" in records[0]["geometry"]
    res = _simulate(tmp_path, *args)
    assert "simulated 0 of 2 cities" in res.stdout and "2 already done with the same settings: c-000, c-001" in res.stdout
    # the last city alone (--first 1: one city left, traced in this process) takes the ray seed the corpus gave it
    _simulate(tmp_path / "alone", *args, "--first", "1")
    alone = json.loads((tmp_path / "alone" / "raw" / "c-001" / "simulation.json").read_text())
    assert (alone["spec"]["seed"], alone["raytrace"]["seed"]) == (11, 11)


def test_a_corpus_continued_from_an_index_names_and_seeds_its_cities_as_the_whole_corpus_does():
    from uavplace.schemas import InputError
    from uavplace.simulate.config import Simulation
    from uavplace.simulate.corpus import corpus_specs

    base = Simulation(name="tm", seed=1000).city("procedural:mixed")
    whole = corpus_specs(["procedural:mixed"], "tm", 5, base)
    later = corpus_specs(["procedural:mixed"], "tm", 5, base, first=3)
    assert [(s.name, s.seed) for s in later] == [("tm-003", 1003), ("tm-004", 1004)] and later == whole[3:]
    for first, count in ((5, 5), (1, 1)):
        with pytest.raises(InputError, match="--first"):
            corpus_specs(["procedural:mixed"], "tm", count, base, first=first)


def test_styles_are_seeded_and_varied():
    from uavplace.simulate.styles import MIXED, STYLES, styled_city

    for name in STYLES:
        used, a = styled_city(name, (200.0, 200.0), 3)
        _, b = styled_city(name, (200.0, 200.0), 3)
        assert used == name and len(a) > 3 and [p.wkt for p, *_ in a] == [p.wkt for p, *_ in b]
        assert all(p.is_valid and 0 <= p.bounds[0] and p.bounds[2] <= 200 for p, *_ in a)
    _, towers = styled_city("towers", (400.0, 400.0), 2)
    assert len({k for *_, k in towers}) < len(towers)  # some buildings are a podium and a tower
    picked = [styled_city("mixed", (100.0, 100.0), s)[0] for s in range(100, 106)]
    # The corpus's recipe (seeds 100..117) names its cities by seed: mixed keeps the first six styles in turn.
    assert picked == ["rotated", "towers", "grid", "organic", "perimeter", "plazas"] and set(picked) == set(MIXED)
    assert set(STYLES) - set(MIXED) == {"oldtown", "tiered"}
    _, tiered = styled_city("tiered", (400.0, 400.0), 3000)
    high = shapely.union_all([p for p, h, _ in tiered if h > 10]).area / 400**2
    assert len(tiered) > 2 * len({k for *_, k in tiered}) and 0.15 < high < 0.45  # few buildings, many roof tiers
    _, old = styled_city("oldtown", (200.0, 200.0), 5)
    lanes = shapely.box(0, 0, 200, 200).difference(shapely.union_all([p for p, *_ in old]))
    assert 0.3 < lanes.area / 200**2 < 0.6  # dense: narrow lanes and a few piazzas between small blocks


def test_trace_cache_entries_are_checked_and_damage_is_traced_again(tmp_path):
    """A trace cache entry is used only when it is whole and carries the sha256 of what made it and of its arrays: a
    truncated, random, altered or reshaped entry, one of other settings, or one whose header claims a huge array is
    traced again (never a crash, nothing decompressed past the limits); a FIFO there is refused before any tracing."""
    import io
    import os
    import zipfile

    from uavplace.simulate.trace_cache import cached_traces

    calls = []

    def trace():  # noqa: ANN202
        calls.append(1)
        return {0: np.arange(12.0).reshape(3, 4), "direct": np.ones((2, 3, 4), np.float32)}

    cache = tmp_path / "cache"
    maps, status = cached_traces(cache, "c", "settings A", trace)
    assert status == "none" and len(calls) == 1
    again, status = cached_traces(cache, "c", "settings A", trace)
    assert (
        status == "used"
        and len(calls) == 1
        and np.array_equal(again[0], maps[0])
        and np.array_equal(again["direct"], maps["direct"])
    )
    entry = cache / "c.npz"
    whole = entry.read_bytes()

    def rewrite(**arrays) -> bytes:  # noqa: ANN003
        with np.load(io.BytesIO(whole), allow_pickle=False) as z:
            kept = {k: z[k] for k in z.files} | arrays
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **kept)
        return buffer.getvalue()

    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**9, 10**6)})
    bomb = io.BytesIO()
    with zipfile.ZipFile(bomb, "w") as z:
        z.writestr("f0.npy", header.getvalue())
    damages = {
        "truncated": (whole[: len(whole) // 2], "unreadable"),
        "random": (os.urandom(len(whole)), "unreadable"),
        "altered": (rewrite(f0=np.arange(12.0).reshape(3, 4) + 1), "do not match the sha256"),
        "reshaped": (rewrite(f0=np.arange(12.0).reshape(4, 3)), "do not match the sha256"),
        "other settings": (rewrite(key=np.array("settings B")), "made with other settings"),
        "huge header": (bomb.getvalue(), "over the limit array_bytes"),
    }
    for what, (data, message) in damages.items():
        entry.write_bytes(data)
        before = len(calls)
        maps, status = cached_traces(cache, "c", "settings A", trace)
        assert len(calls) == before + 1 and status.startswith("traced again") and message in status, (what, status)
        assert cached_traces(cache, "c", "settings A", trace)[1] == "used"  # the new trace was kept, whole
    # An entry whose arrays, each within the limits, hold more than this simulation makes (a 2 GB archive of a
    # small city's key) is traced again from its headers, before anything is decompressed.
    entry.write_bytes(rewrite(f0=np.zeros((1000, 3, 4))))
    maps, status = cached_traces(cache, "c", "settings A", trace, max_bytes=1000)
    assert status.startswith("traced again") and "more than this simulation makes" in status, status
    assert cached_traces(cache, "c", "settings A", trace, max_bytes=1000)[1] == "used"
    entry.unlink()
    os.mkfifo(entry)
    with pytest.raises(InputError, match="not a regular file"):
        cached_traces(cache, "c", "settings A", trace)
    assert entry.is_fifo()


@needs_sionna
def test_each_cell_of_a_small_traced_city_says_where_its_value_came_from(tmp_path):
    """Few rays, one wall for the straight path and an 8 m walk: the tiny city has hit, straight-path, walked and
    unreached cells. Each carries its code in the side file, the ingested receivers, the bundle and `uavdata show`,
    checked against the traced maps kept in the trace cache (what the rays hit, the straight paths) and the export."""
    from uavplace.dataset.preview import estimated_cells
    from uavplace.schemas.provenance import RAY_TRACED, STRAIGHT_PATH, UNREACHED, WALKED

    _simulate(tmp_path, "procedural:tiny", "--name", "tiny", "--users", "3", "--samples", "3e3", "--seed", "4", "--depth", "1",
              "--gap-fill-reach", "8", "--trace-cache", str(tmp_path / "cache"))  # fmt: skip
    with np.load(tmp_path / "cache" / "tiny.npz", allow_pickle=False) as z:
        hit, direct = z["f1"] > 0, z["direct"]
    root = tmp_path / "p"
    ingest_city(tmp_path / "raw" / "tiny", root)
    rx = pd.read_parquet(root / "tiny" / "ingested" / "receivers.parquet").sort_values(["tx_point", "rx_index"])
    expected = np.full(hit.shape, WALKED, np.uint8)
    power = rx["power_dbm"].to_numpy(dtype=float, na_value=np.nan).reshape(hit.shape)
    with np.errstate(divide="ignore"):
        straight = 20.0 + 10 * np.log10(direct)  # the user's 20 dBm along the straight path alone
    expected[np.abs(power - straight) < 2e-4] = STRAIGHT_PATH  # the export's value is the straight path's
    expected[np.isnan(power)] = UNREACHED
    expected[hit] = RAY_TRACED
    assert set(np.unique(expected)) == {UNREACHED, RAY_TRACED, STRAIGHT_PATH, WALKED}
    np.testing.assert_array_equal(rx["provenance"].to_numpy().reshape(hit.shape), expected)
    b = load_bundle(build_city("tiny", BuildConfig(grid_m=4.0, altitude_m=10.0), root).path)
    np.testing.assert_array_equal(b.provenance, expected)  # the export's receivers are the grid's cells
    assert sum(b.cell_sources().values()) == 3 * int((~b.blocked).sum())
    for code, mask in estimated_cells(b, 0).items():
        np.testing.assert_array_equal(mask, (expected[0] == code) & ~b.blocked)


@needs_sionna
@pytest.mark.slow
def test_exact_paths_complete_the_missed_cells_as_ray_tasks_and_resume_per_user(tmp_path):
    """--complete-missed: every open cell the rays missed carries PathSolver's value (the same as PathSolver at that
    point alone) and the code "exact paths" (or "unreached" where it finds none); nothing open is walked or given its
    straight path; run again, every user's paths come from the trace cache and the export is the same."""
    from uavplace.schemas.provenance import EXACT_PATHS, RAY_TRACED, STRAIGHT_PATH, UNREACHED
    from uavplace.simulate.insite import ReceiverGrid
    from uavplace.simulate.pipeline import open_cells
    from uavplace.simulate.raytrace import RadioMapJob, RayTraceConfig, point_path_gains_isolated
    from uavplace.simulate.scene import write_scene

    args = ("procedural:tiny", "--name", "tiny", "--users", "2", "--samples", "3e3", "--seed", "4", "--depth", "1",
            "--gap-fill-reach", "8", "--trace-cache", str(tmp_path / "cache"), "--complete-missed", "--complete-samples", "2e4")  # fmt: skip
    _simulate(tmp_path, *args)
    record = json.loads((tmp_path / "raw" / "tiny" / "simulation.json").read_text())
    with np.load(tmp_path / "cache" / "tiny.npz", allow_pickle=False) as z:
        hit = z["f1"] > 0
    blocks, bounds, _ = load_geometry("procedural:tiny", 4)
    grid = ReceiverGrid(x0_m=2.0, y0_m=2.0, z_m=10.0, num_x=24, num_y=20, spacing_m=4.0)
    missed = ~hit & open_cells(blocks, grid)
    root = tmp_path / "p"
    ingest_city(tmp_path / "raw" / "tiny", root)
    rx = pd.read_parquet(root / "tiny" / "ingested" / "receivers.parquet").sort_values(["tx_point", "rx_index"])
    code = rx["provenance"].to_numpy().reshape(hit.shape)
    assert set(np.unique(code[missed])) <= {EXACT_PATHS, UNREACHED} and (code[missed] == EXACT_PATHS).any()
    assert (code[hit] == RAY_TRACED).all() and set(np.unique(code[~hit & ~missed])) <= {STRAIGHT_PATH, UNREACHED}
    assert record["complete_missed"]["cells"] == int(missed.sum()) and record["complete_missed"]["users_from_cache"] == 0
    power = rx["power_dbm"].to_numpy(dtype=float, na_value=np.nan).reshape(hit.shape)
    u, iy, ix = (int(a[0]) for a in np.nonzero(code == EXACT_PATHS))  # one completed cell, traced again on its own
    xml, _ = write_scene(tmp_path / "scene", blocks, bounds, 800e6)
    job = RadioMapJob(str(xml), (tuple(record["users_m"][u]),), (48.0, 40.0, 10.0), (96.0, 80.0), 4.0)
    alone = point_path_gains_isolated(job, np.array([[4.0 * ix + 2, 4.0 * iy + 2, 10.0]]),
                                      RayTraceConfig(samples_per_tx=20_000, seed=4, max_depth=1))  # fmt: skip
    assert power[u, iy, ix] == pytest.approx(20.0 + 10 * np.log10(alone[0, 0]), abs=0.5)

    again = tmp_path / "again"
    _simulate(again, *args)  # the same trace cache
    redo = json.loads((again / "raw" / "tiny" / "simulation.json").read_text())
    assert redo["complete_missed"]["users_from_cache"] == 2 and redo["complete_missed"]["seconds"] == 0
    for f in sorted((tmp_path / "raw" / "tiny").glob("*.p2m.gz")) + [tmp_path / "raw" / "tiny" / "tiny.provenance.csv.gz"]:
        assert gzip.decompress((again / "raw" / "tiny" / f.name).read_bytes()) == gzip.decompress(f.read_bytes()), f.name


def test_the_free_space_cap_is_friis_with_the_antenna_and_paths_in_phase():
    """A radio map's cell above free space with the user antenna's gain and +6 dB is a grazing ray's artifact: the cap
    is Friis' gain at the 3D distance, 2.15 dBi for the half-wave dipole, 6 dB more."""
    from uavplace.simulate.raytrace import free_space_cap

    d = np.array([8.5, 100.0])
    friis_db = 20 * np.log10(299_792_458.0 / 8e8 / (4 * np.pi * d))
    np.testing.assert_allclose(10 * np.log10(free_space_cap(d**2, 8e8, "hw_dipole")), friis_db + 10 * np.log10(1.64) + 6)
    np.testing.assert_allclose(10 * np.log10(free_space_cap(d**2, 8e8, "iso")), friis_db + 6)

"""Where each cell's value came from: the fill's codes, the side file, ingest's checks, the bundle's (issue 51)."""

from __future__ import annotations

import gzip
import json

import numpy as np
import pandas as pd
import pytest

from tests.conftest import write_grid_city
from uavplace.dataset.build import build_city
from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.checks import check_provenance
from uavplace.ingest.pipeline import ingest_city
from uavplace.ingest.provenance import read_provenance
from uavplace.schemas import InputError
from uavplace.schemas.bundle import BuildConfig
from uavplace.schemas.provenance import (
    COARSE_MAP,
    CODES,
    CODES_PER_ROW,
    EXACT_PATHS,
    NO_RECEIVER,
    NOT_RECORDED,
    PROVENANCE_COLUMNS,
    RAY_TRACED,
    RECEIVER_CODES,
    RUN_COLUMNS,
    STRAIGHT_PATH,
    UNREACHED,
    WALKED,
)
from uavplace.simulate.fill import fill, fill_geodesic
from uavplace.simulate.insite import write_provenance
from uavplace.simulate.raytrace import RayTraceConfig


def _lit(walk: str, open_cells: np.ndarray, hit_at: tuple[int, int], reach_m: float = 24.0) -> np.ndarray:
    fine = np.zeros((1, *open_cells.shape))
    fine[0][hit_at] = 1e-9
    gain, code = fill_geodesic(fine, np.zeros_like(fine), open_cells, np.full(fine.shape, 1e4), reach_m=reach_m,
                               decay_db_per_m=3.0, cell_m=4.0, walk=walk)  # fmt: skip
    assert set(np.unique(code[0][gain[0] > 0])) <= {RAY_TRACED, WALKED}
    return gain[0] > 0


def test_the_walk_lights_a_disc_not_a_diamond_and_never_cuts_a_wall():
    """An isolated hit cell in the open: the 4-neighbour walk lights the diamond |dx| + |dy| <= 6 cells, the
    Euclidean one the cells within 6 cells' straight distance (to 3 %); neither passes a wall, nor its corner."""
    open_cells = np.ones((21, 21), bool)
    iy, ix = np.mgrid[-10:11, -10:11]
    np.testing.assert_array_equal(_lit("4-neighbour", open_cells, (10, 10)), np.abs(iy) + np.abs(ix) <= 6)
    disc = _lit("euclidean", open_cells, (10, 10))
    r = np.hypot(iy, ix)
    assert disc[r <= 6].all() and not disc[r > 6 * 1.03].any()
    assert disc.sum() == (r <= 6).sum() == 113 and (np.abs(iy) + np.abs(ix) <= 6).sum() == 85  # about pi r^2, 2 r^2
    # a wall across the field with one gap: behind it, only what walks through the gap, within reach of the way
    wall = open_cells.copy()
    wall[:, 12] = False
    wall[2, 12] = True
    behind = _lit("euclidean", wall, (10, 10))[:, 13:]
    assert not behind[8:].any()  # the way through the gap at row 2 is longer than 24 m to these
    way = np.hypot(2 - 10, 12 - 10) + np.hypot(iy[:, 13:] + 10 - 2, ix[:, 13:] + 10 - 12)
    assert not behind[way > 6 * 1.03].any()
    corner = np.ones((5, 5), bool)
    corner[0, 1] = corner[1, 0] = False  # two walls meet diagonally between (0, 0) and (1, 1)
    lit = _lit("euclidean", corner, (1, 1), reach_m=6.0)  # 1.5 cells: the diagonal step would reach (0, 0)
    assert not lit[0, 0] and lit[1, 2] and lit[2, 2]


def test_the_fills_say_which_cells_were_hit_walked_given_their_straight_path_or_left_unreached():
    fine = np.zeros((1, 1, 8))
    fine[0, 0, 0] = 1e-6  # hit
    direct = np.zeros_like(fine)
    direct[0, 0, 1] = 1e-12  # next to the hit cell: the walk's value is larger than this straight path
    direct[0, 0, 5] = 1e-9  # out of the walk's reach: the straight path
    open_cells = np.ones((1, 8), bool)
    d2 = np.full(fine.shape, 100.0)
    gain, code = fill_geodesic(fine, direct, open_cells, d2, reach_m=8.0, decay_db_per_m=3.0, cell_m=4.0)
    np.testing.assert_array_equal(
        code[0, 0], [RAY_TRACED, WALKED, WALKED, UNREACHED, UNREACHED, STRAIGHT_PATH, UNREACHED, UNREACHED]
    )
    assert gain[0, 0, 5] == direct[0, 0, 5] and gain[0, 0, 1] > direct[0, 0, 1] and (gain[code == UNREACHED] == 0).all()
    coarse = {1: fine, 4: np.full((1, 1, 2), 1e-7)}
    for method in ("parent", "smooth"):
        _, c = fill(coarse, RayTraceConfig(gap_fill_method=method, gap_fill_factors=(4,)), open_cells, d2)
        assert c[0, 0, 0] == RAY_TRACED and (c[0, 0, 1:] == COARSE_MAP).all()
    exact = np.where(np.arange(8) % 2, 1e-9, 0.0).reshape(1, 1, 8)
    _, c = fill({1: exact}, RayTraceConfig(solver="paths"), open_cells, d2)
    np.testing.assert_array_equal(c[0, 0], np.where(np.arange(8) % 2, EXACT_PATHS, UNREACHED))


def _side_file(path, lines: list[str], columns: tuple[str, ...] = PROVENANCE_COLUMNS) -> None:
    with gzip.open(path, "wt") as f:
        f.write(f"# comment\n{','.join(columns)}\n" + "".join(f"{line}\n" for line in lines))


def test_every_code_is_one_digit():
    """The side file writes a receiver's code as one digit."""
    assert all(0 <= code <= 9 for code in CODES) and set(RECEIVER_CODES) <= set(CODES)


def test_the_side_file_round_trips_and_refuses_what_is_not_a_row_of_codes(tmp_path):
    long = np.resize(np.array([1, 4, 4, 0, 3, 2, 5, 6], np.uint8), 2 * CODES_PER_ROW + 7)  # three rows
    codes = {(1, 1): np.array([1, 1, 4, 4, 4, 0, 3, 1], np.uint8), (1, 2): np.zeros(8, np.uint8), (2, 1): long}
    path = write_provenance(tmp_path, "c", 2, codes)
    text = gzip.decompress(path.read_bytes()).decode().splitlines()
    assert "1,1,2,1,11444031" in text and "2,1,2,4001," + "".join(map(str, long[4000:])) in text
    assert max(len(line) for line in text if not line.startswith("#")) <= len("2,1,2,4001,") + CODES_PER_ROW
    got = read_provenance(path, path.name)
    assert got.keys() == {(1, 1, 2), (1, 2, 2), (2, 1, 2)}
    assert all(np.array_equal(got[(*k, 2)], c) and got[(*k, 2)].dtype == np.uint8 for k, c in codes.items())
    assert path.read_bytes() == write_provenance(tmp_path, "c", 2, codes).read_bytes()  # the same codes, the same bytes
    bad = {
        "1,1,2,1,14x1": r":3: codes: receiver 3: 'x' is not a code \(a digit\)",
        "1,1,2,1,1471": r":3: codes: receiver 3: 7 is not a receiver's code",
        "1,1,2,1,": r":3: codes: no code",
        "1,1,2,1," + "1" * (CODES_PER_ROW + 1): rf":3: codes: {CODES_PER_ROW + 1} codes, more than a row holds",
        "1,1,2,1": r":3: row: 4 fields, expected 5",
        "1,1,2,0,1": r":3: first_rx: 0 is not a count",
        "1,x,2,1,1": r":3: tx_point: 'x' is not an integer",
        "1,1,2,1,1111\n1,1,2,6,11": r":4: first_rx: row starts at receiver 6; .* reach 4",
        "1,1,2,1,1111\n1,1,2,3,11": r":4: first_rx: row starts at receiver 3",
    }
    # The runs of an earlier version's side files: read, and checked as before.
    f = tmp_path / "runs.provenance.csv.gz"
    _side_file(f, ["1,1,2,1,2,1", "1,1,2,3,3,4", "1,1,2,6,1,0", "1,1,2,7,1,3", "1,1,2,8,1,1"], RUN_COLUMNS)
    np.testing.assert_array_equal(read_provenance(f, f.name)[(1, 1, 2)], codes[(1, 1)])
    runs = {
        "1,1,2,1,x,1": r":3: count: 'x' is not an integer",
        "1,1,2,1,4,7": r":3: code: 7 is not a receiver's code",
        "1,1,2,1,4": r":3: row: 5 fields, expected 6",
        "1,1,2,1,0,1": r":3: count: 0 is not a count",
        "1,1,2,1,4,1\n1,1,2,6,2,1": r":4: first_rx: row starts at receiver 6; .* reach 4",
        "1,1,2,1,1000000000000,1": r":3: count: receivers the rows describe: .* over the limit",  # never allocated
    }
    for columns, cases in ((PROVENANCE_COLUMNS, bad), (RUN_COLUMNS, runs)):
        for k, (text, pattern) in enumerate(cases.items()):
            f = tmp_path / f"bad{len(columns)}-{k}.provenance.csv.gz"
            _side_file(f, text.split("\n"), columns)
            with pytest.raises(InputError, match=pattern):
                read_provenance(f, f.name)
    f = tmp_path / "runs.provenance.csv.gz"  # an earlier version's run of 9e8 receivers where the export holds 16
    _side_file(f, ["1,1,2,1,900000000,1"], RUN_COLUMNS)
    with pytest.raises(InputError, match=r":3: count: a row of 900,000,000 receivers, more than the export holds \(16\)"):
        read_provenance(f, f.name, receivers=16)
    f = tmp_path / "empty.provenance.csv.gz"
    f.write_bytes(gzip.compress(b"# nothing\n"))
    with pytest.raises(InputError, match="header: no header line"):
        read_provenance(f, f.name)
    f.write_bytes(b"not gzip")
    with pytest.raises(InputError, match="not a readable gzip file"):
        read_provenance(f, f.name)
    # A small gzip of newlines (2 GB of text) or of one endless line is refused as it streams, past what runs of the
    # export's receivers take, never read whole (it once reached 4.6 GB of memory).
    f.write_bytes(gzip.compress(b"\n" * 20_000_000))
    with pytest.raises(InputError, match="more than the codes of the export's receivers take"):
        read_provenance(f, f.name, receivers=16)
    f.write_bytes(gzip.compress(b"1" * 10_000))
    with pytest.raises(InputError, match="a line longer than 4096 characters"):
        read_provenance(f, f.name)
    f.write_bytes(gzip.compress(b"\xff\xfe garbage\n"))
    with pytest.raises(InputError, match="not UTF-8"):
        read_provenance(f, f.name)


def _codes_for(folder, root) -> dict[tuple[int, int], np.ndarray]:
    """Codes for a grid city's receivers as a side file would give them: unreached where the export says so, and
    ray-traced, walked, straight path in turn elsewhere."""
    ingest_city(folder, root)
    rx = pd.read_parquet(root / "city" / "ingested" / "receivers.parquet").sort_values(["tx_point", "rx_index"])
    out = {}
    for (tx_set, tx_point), g in rx.groupby(["tx_set_id", "tx_point"]):
        turn = np.array([RAY_TRACED, WALKED, STRAIGHT_PATH])[np.arange(len(g)) % 3]
        out[(int(tx_set), int(tx_point))] = np.where(g["reached"].to_numpy(bool), turn, UNREACHED).astype(np.uint8)
    return out


def test_ingest_reads_the_side_file_against_the_export_and_says_what_an_export_without_one_is(tmp_path):
    folder = write_grid_city(tmp_path / "raw" / "city", dead_share=0.3)
    codes = _codes_for(folder, tmp_path / "p0")
    assert (pd.read_parquet(tmp_path / "p0" / "city" / "ingested" / "receivers.parquet")["provenance"].isin([0, 1])).all()
    write_provenance(folder, "city", 2, codes)
    _, manifest, _ = ingest_city(folder, tmp_path / "p")
    rx = pd.read_parquet(tmp_path / "p" / "city" / "ingested" / "receivers.parquet").sort_values(["tx_point", "rx_index"])
    np.testing.assert_array_equal(rx["provenance"].to_numpy(), np.concatenate([codes[k] for k in sorted(codes)]))
    assert manifest.counts["receiver_rows_walked"] == sum(int((c == WALKED).sum()) for c in codes.values())
    b = load_bundle(build_city("city", BuildConfig(grid_m=4.0, altitude_m=10.0), tmp_path / "p").path)
    assert b.cell_sources()["walked"] == sum(int((c == WALKED).sum()) for c in codes.values())

    # a reached receiver said unreached; runs for fewer receivers than the export has; a transmitter without runs
    k = int(np.argmax(codes[(1, 1)] == WALKED))
    wrong = {key: c.copy() for key, c in codes.items()}
    wrong[(1, 1)][k] = UNREACHED
    write_provenance(folder, "city", 2, wrong)
    with pytest.raises(InputError, match=rf"city.provenance.csv.gz: code: transmitter 1 of set 1, receiver {k + 1}: code 0 "
                       r"\(unreached\), but city.pl.t001_01.r002.p2m says a path reached it"):  # fmt: skip
        ingest_city(folder, tmp_path / "p")
    write_provenance(folder, "city", 2, {key: c[:-1] for key, c in codes.items()})
    with pytest.raises(
        InputError, match=r"codes: the rows of transmitter 1 of set 1 and receiver set 2 describe receivers 1..29"
    ):
        ingest_city(folder, tmp_path / "p")
    write_provenance(folder, "city", 2, {(1, 1): codes[(1, 1)]})
    with pytest.raises(InputError, match=r"tx_point: no rows for transmitter 2 of set 1 and receiver set 2"):
        ingest_city(folder, tmp_path / "p")
    write_provenance(folder, "city", 2, codes | {(1, 9): codes[(1, 1)]})
    with pytest.raises(InputError, match=r"codes: the rows of transmitter 9 of set 1 and receiver set 2 describe 30 receivers, "
                       r"the export has 0"):  # fmt: skip
        ingest_city(folder, tmp_path / "p")
    assert b.path.is_dir()  # nothing refused replaced the good ingest's bundle

    # A side file records the sha256 of its export's .p2m files: beside the same export it is read, beside another
    # simulation's (one receiver's value changed) it is refused, never taken for the codes of these receivers.
    p2m = sorted(folder.glob("*.p2m*"))
    write_provenance(folder, "city", 2, codes, p2m)
    _, _, report = ingest_city(folder, tmp_path / "p")
    assert not any("records no sha256" in w for w in report.warnings)
    text = p2m[0].read_text().splitlines()
    last = text[-1].split()
    text[-1] = " ".join([*last[:-2], f"{float(last[-2]) + 1:.4f}", last[-1]])
    p2m[0].write_text("\n".join(text) + "\n")
    with pytest.raises(InputError, match=r"city.provenance.csv.gz: export: written for another export"):
        ingest_city(folder, tmp_path / "p")
    write_provenance(folder, "city", 2, codes)  # an older side file records none: read, with a warning
    _, _, report = ingest_city(folder, tmp_path / "p")
    assert any("records no sha256 of its export" in w for w in report.warnings)

    # without a side file: a simulation.json of exact paths, or of an earlier uavplace (not recorded)
    (folder / "city.provenance.csv.gz").unlink()
    for solver, code in (("paths", EXACT_PATHS), ("radio-map", NOT_RECORDED)):
        (folder / "simulation.json").write_text(json.dumps({"raytrace": {"solver": solver}}))
        _, manifest, _ = ingest_city(folder, tmp_path / "p")
        rx = pd.read_parquet(tmp_path / "p" / "city" / "ingested" / "receivers.parquet")
        assert set(rx["provenance"]) == {UNREACHED, code}
        assert manifest.counts["receiver_rows_not_recorded"] == (int(rx["reached"].sum()) if code == NOT_RECORDED else 0)


def test_a_bundle_whose_provenance_disagrees_with_its_maps_is_refused():
    dead = np.array([[[True, False, False]]])
    num_rx = np.array([[[1, 1, 0]]])
    check_provenance("maps.npz", np.array([[[UNREACHED, WALKED, 8]]], np.uint8), dead, num_rx)
    for codes, pattern in (
        ([[[RAY_TRACED, WALKED, 8]]], r"cell \[0, 0, 0\]: code 1 \(ray-traced\) but the cell is dead with 1 receiver"),
        ([[[UNREACHED, UNREACHED, 8]]], r"cell \[0, 0, 1\]: code 0 \(unreached\) but the cell is live"),
        ([[[UNREACHED, WALKED, WALKED]]], r"cell \[0, 0, 2\]: code 4 \(walked\) but the cell is live with 0 receiver"),
        ([[[NO_RECEIVER, WALKED, 8]]], r"cell \[0, 0, 0\]: code 7 \(no receiver\) but the cell is dead with 1"),
        ([[[UNREACHED, 200, 8]]], r"cell \[0, 0, 1\]: 200 is not a provenance code"),
    ):
        with pytest.raises(InputError, match="maps.npz: provenance: " + pattern):
            check_provenance("maps.npz", np.array(codes, np.uint8), dead, num_rx)


def test_the_docs_code_table_is_the_contract():
    """docs/simulate.md's table of codes lists exactly ``schemas.provenance.CODES``' names, in order."""
    from tests.conftest import REPO
    from uavplace.schemas.provenance import CODES

    rows = [line.split("|")[1:3] for line in (REPO / "docs" / "simulate.md").read_text().splitlines() if line[:4] in
            {f"| {c} " for c in range(10)}]  # fmt: skip
    assert [(int(c), n.strip()) for c, n in rows] == [(c, name) for c, (name, _) in CODES.items()]

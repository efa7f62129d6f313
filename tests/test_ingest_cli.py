"""`uavdata ingest` end to end: real fixture folders, synthetic cities, the bad-input corpus."""

from __future__ import annotations

import json
import shutil

import duckdb
import pandas as pd
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from tests.conftest import write_grid_city
from uavplace.cli import uavdata, uavrl
from uavplace.infra.files import sha256_file
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas import CityManifest, IngestReport


def run(*args: str):
    return CliRunner().invoke(uavdata, list(args), catch_exceptions=False)


def ingested(out, city):
    base = out / city / "ingested"
    manifest = CityManifest.model_validate_json((base / "manifest.json").read_text())
    report = IngestReport.model_validate_json((base / "ingest_report.json").read_text())
    return base, manifest, report


def test_rosslyn_folder(rosslyn, tmp_path):
    res = run("ingest", str(rosslyn), "--out", str(tmp_path), "--name", "rosslyn")
    assert res.exit_code == 0, res.output
    assert "1 users, 10 receiver rows (10 reached), 29 buildings, 0 rows rejected" in res.output
    base, m, report = ingested(tmp_path, "rosslyn")
    assert m.counts["files"] == 14 and m.counts["files_skipped"] == 5 and m.counts["terrain_triangles"] == 119
    assert m.origin is not None and (m.origin.longitude, m.origin.latitude) == (-77.0787, 38.8907)
    assert m.frequency_hz == 60e9 and m.tx_power_dbm == (0.0,)
    skipped = {f.path for f in report.files if f.status == "skipped"}
    assert skipped == {f"model.{o}.t001_01.r002.p2m" for o in ("doa", "dod", "dspower", "paths")} | {"model.inputpower.t01.p2m"}
    rx = pq.read_table(base / "receivers.parquet").to_pandas()
    assert len(rx) == 10
    row = rx.iloc[0]
    assert (row.path_loss_db, row.path_gain_db, row.power_dbm, row.txloss_db) == (147.583, -147.583, -143.281, 147.583)
    assert row.delay_spread_s == pytest.approx(7.35315e-08) and bool(row.reached)
    assert rx.sinr_db.isna().all()
    tx = pq.read_table(base / "transmitters.parquet").to_pylist()
    assert tx[0]["x_m"] == 746.0 and tx[0]["frequency_hz"] == 60e9 and tx[0]["antenna"] == "HalfWaveDipole"
    # every table's hash is in the manifest, every source file's hash too
    for name, digest in m.tables.items():
        fname = "terrain.npz" if name == "terrain" else f"{name}.parquet"
        assert sha256_file(base / fname) == digest
    assert {s.path: s.sha256 for s in m.sources}["Rosslyn.city"] == sha256_file(rosslyn / "Rosslyn.city")
    assert any("lists 1 point(s) but its outputs have 10 rows" in w for w in report.warnings)


def test_deepmimo_folder(deepmimo, tmp_path):
    res = run("ingest", str(deepmimo), "--out", str(tmp_path), "--quiet")
    assert res.exit_code == 0, res.output
    _, m, report = ingested(tmp_path, "deepmimo-2025-grid")
    assert m.counts["receiver_rows"] == 1 + 1 + 4617 and m.counts["receiver_rows_reached"] == 1 + 457
    assert m.counts["transmitters"] == 3 and m.counts["buildings"] == 0 and m.frequency_hz == 3.5e9
    assert {r.status for r in report.files if r.path.startswith(("insite.cir", "insite.doa", "insite.paths"))} == {"skipped"}
    con = duckdb.connect()
    rx = f"'{tmp_path}/deepmimo-2025-grid/ingested/receivers.parquet'"
    # r002 has both a pl and a pg file: one row, both columns, both sentinels
    merged = con.sql(f"select path_loss_db, path_gain_db, reached from {rx} where rx_set_id = 2").fetchall()
    assert merged == [(None, None, False)]
    assert con.sql(f"select count(*) from {rx} where rx_set_id = 4 and not reached").fetchall() == [(4160,)]


def test_boxes_folder(boxes, tmp_path):
    res = run("ingest", str(boxes), "--out", str(tmp_path))
    assert res.exit_code == 0, res.output
    base, m, _ = ingested(tmp_path, "halosnoopy-2023-boxes")
    assert m.counts["buildings"] == 6 and m.counts["receiver_rows"] == 0 and m.counts["transmitters"] == 3
    assert [t["power_dbm"] for t in pq.read_table(base / "transmitters.parquet").to_pylist()] == [30.0] * 3
    assert m.setup is not None and len(m.setup.comm_systems) == 3


def test_synthetic_city_gz_crlf_merge(tmp_path):
    city = write_grid_city(tmp_path / "raw" / "tiny", outputs=("pl", "power"), gz=True, crlf=True)
    out, m, report = ingest_city(city, tmp_path / "proc")
    rx = pd.read_parquet(out / "receivers.parquet")
    assert len(rx) == 2 * 30 and m.counts["transmitters"] == 2 and m.frequency_hz == 8e8
    assert m.tx_power_dbm == (20.0,)
    # power = 20 - path loss wherever reached, null with the path loss where not
    reached = rx[rx.reached.astype(bool)]
    assert ((20 - reached.path_loss_db) - reached.power_dbm).abs().max() < 1e-3
    assert rx[~rx.reached.astype(bool)][["path_loss_db", "power_dbm", "phase_deg"]].isna().all().all()
    assert report.rows_rejected == 0 and report.warnings == ()


def test_unknown_file_is_a_warning(tmp_path):
    city = write_grid_city(tmp_path / "tiny")
    (city / "notes.txt").write_text("hello")
    res = run("ingest", str(city), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 0
    assert "warning: notes.txt: unknown file type, ignored" in res.output
    _, m, _ = ingested(tmp_path / "proc", "tiny")
    assert m.counts["files_unknown"] == 1


def _rewrite(path, old, new):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


BAD = {
    "truncated row": (
        lambda c: _rewrite(c / "city.pl.t001_01.r002.p2m", "\n30 ", "\n30 1 "),
        "city.pl.t001_01.r002.p2m:33: row:",
    ),
    "missing column": (
        lambda c: _rewrite(c / "city.pl.t002_01.r002.p2m", "<Distance(m)> ", ""),
        "city.pl.t002_01.r002.p2m:3: header:",
    ),
    "text in number": (
        lambda c: _rewrite(c / "city.pl.t001_01.r002.p2m", "\n5 ", "\n5 x"),
        "city.pl.t001_01.r002.p2m:8: x_m: 'x",
    ),
    "duplicate receiver": (
        lambda c: _rewrite(c / "city.pl.t001_01.r002.p2m", "\n6 ", "\n5 "),
        "city.pl.t001_01.r002.p2m:9: rx_index: duplicate",
    ),
    "nan": (
        lambda c: (c / "city.pl.t001_01.r002.p2m").write_text(
            (c / "city.pl.t001_01.r002.p2m").read_text().replace("\n", "\n", 3)[:-1].rsplit(" ", 1)[0] + " nan\n"
        ),
        "city.pl.t001_01.r002.p2m:33: path_loss_db: value nan",
    ),
    "grid row count": (
        lambda c: _rewrite(c / "city.txrx", "side2 16.000000", "side2 20.000000"),
        "city.pl.t001_01.r002.p2m: rows: 30 rows, but grid 'Drone_grid' (city.txrx:19) is 6 x 6 = 36",
    ),
    "off the lattice": (
        lambda c: _rewrite(c / "city.txrx", "\n10.000000 -20.000000 10.000000", "\n11.000000 -20.000000 10.000000"),
        "x_m: receiver 1 at x_m=10.0, off grid",
    ),
    "face with 2 vertices": (
        lambda c: (c / "b.city").write_text(
            "begin_<city> c\nbegin_<structure> s\nbegin_<face> f\nnVertices 2\n0 0 0\n1 1 1\nend_<face>\nend_<structure>\nend_<city>\n"
        ),
        "b.city:4: nVertices: face has 2 vertices",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_corpus(tmp_path, case):
    """Each bad input: one line naming file, line and field; exit 2; the previous ingest untouched."""
    city = write_grid_city(tmp_path / "tiny")
    proc = tmp_path / "proc"
    assert run("ingest", str(city), "--out", str(proc), "--quiet").exit_code == 0
    before = {p.name: p.read_bytes() for p in (proc / "tiny" / "ingested").iterdir()}
    mutate, expected = BAD[case]
    mutate(city)
    res = run("ingest", str(city), "--out", str(proc), "--quiet")
    assert res.exit_code == 2
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and expected in lines[0], res.output
    after = {p.name: p.read_bytes() for p in (proc / "tiny" / "ingested").iterdir()}
    assert after == before
    assert sorted(p.name for p in (proc / "tiny").iterdir()) == [".ingested.lock", "ingested"]


def test_empty_and_unknown_only_folders(tmp_path):
    (tmp_path / "empty").mkdir()
    res = run("ingest", str(tmp_path / "empty"), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 2 and "empty folder" in res.output
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "photo.jpg").write_bytes(b"\xff\xd8")
    res = run("ingest", str(tmp_path / "junk"), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 2 and "no receiver output" in res.output
    assert not (tmp_path / "proc").exists() or not any((tmp_path / "proc").rglob("*.parquet"))


def test_renamed_outputs_and_a_floor_plan_are_refused_saying_what_is_read(tmp_path):
    """Receiver outputs a user renamed, a CIR (per path) and a floor plan: the refusal says why each was passed over,
    that a .p2m is recognised by its <project>.<output>.tTTT_SS.rRRR name, and which outputs are read."""
    folder = tmp_path / "mine"
    folder.mkdir()
    for name in ("power_north.p2m", "power_south.p2m", "city.cir.t001_01.r002.p2m", "floor.flp"):
        (folder / name).write_text("# nothing\n")
    res = run("ingest", str(folder), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 2, res.output
    text = " ".join(res.output.split())  # the error line as one, whatever the terminal's width
    assert "2 x a .p2m whose name is not <project>.<output>.tTTT_SS.rRRR.p2m (e.g. power_north.p2m)" in text
    assert "1 x complex impulse response, per path (not used by uavplace) (e.g. city.cir.t001_01.r002.p2m)" in text
    assert "1 x a Wireless InSite object, foliage or floor plan: not read" in text and "(e.g. floor.flp)" in text
    assert "outputs power, pl, pg, txloss, spread, noise" in text


def test_two_folders_of_one_city_name_are_refused_before_any_work(tmp_path):
    """`uavdata ingest tiny other/tiny`: the second would silently replace the first's tables."""
    one, two = write_grid_city(tmp_path / "tiny"), write_grid_city(tmp_path / "other" / "tiny")
    res = run("ingest", str(one), str(two), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 2 and "are both city 'tiny'" in res.output, res.output
    res = run("ingest", str(one), str(tmp_path / "tiny" / "."), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 2 and "given twice" in res.output, res.output
    assert not (tmp_path / "proc").exists()


def test_quantity_given_twice(tmp_path):
    city = write_grid_city(tmp_path / "tiny")
    shutil.copy(city / "city.pl.t001_01.r002.p2m", city / "other.pl.t001_01.r002.p2m")
    res = run("ingest", str(city), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 2 and "path_loss_db for t001_01 r002 is also given by" in res.output


def test_interrupted_swap_recovers(tmp_path):
    city = write_grid_city(tmp_path / "tiny")
    out, _, _ = ingest_city(city, tmp_path / "proc")
    # a crash between the two renames leaves only the old folder, renamed aside
    out.rename(out.parent / ".ingested.old")
    (out.parent / ".ingested.tmp-dead").mkdir()
    out2, _, _ = ingest_city(city, tmp_path / "proc")
    assert sorted(p.name for p in out2.parent.iterdir()) == [".ingested.lock", "ingested"]


def test_list_schema_and_help(tmp_path, rosslyn):
    assert run("ingest", str(rosslyn), "--out", str(tmp_path / "p"), "--quiet").exit_code == 0
    res = run("list", "--root", str(tmp_path / "p"))
    assert "lasse-2018-rosslyn" in res.output and res.exit_code == 0
    res = CliRunner().invoke(uavrl, ["datasets", "--root", str(tmp_path / "p")])
    assert res.exit_code == 0 and "lasse-2018-rosslyn" in res.output
    res = run("schema", "--out", str(tmp_path / "s"))
    assert res.exit_code == 0
    names = sorted(p.name for p in (tmp_path / "s").iterdir())
    assert "city_manifest.schema.json" in names and "table_receivers.schema.json" in names
    table = json.loads((tmp_path / "s" / "table_receivers.schema.json").read_text())
    assert table["properties"]["power_dbm"]["unit"] == "dBm" and table["properties"]["reached"]["type"] == ["boolean", "null"]
    res = run("schema", "ingest_report")
    assert res.exit_code == 0 and json.loads(res.output)["title"] == "IngestReport"
    for cmd in (["--help"], ["ingest", "--help"], ["schema", "--help"], ["list", "--help"]):
        res = run(*cmd)
        assert res.exit_code == 0 and "Usage:" in res.output
    assert "--out" in run("ingest", "--help").output


def _ingest_peak_mb(city, out) -> float:
    """Peak RSS [MB] a child process gains running the real ingest, above its own imports."""
    import subprocess
    import sys

    from tests.conftest import REPO

    code = (
        "import sys\n"
        "def hwm(): return int(next(l for l in open('/proc/self/status') if l.startswith('VmHWM')).split()[1]) / 1024\n"
        "import uavplace.ingest.cli, uavplace.ingest.pipeline\n"
        "base = hwm()\n"
        "uavplace.ingest.pipeline.ingest_city(sys.argv[1], sys.argv[2])\n"
        "print(hwm() - base)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code, str(city), str(out)], cwd=REPO, capture_output=True, text=True, check=True)
    return float(proc.stdout.split()[-1])


@pytest.mark.slow
def test_ingest_memory_stays_flat(tmp_path):
    """A .p2m ten times larger costs the ingest little more memory: it is read and written in batches."""
    import numpy as np

    from uavplace.simulate.insite import write_p2m

    peaks = {}
    for rows in (100_000, 1_000_000):
        city = tmp_path / f"c{rows}"
        city.mkdir()
        i = np.arange(rows)
        pos = np.column_stack([(i % 1000) * 4.0, (i // 1000) * 4.0, np.full(rows, 10.0)])
        write_p2m(city, "big", "power", tx_point=1, tx_set=(1, "U"), rx_set=(2, "R"), positions_m=pos,
                  distance_m=np.hypot(pos[:, 0], pos[:, 1]) + 1, values=-60 - (i % 50) * 1.0)  # fmt: skip
        peaks[rows] = _ingest_peak_mb(city, tmp_path / "proc")
    assert peaks[1_000_000] < peaks[100_000] + 80, peaks  # reading whole cost about 230 MB per million rows


def test_versions_units_and_bracketed_names_are_shown(tmp_path):
    from importlib.metadata import version

    for cli, name in ((uavdata, "uavdata"), (uavrl, "uavrl")):
        res = CliRunner().invoke(cli, ["--version"])
        assert res.exit_code == 0 and res.output.strip() == f"{name}, version {version('uavplace')}"
    assert "default noise plus interference, -75 dBm" in " ".join(run("--help").output.split())
    city = write_grid_city(tmp_path / "city")
    (city / "notes [draft].txt").write_text("x")
    res = run("ingest", str(city), "--out", str(tmp_path / "proc"))
    assert res.exit_code == 0 and "notes [draft].txt" in res.output  # a warning is printed whatever the verbosity
    assert "city: files" not in res.output and res.output.count("ingested city:") == 1  # a line per city by default
    res = run("ingest", str(city), "--out", str(tmp_path / "proc"), "--verbose")
    assert res.exit_code == 0 and "city: files" in res.output and "unknown" in res.output  # the table of every file
    res = run("list", "--root", str(tmp_path / "proc"))
    assert "frequency [MHz]" in res.output


def test_underground_roofs_are_rejected_and_an_empty_city_warns(tmp_path):
    """A roof-only building at z = -20 m (below the ground, 0 m without terrain) is counted as rejected, not kept as a
    building that can never block; a .city without structures says so."""
    from tests.bad_inputs.cases import _city_file, _face

    city = write_grid_city(tmp_path / "c")
    for f in city.glob("*.city"):
        f.unlink()
    (city / "b.city").write_text(_city_file(_face((0, 0, -20), (10, 0, -20), (10, 10, -20), (0, 10, -20))))
    (city / "e.city").write_text("begin_<city> c\nend_<city>\n")
    _, manifest, report = ingest_city(city, tmp_path / "out")
    assert manifest.counts["buildings"] == 0 and manifest.counts["rows_rejected"] == 1
    assert any("roof at -20 m is below the ground (0 m without terrain)" in r.reason for r in report.rejections)
    assert any("e.city: no building in this Wireless InSite .city file" in w for w in report.warnings)


def test_every_help_names_its_ranges_without_none():
    """Every option of every command of both CLIs in ``--help``: a range shown as it is (an unbounded finite number
    reads "finite", never click's ``x<=None``)."""
    import click

    for group in (uavdata, uavrl):
        names = group.list_commands(click.Context(group))  # the lazy groups load a command when it is asked for
        assert "build" in names or "train" in names
        for name in names:
            res = CliRunner().invoke(group, [name, "--help"], terminal_width=200)
            assert res.exit_code == 0, (group.name, name, res.output)
            assert "None]" not in res.output and "x<=None" not in res.output, (group.name, name)


def test_no_help_text_carries_a_date():
    """The product says what is true now: no `--help` of either CLI, nor any package file, dates a measurement (the
    history lives in experiments/log/)."""
    import re

    from tests.conftest import REPO

    dated = re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b")
    for cli in (uavdata, uavrl):
        for name in ["", *cli.list_commands(None)]:
            text = CliRunner().invoke(cli, [name, "--help"] if name else ["--help"]).output
            assert not dated.search(text), (name, dated.search(text))
    for package in ("schemas", "infra", "ingest", "dataset", "simulate", "rl", "eval", "cli"):
        for path in (REPO / package).rglob("*.py"):
            lines = [n for n, line in enumerate(path.read_text().splitlines(), 1) if dated.search(line)]
            assert not lines, f"{path.relative_to(REPO)}:{lines[0]} dates a measurement"


def test_a_mistyped_city_is_named_with_the_nearest_before_anything_heavy_loads(tmp_path):
    """`uavrl report --dataset florense` and `uavdata build --city florense`: one line with the nearest names,
    refused before torch (the agents, the searcher) is imported."""
    import subprocess
    import sys

    root = tmp_path / "p"
    ingest_city(write_grid_city(tmp_path / "florence"), root)
    script = (
        "import sys\n"
        "from click.testing import CliRunner\n"
        "from uavplace.cli import uavdata, uavrl\n"
        f"r = CliRunner().invoke(uavrl, ['report', '--dataset', 'florense', '--root', {str(root)!r}])\n"
        f"b = CliRunner().invoke(uavdata, ['build', '--city', 'florense', '--root', {str(root)!r}])\n"
        "print(r.exit_code, b.exit_code, 'torch' in sys.modules)\n"
        "print(r.output.strip())\n"
        "print(b.output.strip())\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[0] == "2 2 False", out
    assert "did you mean florence?" in out[1] and "city 'florence' is ingested but not built" not in out[1]
    assert "no ingested city of that name: did you mean florence?" in out[2]


def test_a_mistyped_command_is_answered_with_the_nearest_commands():
    """`uavrl trian`, `uavdata biuld`: one error line that names the nearest command, lazy commands included (click
    alone offers only the commands already loaded); a word like none gets no guess."""
    from uavplace.cli import uavdata, uavrl

    for group, typed, near in ((uavrl, "trian", "'train'"), (uavdata, "biuld", "'build'"), (uavrl, "reprot", "'report'")):
        res = CliRunner().invoke(group, [typed])
        assert res.exit_code == 2 and f"No such command '{typed}'. Did you mean {near}?" in res.output, res.output
    res = CliRunner().invoke(uavdata, ["zzz"])
    assert res.exit_code == 2 and "No such command 'zzz'." in res.output and "Did you mean" not in res.output
    assert CliRunner().invoke(uavrl, ["--help"]).exit_code == 0

"""The .p2m reader against real Wireless InSite outputs and synthetic variants."""

from __future__ import annotations

import gzip
import shutil

import numpy as np
import pyarrow as pa
import pytest

from uavplace.ingest.wireless_insite.p2m import read_p2m
from uavplace.ingest.wireless_insite.p2m_header import parse_filename
from uavplace.schemas import InputError


def test_deepmimo_full_grid(deepmimo):
    meta, t = read_p2m(deepmimo / "insite.pl.t001_01.r004.p2m")
    assert meta.header_style == "insite4"
    assert (meta.tx_set_id, meta.tx_point, meta.rx_set_id) == (1, 1, 4)
    assert (meta.tx_set_name, meta.rx_set_name) == ("BS1", "UE_grid")
    assert meta.num_rows == 81 * 57 == t.num_rows
    assert meta.num_reached == 4617 - 4160
    d = t.to_pandas()
    first, last = d.iloc[0], d.iloc[-1]
    assert (first.rx_index, first.x_m, first.y_m, first.z_m, first.distance_m) == (1, -100.37, -70.9989, 2, 162.379)
    assert (last.rx_index, last.x_m, last.y_m, last.distance_m) == (4617, 99.63, 69.0011, 85.221)
    # sentinel 250 is "not reached" and never a value
    assert not first.reached and np.isnan(first.path_loss_db)
    assert d.path_loss_db.isna().sum() == 4160
    assert d.path_loss_db.max() == pytest.approx(115.044)
    assert d.path_loss_db.min() == pytest.approx(53.4931)
    reached = d[d.reached]
    assert reached.iloc[0].rx_index == 60 and reached.iloc[0].path_loss_db == pytest.approx(81.0577)


def test_deepmimo_path_gain_sentinel(deepmimo):
    meta, t = read_p2m(deepmimo / "insite.pg.t001_01.r002.p2m")
    assert meta.num_rows == 1 and meta.num_reached == 0
    assert t.column("path_gain_db").null_count == 1


def test_rosslyn_old_header_all_quantities(rosslyn):
    expect = {
        "pl": ("path_loss_db", 147.583, 128.327),
        "pg": ("path_gain_db", -147.583, -128.327),
        "txloss": ("txloss_db", 147.583, 128.327),
        "power": ("power_dbm", -143.281, -124.025),
        "spread": ("delay_spread_s", 7.35315e-08, 3.8769e-08),
    }
    for output, (column, first, last) in expect.items():
        meta, t = read_p2m(rosslyn / f"model.{output}.t001_01.r002.p2m")
        assert meta.header_style == "insite3" and meta.num_rows == 10
        values = t.column(column).to_pylist()
        assert values[0] == pytest.approx(first) and values[-1] == pytest.approx(last)
        assert t.column("x_m").to_pylist()[-1] == pytest.approx(677.164)
    meta, t = read_p2m(rosslyn / "model.power.t001_01.r002.p2m")
    assert t.column("phase_deg").to_pylist()[0] == pytest.approx(-152.143)
    assert meta.num_reached == 10
    meta, _ = read_p2m(rosslyn / "model.spread.t001_01.r002.p2m")
    assert meta.num_reached is None  # delay spread carries no reach information


@pytest.mark.parametrize(
    "name,expect",
    [
        ("model.pl.t001_01.r002.p2m", ("model", "pl", 1, 1, 2)),
        ("a.b.power.t0012_1005.r1002.p2m.gz", ("a.b", "power", 12, 1005, 1002)),
        ("insite.paths.t001_01.r001.p2m", ("insite", "paths", 1, 1, 1)),
        ("model.inputpower.t01.p2m", ("model", "inputpower", None, 1, None)),
    ],
)
def test_filenames(name, expect):
    n = parse_filename(name)
    assert n is not None and (n.project, n.output, n.tx_point, n.tx_set, n.rx_set) == expect


def test_skip_reasons():
    assert parse_filename("x.cir.t001_01.r001.p2m").skip_reason.startswith("complex impulse")
    assert parse_filename("x.pl.t001_01.r001.p2m").skip_reason is None
    assert "unknown" in parse_filename("x.weird.t001_01.r001.p2m").skip_reason
    assert parse_filename("notes.p2m") is None


def test_gzip_and_crlf_read_like_plain(deepmimo, tmp_path):
    src = deepmimo / "insite.pl.t001_01.r004.p2m"
    crlf = tmp_path / src.name
    crlf.write_bytes(src.read_bytes().replace(b"\n", b"\r\n"))
    gz = tmp_path / "g" / (src.name + ".gz")
    gz.parent.mkdir()
    with gzip.open(gz, "wb") as f:
        f.write(src.read_bytes())
    _, ref = read_p2m(src)
    for path in (crlf, gz):
        _, t = read_p2m(path)
        assert t.equals(ref)


def test_irregular_spacing_falls_back(rosslyn, tmp_path):
    src = rosslyn / "model.pl.t001_01.r002.p2m"
    lines = src.read_text().splitlines()
    padded = lines[:2] + ["  " + "\t".join(line.split()) + "  " for line in lines[2:]]
    (tmp_path / src.name).write_text("\n".join(padded) + "\n")
    _, t = read_p2m(tmp_path / src.name)
    _, ref = read_p2m(src)
    assert t.equals(ref)


def test_power_threshold_marks_unreached(tmp_path, rosslyn):
    shutil.copy(rosslyn / "model.power.t001_01.r002.p2m", tmp_path)
    meta, t = read_p2m(tmp_path / "model.power.t001_01.r002.p2m", power_threshold_dbm=-130.0)
    powers = [-143.281, -105.432, -124.257, -108.367, -101.32]
    assert meta.power_threshold_dbm == -130.0
    assert t.column("reached").to_pylist()[:5] == [p > -130 for p in powers]
    assert t.column("power_dbm").to_pylist()[0] is None


def _corrupt(tmp_path, deepmimo, line_no: int, new: str | None) -> tuple[str, int]:
    src = deepmimo / "insite.pl.t001_01.r004.p2m"
    lines = src.read_text().splitlines()
    if new is None:
        del lines[line_no - 1]
    else:
        lines[line_no - 1] = new
    dst = tmp_path / src.name
    dst.write_text("\n".join(lines) + "\n")
    return str(dst), line_no


@pytest.mark.parametrize(
    "line,new,field,words",
    [
        (100, "97 -100.37 -70.9989 2 162.379", "path_loss_db", "truncated"),
        (4620, "4617 99.63 69.0011", "z_m", "found 3 (truncated row?)"),
        (50, "47 12.0 -70.9989 2 40 abc", "path_loss_db", "'abc' is not a number"),
        (51, "48 12.0 -70.9989 x2 40 80", "z_m", "'x2' is not a number"),
        (200, "197 -100.37 -70.9989 2 162.379 nan", "path_loss_db", "not a finite number"),
        (300, "296 -100.37 -70.9989 2 162.379 250", "rx_index", "duplicate receiver number 296 (first at line 299)"),
        (10, "7 -100.37 -70.9989 2 162.379 250 1", "row", "found 7"),
    ],
)
def test_bad_rows_name_file_line_field(tmp_path, deepmimo, line, new, field, words):
    path, line_no = _corrupt(tmp_path, deepmimo, line, new)
    with pytest.raises(InputError) as exc:
        read_p2m(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}:{line_no}: {field}:"), msg
    assert words in msg and "\n" not in msg


def test_header_column_mismatch(tmp_path, deepmimo):
    src = deepmimo / "insite.pl.t001_01.r001.p2m"
    dst = tmp_path / "insite.pl.t001_01.r001.p2m"
    dst.write_text(src.read_text().replace("<PathLoss(dB)>", "<PathGain(dB)>"))
    with pytest.raises(InputError, match=r":3: PathGain: column 'PathGain' where a 'pl' output has path_loss_db"):
        read_p2m(dst)
    dst.write_text(src.read_text().replace(" <PathLoss(dB)>", ""))
    with pytest.raises(InputError, match="header names 4 columns"):
        read_p2m(dst)


def test_header_and_name_disagree(tmp_path, deepmimo):
    dst = tmp_path / "insite.pl.t002_01.r001.p2m"
    shutil.copy(deepmimo / "insite.pl.t001_01.r001.p2m", dst)
    with pytest.raises(InputError, match="header says transmitter set 1 point 1, file name says set 1 point 2"):
        read_p2m(dst)


def test_header_only_is_truncated(tmp_path, deepmimo):
    dst = tmp_path / "insite.pl.t001_01.r001.p2m"
    dst.write_text("".join((deepmimo / "insite.pl.t001_01.r001.p2m").read_text().splitlines(True)[:3]))
    with pytest.raises(InputError, match="no receiver rows"):
        read_p2m(dst)


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16", "cr"])
def test_encodings_are_detected(tmp_path, deepmimo, encoding):
    """A byte-order mark (UTF-8 or UTF-16) or old Mac line ends read exactly like the plain file."""
    src = deepmimo / "insite.pl.t001_01.r004.p2m"
    text = src.read_text()
    dst = tmp_path / src.name
    if encoding == "cr":
        dst.write_bytes(text.replace("\n", "\r").encode())
    else:
        dst.write_bytes(text.encode(encoding))
    _, ref = read_p2m(src)
    meta, t = read_p2m(dst)
    assert t.equals(ref) and meta.num_rows == 81 * 57


def test_batches_stream_and_errors_still_name_their_line(tmp_path, deepmimo):
    """Small batches give the same table; a duplicate across batches, or a bad row after the fallback, names its line."""
    from uavplace.ingest.wireless_insite.p2m import P2MStream

    src = deepmimo / "insite.pl.t001_01.r004.p2m"
    _, ref = read_p2m(src)
    stream = P2MStream(src, batch_bytes=4096)
    tables = list(stream)
    assert len(tables) > 10 and pa.concat_tables(tables).equals(ref) and stream.meta.num_rows == ref.num_rows
    lines = src.read_text().splitlines()
    padded = lines[:3] + ["\t".join(line.split()) if i == 3000 else line for i, line in enumerate(lines[3:])]
    (tmp_path / src.name).write_text("\n".join(padded) + "\n")  # irregular spacing far into the file
    assert pa.concat_tables(list(P2MStream(tmp_path / src.name, batch_bytes=4096))).equals(ref)
    lines[4000] = lines[10].replace(lines[10].split()[0], lines[3].split()[0], 1)  # receiver 1 again, 2 batches on
    (tmp_path / src.name).write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r":4001: rx_index: duplicate receiver number 1 \(first at line 4\)"):
        list(P2MStream(tmp_path / src.name, batch_bytes=4096))


def test_header_titles_parse_in_linear_time():
    """A title regex that searched names lazily took 19.5 s on a 30 kB header line and never ended on 50 MB
    (issue 34): ``column_titles`` is linear, so a 5 MB line of junk takes well under a second of CPU (bound: 10 s of
    this process's CPU time, which a busy machine does not inflate as it does the wall time)."""
    import time

    from uavplace.ingest.wireless_insite.p2m_header import column_titles

    line = "# X(m) Y(m) Z(m) Distance(m) Power(dBm) Phase(deg)"
    assert column_titles(line) == [("X", "m"), ("Y", "m"), ("Z", "m"), ("Distance", "m"), ("Power", "dBm"), ("Phase", "deg")]
    for junk in ("# " + "ab " * 1_700_000 + "(m)", "(" * 5_000_000, "a(" * 2_500_000 + ")"):
        t = time.process_time()
        column_titles(junk)
        assert time.process_time() - t < 10.0

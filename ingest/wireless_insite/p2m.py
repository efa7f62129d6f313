"""Receiver outputs (.p2m, .p2m.gz) of Wireless InSite.

File name: ``<project>.<output>.t<TTT>_<SS>.r<RRR>.p2m`` (TTT the transmitter
point, SS the transmitter set's project_id, RRR the receiver set's project_id;
3 or 4 digits). Two header styles::

    #Rx                                                     <- InSite 3.2
    # X(m), Y(m), Z(m), Distance(m), PathLoss(dB)

    # <Transmitter Set: Tx: 1 BS1 - Point 1>                <- InSite 3.3 and later
    # <Receiver Set: Rx: 4 UE_grid>
    # <X(m)> <Y(m)> <Z(m)> <Distance(m)> <PathLoss(dB)>

then one row per receiver, ``rx x y z distance value...``, space separated:
``1 -100.37 -70.9989 2 162.379 250``.

The body is parsed with pyarrow's multithreaded CSV reader; only when it
fails does a line-by-line pass run, to name the line and field at fault.
"""

from __future__ import annotations

import gzip
import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from schemas import InputError, ReceiverSet
from schemas.receivers import QUANTITIES, RECEIVER_OUTPUTS, SKIPPED_OUTPUTS

#: ``model.pl.t001_01.r002.p2m`` -> project "model", output "pl", tx point 1, tx set 1, rx set 2.
FILENAME_RE = re.compile(
    r"^(?P<project>.+)\.(?P<output>[A-Za-z0-9]+)\.t(?P<tx_point>\d{3,4})_(?P<tx_set>\d{2,4})"
    r"\.r(?P<rx_set>\d{3,4})\.p2m(?:\.gz)?$"
)
#: Transmitter-only outputs, e.g. ``model.inputpower.t01.p2m``.
TX_ONLY_RE = re.compile(r"^(?P<project>.+)\.(?P<output>[A-Za-z0-9]+)\.t(?P<tx_set>\d{2,4})\.p2m(?:\.gz)?$")
#: ``# <Transmitter Set: Tx: 1 BS1 - Point 1>``
TX_HEADER_RE = re.compile(r"<Transmitter Set:\s*Tx:\s*(?P<id>\d+)\s+(?P<name>.*?)\s*-\s*Point\s+(?P<point>\d+)\s*>")
#: ``# <Receiver Set: Rx: 4 UE_grid>``
RX_HEADER_RE = re.compile(r"<Receiver Set:\s*Rx:\s*(?P<id>\d+)\s*(?P<name>.*?)\s*>")
#: One ``Name(unit)`` column title in either header style.
COLUMN_RE = re.compile(r"([A-Za-z][A-Za-z ]*?)\s*\(([^)]*)\)")
#: The position columns every receiver row starts with (after the receiver number).
POSITION_COLUMNS = ("x_m", "y_m", "z_m", "distance_m")
_NON_SPACE = re.compile(rb"\S")
#: Bytes read to find the header of an uncompressed file.
_HEADER_PROBE = 1 << 16
#: InSite's power threshold when the .setup gives none [dBm].
DEFAULT_POWER_THRESHOLD_DBM = -250.0


@dataclass(frozen=True)
class P2MName:
    project: str
    output: str
    tx_point: int | None
    tx_set: int
    rx_set: int | None

    @property
    def is_receiver_output(self) -> bool:
        return self.output in RECEIVER_OUTPUTS and self.rx_set is not None

    @property
    def skip_reason(self) -> str | None:
        if self.is_receiver_output:
            return None
        return SKIPPED_OUTPUTS.get(self.output, f"unknown InSite output type '{self.output}'")


def parse_filename(name: str) -> P2MName | None:
    """Identify a .p2m by its name; None if the name is not an InSite output name."""
    m = FILENAME_RE.match(name)
    if m:
        return P2MName(m["project"], m["output"].lower(), int(m["tx_point"]), int(m["tx_set"]), int(m["rx_set"]))
    m = TX_ONLY_RE.match(name)
    if m:
        return P2MName(m["project"], m["output"].lower(), None, int(m["tx_set"]), None)
    return None


def read_bytes(path: str | Path) -> bytes:
    path = Path(path)
    if path.name.endswith(".gz"):
        try:
            with gzip.open(path, "rb") as f:
                return f.read()
        except (OSError, EOFError) as exc:
            raise InputError(path, f"not a readable gzip file ({exc})") from None
    return path.read_bytes()


@dataclass(frozen=True)
class _Header:
    lines: list[str]
    body_offset: int
    style: str
    tx: re.Match[str] | None
    rx: re.Match[str] | None
    titles: list[tuple[str, str]] | None
    titles_line: int | None


def _split_header(raw: bytes) -> _Header:
    lines: list[str] = []
    offset = 0
    while offset < len(raw) and raw[offset : offset + 1] == b"#":
        end = raw.find(b"\n", offset)
        end = len(raw) if end < 0 else end + 1
        lines.append(raw[offset:end].decode("utf-8", "replace").strip())
        offset = end
    tx = rx = None
    titles = titles_line = None
    for i, line in enumerate(lines):
        tx = tx or TX_HEADER_RE.search(line)
        rx = rx or RX_HEADER_RE.search(line)
        found = COLUMN_RE.findall(line.replace("<", " ").replace(">", " ").replace(",", " "))
        if len(found) >= 4:
            titles, titles_line = [(n.strip(), u.strip()) for n, u in found], i + 1
    if tx or rx:
        style = "insite4"
    elif lines and lines[0].lstrip("#").strip().lower().startswith("rx"):
        style = "insite3"
    else:
        style = "none"
    return _Header(lines, offset, style, tx, rx, titles, titles_line)


def _value_columns(path: str, output: str, header: _Header) -> tuple[str, ...]:
    """The value columns after the positions, checked against the header titles when present."""
    expected = RECEIVER_OUTPUTS[output]
    if header.titles is None:
        return expected
    titles = header.titles
    if len(titles) != len(POSITION_COLUMNS) + len(expected):
        raise InputError(
            path,
            f"header names {len(titles)} columns, a '{output}' output has {len(POSITION_COLUMNS) + len(expected)} "
            f"(x y z distance {' '.join(expected)})",
            line=header.titles_line,
            field="header",
        )
    for (name, unit), column in zip(titles[len(POSITION_COLUMNS) :], expected, strict=True):
        q = QUANTITIES[column]
        key = name.lower().replace(" ", "")
        if key not in q.header_names:
            raise InputError(
                path,
                f"column '{name}' where a '{output}' output has {column}",
                line=header.titles_line,
                field=name,
            )
        if unit.lower() not in q.header_units:
            raise InputError(path, f"unit '{unit}' for {name}, expected {q.unit}", line=header.titles_line, field=name)
    return expected


def _line_of_row(raw: bytes, body_offset: int, n_header: int, row: int) -> int:
    """1-based file line of the ``row``-th (0-based) non-empty body line."""
    seen = -1
    for i, line in enumerate(raw[body_offset:].splitlines()):
        if line.strip():
            seen += 1
            if seen == row:
                return n_header + i + 1
    return n_header + row + 1


def _diagnose(path: str, raw: bytes, header: _Header, names: list[str]) -> list[list[str]]:
    """Line-by-line check of the body: raise on the first bad line, else return the rows' words."""
    rows: list[list[str]] = []
    n_header = len(header.lines)
    for i, line in enumerate(raw[header.body_offset :].decode("utf-8", "replace").splitlines()):
        words = line.split()
        if not words:
            continue
        lineno = n_header + i + 1
        if len(words) != len(names):
            missing = names[len(words)] if len(words) < len(names) else None
            raise InputError(
                path,
                f"expected {len(names)} columns (rx {' '.join(names[1:])}), found {len(words)}"
                + (" (truncated row?)" if missing else ""),
                line=lineno,
                field=missing or "row",
            )
        for word, name in zip(words, names, strict=True):
            try:
                int(word) if name == "rx_index" else float(word)
            except ValueError:
                raise InputError(path, f"'{word}' is not a number", line=lineno, field=name) from None
        rows.append(words)
    return rows


def _parse_body(path: str, raw: bytes, header: _Header, names: list[str], file: Path | None = None) -> pa.Table:
    """Parse the rows after the header: memory-mapped from ``file`` when given, else from ``raw``."""
    types = {n: (pa.int64() if n == "rx_index" else pa.float64()) for n in names}
    read = pacsv.ReadOptions(column_names=names, use_threads=True)
    parse = pacsv.ParseOptions(delimiter=" ", ignore_empty_lines=True)
    convert = pacsv.ConvertOptions(
        column_types=types, null_values=[], strings_can_be_null=False, quoted_strings_can_be_null=False
    )
    try:
        if file is not None:
            with pa.memory_map(str(file)) as mm:
                mm.seek(header.body_offset)
                return pacsv.read_csv(mm, read, parse, convert)
        return pacsv.read_csv(io.BytesIO(memoryview(raw)[header.body_offset :]), read, parse, convert)
    except pa.ArrowInvalid:
        pass
    if file is not None:
        raw = file.read_bytes()
    # Irregular spacing (tabs, padding) or a real error: find out line by line.
    words = _diagnose(path, raw, header, names)
    normalised = "\n".join(" ".join(w) for w in words).encode()
    return pacsv.read_csv(io.BytesIO(normalised), read, parse, convert)


def read_p2m(
    path: str | Path,
    *,
    display: str | None = None,
    power_threshold_dbm: float | None = None,
) -> tuple[ReceiverSet, pa.Table]:
    """Read one receiver output.

    Args:
        path: the .p2m or .p2m.gz file.
        display: the name errors and the returned metadata use for it.
        power_threshold_dbm: the receiving antenna's threshold [dBm]; received
            powers at or below it are "not reached" (default -250, InSite's).

    Returns:
        The file's ``ReceiverSet`` and a table with ``rx_index`` [N] (int32),
        ``x_m``, ``y_m``, ``z_m``, ``distance_m`` and the output's value
        columns [N] (float64, null where not reached), and ``reached`` [N]
        (bool, null if the output carries no reach information).
    """
    path = Path(path)
    name = display or str(path)
    ident = parse_filename(path.name)
    if ident is None or not ident.is_receiver_output:
        raise InputError(name, "not a receiver output name (<project>.<output>.tTTT_SS.rRRR.p2m)", field="file name")
    assert ident.tx_point is not None and ident.rx_set is not None
    gz = path.name.endswith(".gz")
    if gz:
        raw = read_bytes(path)
    else:  # the header from the file's start; the body is memory-mapped by the CSV reader
        with open(path, "rb") as f:
            raw = f.read(_HEADER_PROBE)
            if len(raw) == _HEADER_PROBE and raw.count(b"\n#") + 1 >= raw.count(b"\n"):
                raw += f.read()  # an unusually long header
    header = _split_header(raw)
    values = _value_columns(name, ident.output, header)
    if header.tx and (int(header.tx["id"]) != ident.tx_set or int(header.tx["point"]) != ident.tx_point):
        raise InputError(
            name,
            f"header says transmitter set {header.tx['id']} point {header.tx['point']}, "
            f"file name says set {ident.tx_set} point {ident.tx_point}",
            line=1,
            field="Transmitter Set",
        )
    if header.rx and int(header.rx["id"]) != ident.rx_set:
        raise InputError(name, f"header says receiver set {header.rx['id']}, file name says {ident.rx_set}", field="Receiver Set")
    names = ["rx_index", *POSITION_COLUMNS, *values]
    if _NON_SPACE.search(raw, header.body_offset) is None and (gz or path.stat().st_size <= len(raw)):
        raise InputError(name, "no receiver rows after the header (empty or truncated file)", line=len(header.lines) + 1)
    table = _parse_body(name, raw, header, names, file=None if gz else path)
    if not gz:
        raw = b""  # read again, whole, only if an error has to name its line

    def whole() -> bytes:
        return raw or path.read_bytes()

    # Checks and sentinels run on Arrow's chunked columns: no concatenation, no Python loop over rows.
    rx = table.column("rx_index").to_numpy()

    def fail(row: int, field: str, message: str) -> InputError:
        return InputError(name, message, line=_line_of_row(whole(), header.body_offset, len(header.lines), row), field=field)

    for n in names[1:]:
        col = table.column(n)
        if not pc.all(pc.is_finite(col)).as_py():
            row = int(np.argmax(~np.isfinite(col.to_numpy())))
            raise fail(row, n, f"value {col[row].as_py()} is not a finite number")
    if rx.min() < 1:
        row = int(np.argmin(rx))
        raise fail(row, "rx_index", f"receiver number {rx[row]} < 1")
    if not (np.diff(rx) > 0).all():
        order = np.argsort(rx, kind="stable")
        dup = np.flatnonzero(np.diff(rx[order]) == 0)
        if dup.size:
            first, second = sorted((int(order[dup[0]]), int(order[dup[0] + 1])))
            line1 = _line_of_row(whole(), header.body_offset, len(header.lines), first)
            raise fail(second, "rx_index", f"duplicate receiver number {rx[second]} (first at line {line1})")

    threshold = DEFAULT_POWER_THRESHOLD_DBM if power_threshold_dbm is None else power_threshold_dbm
    unreached = None
    for n in values:
        q = QUANTITIES[n]
        if q.sentinel == "ge":
            mask = pc.greater_equal(table.column(n), q.sentinel_value)
        elif q.sentinel == "le":
            mask = pc.less_equal(table.column(n), q.sentinel_value)
        elif q.sentinel == "threshold":
            mask = pc.less_equal(table.column(n), threshold)
        else:
            continue
        unreached = mask if unreached is None else pc.or_(unreached, mask)

    num_unreached = 0 if unreached is None else int(pc.sum(unreached).as_py() or 0)
    out: dict[str, pa.ChunkedArray] = {"rx_index": table.column("rx_index").cast(pa.int32())}
    for n in POSITION_COLUMNS:
        out[n] = table.column(n)
    null = pa.scalar(None, pa.float64())
    for n in values:
        out[n] = pc.if_else(unreached, null, table.column(n)) if num_unreached else table.column(n)
    out["reached"] = pc.invert(unreached) if unreached is not None else pa.chunked_array([pa.nulls(len(rx), pa.bool_())])
    meta = ReceiverSet(
        source=name,
        output=ident.output,
        project=ident.project,
        header_style=header.style,  # type: ignore[arg-type]
        tx_set_id=ident.tx_set,
        tx_point=ident.tx_point,
        tx_set_name=header.tx["name"] if header.tx else None,
        rx_set_id=ident.rx_set,
        rx_set_name=(header.rx["name"] or None) if header.rx else None,
        columns=values,
        num_rows=len(rx),
        num_reached=len(rx) - num_unreached if unreached is not None else None,
        power_threshold_dbm=threshold if "power_dbm" in values else None,
    )
    return meta, pa.table(out)

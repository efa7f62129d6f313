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

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from uavplace.infra.limits import check_limit, limits
from uavplace.schemas import InputError, ReceiverSet
from uavplace.schemas.receivers import QUANTITIES, RECEIVER_OUTPUTS, SKIPPED_OUTPUTS
from uavplace.schemas.tables import RECEIVERS, Column

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
#: The ``(unit)`` of a column title; ``column_titles`` takes the name before it.
_UNIT_RE = re.compile(r"\(([^)]*)\)")
#: A column title's name: letters and spaces, starting with a letter, right before its ``(unit)``.
_NAME_RE = re.compile(r"[A-Za-z][A-Za-z ]*$")


def column_titles(line: str) -> list[tuple[str, str]]:
    """The ``Name(unit)`` column titles of a header line, as (name, unit), in linear time (a title regex that searched
    for the name lazily took seconds on a 30 kB line and never ended on 50 MB)."""
    end = line.rfind(")")
    out = []
    start = 0
    for m in _UNIT_RE.finditer(line, 0, end + 1):  # every "(" searched has a ")" after it: no failed scans
        before = line[start : m.start()].rstrip()
        name = _NAME_RE.search(before[-256:])  # a title is short; the bound keeps the search linear
        if name is not None:
            out.append((name.group(0), m.group(1)))
        start = m.end()
    return out


#: The position columns every receiver row starts with (after the receiver number).
POSITION_COLUMNS = ("x_m", "y_m", "z_m", "distance_m")
_NON_SPACE = re.compile(rb"\S")
#: Bytes read to find the header of an uncompressed file.
_HEADER_PROBE = 1 << 16
#: The longest line of a receiver row read [bytes] (a row is a few dozen: 8 numbers).
MAX_LINE_BYTES = 1 << 16
#: InSite's power threshold when the .setup gives none [dBm].
DEFAULT_POWER_THRESHOLD_DBM = -250.0
#: Peak gain [dBi] of the InSite antenna types whose gain the type fixes (keys lower case, without spaces).
ANTENNA_GAINS_DBI = {"isotropic": 0.0, "halfwavedipole": 2.15, "shortdipole": 1.76, "linearwiredipole": 2.15}
#: Gain [dBi] assumed for a declared antenna of another type (a horn, an array, a dish): a large dish's.
UNKNOWN_ANTENNA_GAIN_DBI = 30.0
#: Gain [dBi] of an antenna the export does not declare: a half-wave dipole, InSite's default.
UNDECLARED_ANTENNA_GAIN_DBI = 2.15
#: A received power may exceed the transmitted power plus both antennas' gains by at most this [dB]. In the far field
#: every path loses power (a path gain above 0 dB is not physical); only paths adding in phase can raise the sum,
#: and two equal paths in phase double the amplitude: +6 dB.
COHERENT_MARGIN_DB = 6.0


def antenna_gain_dbi(antenna_type: str | None) -> float:
    """Peak gain [dBi] bounding an antenna of this InSite ``type`` (None: not declared): ``ANTENNA_GAINS_DBI``,
    else ``UNKNOWN_ANTENNA_GAIN_DBI``, or ``UNDECLARED_ANTENNA_GAIN_DBI`` without a declaration."""
    if antenna_type is None:
        return UNDECLARED_ANTENNA_GAIN_DBI
    return ANTENNA_GAINS_DBI.get(antenna_type.replace(" ", "").replace("_", "").lower(), UNKNOWN_ANTENNA_GAIN_DBI)


#: Text read per batch by the streaming reader (a row is about 45 bytes: some 45 k rows a batch). Measured on a
#: 5 M-row ingest: 16 MiB peaked 150 MB higher, 1 MiB and below ran 10-20 % slower.
BATCH_BYTES = 2 << 20
#: Rows checked at a time after the line-by-line fallback.
_FALLBACK_ROWS = 250_000
#: A number as every reader parses it (no ``_`` separators), or nan/inf (refused later as not finite).
_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?(?:nan|inf|infinity)", re.IGNORECASE)
_INTEGER = re.compile(rb"\+?\d+")
#: Longest number word accepted [characters] (a float has at most 17 significant digits).
_MAX_WORD = 40
_NUL = b"\0"
_UTF8_BOM = b"\xef\xbb\xbf"
_UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")


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
        found = column_titles(line.replace("<", " ").replace(">", " ").replace(",", " "))
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


def _diagnose(path: str, raw: bytes, header: _Header, names: list[str]) -> bytes:
    """Line-by-line check of the body: raise on the first bad line, else return the rows single-space separated.

    Numbers must look like numbers to any reader (``-7_0.5`` does to Python, not to Arrow), and be short.
    """
    rows: list[bytes] = []
    n_header = len(header.lines)
    for i, line in enumerate(raw[header.body_offset :].splitlines()):
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
            pattern = _INTEGER if name == "rx_index" else _NUMBER
            if len(word) > _MAX_WORD or pattern.fullmatch(word) is None:
                shown = word[:_MAX_WORD].decode("utf-8", "replace") + ("..." if len(word) > _MAX_WORD else "")
                what = "a receiver number" if name == "rx_index" else "a number"
                raise InputError(path, f"'{shown}' is not {what}", line=lineno, field=name)
        rows.append(b" ".join(words))
    return b"\n".join(rows) + b"\n"


def _text_conversion(probe: bytes) -> str | None:
    """What a body must be converted from before Arrow reads it: None (ASCII/UTF-8, LF or CRLF), or
    ``utf-8-sig`` (a byte-order mark), ``utf-16`` (with its byte-order mark) or ``cr`` (old Mac line ends)."""
    if probe.startswith(_UTF8_BOM):
        return "utf-8-sig"
    if probe[:2] in _UTF16_BOMS:
        return "utf-16"
    if b"\r" in probe and b"\n" not in probe:
        return "cr"
    return None


def _converted(path: str, raw: bytes, conversion: str) -> bytes:
    if conversion == "utf-16":
        try:
            raw = raw.decode("utf-16").encode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputError(path, f"starts with a UTF-16 byte-order mark but is not UTF-16 text ({exc.reason})") from None
    elif conversion == "utf-8-sig":
        raw = raw[len(_UTF8_BOM) :]
    return raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")


class P2MStream:
    """One receiver output, read in batches of about ``batch_bytes`` of text (memory stays flat).

    Iterating yields validated ``pa.Table`` batches with ``rx_index`` (int32),
    ``x_m``, ``y_m``, ``z_m``, ``distance_m``, the output's value columns
    (float64, null where not reached) and ``reached`` (bool, null if the output
    carries no reach information). ``meta`` is the file's ``ReceiverSet`` once
    every batch has been read. Any bad row raises ``InputError`` naming the
    file's line and column; the caller discards what it got so far.

    Args:
        path: the .p2m or .p2m.gz file.
        display: the name errors and the metadata use for it.
        power_threshold_dbm: the receiving antenna's threshold [dBm]; received
            powers at or below it are "not reached" (default -250, InSite's).
        max_gain_db: the most a received power may exceed the transmitted
            one [dB]: both antennas' gains and ``COHERENT_MARGIN_DB``.
        tx_power_dbm: the transmitter's power [dBm], when known.
        batch_bytes: text read per batch.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        display: str | None = None,
        power_threshold_dbm: float | None = None,
        max_gain_db: float | None = None,
        tx_power_dbm: float | None = None,
        batch_bytes: int = BATCH_BYTES,
    ) -> None:
        self.path = Path(path)
        self.name = display or str(path)
        ident = parse_filename(self.path.name)
        if ident is None or not ident.is_receiver_output:
            raise InputError(self.name, "not a receiver output name (<project>.<output>.tTTT_SS.rRRR.p2m)", field="file name")
        assert ident.tx_point is not None and ident.rx_set is not None
        self.ident = ident
        self.gz = self.path.name.endswith(".gz")
        self.batch_bytes = batch_bytes
        self.threshold = DEFAULT_POWER_THRESHOLD_DBM if power_threshold_dbm is None else power_threshold_dbm
        self.max_gain_db, self.tx_power_dbm = max_gain_db, tx_power_dbm
        self._raw: bytes | None = None  # the whole (converted) file, when it had to be read whole
        probe = self._read(_HEADER_PROBE)
        conversion = _text_conversion(probe)
        if _NUL in probe and conversion != "utf-16":
            raise InputError(
                self.name,
                f"holds NUL bytes (first at byte {probe.index(_NUL)}): binary data, or UTF-16 text without a "
                "byte-order mark; a .p2m is ASCII text",
            )
        if conversion is not None:
            self._raw = _converted(self.name, self._read(None), conversion)
            probe = self._raw
        elif len(probe) == _HEADER_PROBE and probe.count(b"\n#") + 1 >= probe.count(b"\n"):
            self._raw = self._read(None)  # an unusually long header
            probe = self._raw
        self.conversion = conversion
        header = _split_header(probe)
        self.header = header
        values = _value_columns(self.name, ident.output, header)
        if header.tx and (int(header.tx["id"]) != ident.tx_set or int(header.tx["point"]) != ident.tx_point):
            raise InputError(
                self.name,
                f"header says transmitter set {header.tx['id']} point {header.tx['point']}, "
                f"file name says set {ident.tx_set} point {ident.tx_point}",
                line=1,
                field="Transmitter Set",
            )
        if header.rx and int(header.rx["id"]) != ident.rx_set:
            raise InputError(
                self.name, f"header says receiver set {header.rx['id']}, file name says {ident.rx_set}", field="Receiver Set"
            )
        self.values = values
        self.names = ["rx_index", *POSITION_COLUMNS, *values]
        whole = self._raw is not None or len(probe) < _HEADER_PROBE
        if whole and _NON_SPACE.search(probe, header.body_offset) is None:
            raise InputError(self.name, "no receiver rows after the header (empty or truncated file)", line=len(header.lines) + 1)
        self._rows = 0
        self._reached = 0
        self._has_reach = any(QUANTITIES[n].sentinel != "none" for n in values)
        self._rx_parts: list[np.ndarray] = []
        self._finished = False

    # -- bytes ------------------------------------------------------------------------------------
    def _stream(self) -> pa.NativeFile:
        return pa.input_stream(str(self.path), compression="gzip" if self.gz else None)

    def _read(self, size: int | None) -> bytes:
        """``size`` bytes of the (decompressed) file, or all of it within the limit ``export_bytes``."""
        limit = limits().export_bytes
        try:
            with self._stream() as f:
                data = f.read(limit + 1) if size is None else f.read(size)
        except OSError as exc:
            raise InputError(self.name, f"not a readable gzip file ({exc})" if self.gz else f"unreadable ({exc})") from None
        if size is None:
            check_limit("export_bytes", len(data), self.name, "size of the (decompressed) text [bytes]")
        return data

    def _whole(self) -> bytes:
        """The whole (converted) file: read only when an error has to name its line."""
        if self._raw is None:
            self._raw = self._read(None)
        return self._raw

    def _body(self) -> pa.NativeFile:
        if self._raw is not None:
            buf = pa.BufferReader(self._raw)
        else:
            buf = self._stream()
        buf.read(self.header.body_offset)
        return buf

    # -- rows -------------------------------------------------------------------------------------
    def _options(self) -> tuple[pacsv.ReadOptions, pacsv.ParseOptions, pacsv.ConvertOptions]:
        types = {n: (pa.int64() if n == "rx_index" else pa.float64()) for n in self.names}
        read = pacsv.ReadOptions(
            column_names=self.names, use_threads=False
        )  # per-batch threads cost memory (thread heaps) and gained no speed
        parse = pacsv.ParseOptions(delimiter=" ", ignore_empty_lines=True)
        convert = pacsv.ConvertOptions(
            column_types=types, null_values=[], strings_can_be_null=False, quoted_strings_can_be_null=False
        )
        return read, parse, convert

    def _fail(self, row: int, field: str, message: str) -> InputError:
        line = _line_of_row(self._whole(), self.header.body_offset, len(self.header.lines), row)
        return InputError(self.name, message, line=line, field=field)

    def _blocks(self) -> Iterator[bytes]:
        """The body in blocks of about ``batch_bytes``, each ending at a line end (no read-ahead: memory stays flat);
        ``InputError`` on a line longer than ``MAX_LINE_BYTES`` or a text past the limit ``export_bytes`` (a
        decompression bomb is stopped there, not held in memory)."""
        body = self._body()
        rest = b""
        read, lines = self.header.body_offset, len(self.header.lines)
        while data := body.read(self.batch_bytes):
            read += len(data)
            check_limit("export_bytes", read, self.name, "size of the (decompressed) text [bytes]")
            data = rest + data
            cut = data.rfind(b"\n") + 1
            rest = data[cut:]
            lines += data.count(b"\n", 0, cut)
            if len(rest) > MAX_LINE_BYTES:
                raise InputError(
                    self.name, f"a line of more than {MAX_LINE_BYTES:,} bytes (a receiver row is a few dozen)", line=lines + 1
                )
            if cut and data[:cut].strip():
                yield data[:cut]
        if rest.strip():
            yield rest

    def __iter__(self) -> Iterator[pa.Table]:
        if self._finished:
            raise RuntimeError(f"{self.name}: a P2MStream is read once")
        done = 0
        try:
            for block in self._blocks():
                table = pacsv.read_csv(pa.BufferReader(block), *self._options())
                yield self._checked(table, done)
                done += table.num_rows
        except pa.ArrowInvalid:
            # Irregular spacing (tabs, padding) or a real error: find out line by line, then go on from row `done`.
            normalised = _diagnose(self.name, self._whole(), self.header, self.names)
            try:
                table = pacsv.read_csv(pa.BufferReader(normalised), *self._options()).slice(done)
            except pa.ArrowInvalid as exc:
                raise InputError(self.name, f"unreadable rows ({exc})") from None
            for start in range(0, table.num_rows, _FALLBACK_ROWS):
                part = table.slice(start, _FALLBACK_ROWS)
                yield self._checked(part, done)
                done += part.num_rows
        except OSError as exc:
            raise InputError(self.name, f"not a readable gzip file ({exc})" if self.gz else f"unreadable ({exc})") from None
        self._finish()

    def _checked(self, table: pa.Table, row0: int) -> pa.Table:
        """Validate one batch (rows ``row0``...) and turn it into the output columns."""
        rx = table.column("rx_index").to_numpy()
        cols = {n: table.column(n).to_numpy() for n in self.names[1:]}
        for n, v in cols.items():
            if not np.isfinite(v).all():
                row = int(np.argmax(~np.isfinite(v)))
                raise self._fail(row0 + row, n, f"value {v[row]} is not a finite number")
        if rx.min() < 1:
            row = int(np.argmin(rx))
            raise self._fail(row0 + row, "rx_index", f"receiver number {rx[row]} < 1")
        if rx.max() > np.iinfo(np.int32).max:
            row = int(np.argmax(rx))
            raise self._fail(row0 + row, "rx_index", f"receiver number {rx[row]} is too large")
        self._check_unique(rx, row0)  # within the batch now; across batches at the end
        self._rx_parts.append(rx.astype(np.int32))

        unreached = np.zeros(len(rx), bool)
        for n in self.values:
            q = QUANTITIES[n]
            if q.sentinel == "ge":
                unreached |= cols[n] >= q.sentinel_value
            elif q.sentinel == "le":
                unreached |= cols[n] <= q.sentinel_value
            elif q.sentinel == "threshold":
                unreached |= cols[n] <= self.threshold
        for n in POSITION_COLUMNS:
            self._check_range(RECEIVERS.column(n), cols[n], None, row0)
        for n in self.values:
            self._check_range(RECEIVERS.column(n), cols[n], ~unreached, row0)
        if self.max_gain_db is not None and self.tx_power_dbm is not None:
            self._check_gain(cols, unreached, row0)

        self._rows += len(rx)
        self._reached += int((~unreached).sum())
        out: dict[str, pa.Array] = {"rx_index": pa.array(rx.astype(np.int32))}
        for n in POSITION_COLUMNS:
            out[n] = pa.array(cols[n])
        for n in self.values:
            out[n] = pa.array(cols[n], mask=unreached) if unreached.any() else pa.array(cols[n])
        out["reached"] = pa.array(~unreached) if self._has_reach else pa.nulls(len(rx), pa.bool_())
        return pa.table(out)

    def _check_gain(self, cols: dict[str, np.ndarray], unreached: np.ndarray, row0: int) -> None:
        """(Called with ``tx_power_dbm`` and ``max_gain_db`` known.) Refuse a reached row whose received power exceeds the transmit power by more than both antennas and paths
        in phase can (``max_gain_db``): in the far field every path loses power, so a dropped sign is caught here.
        (Path gain and path loss are bounded by their columns' ranges: at most 0 dB gained.)"""
        if "power_dbm" not in cols:
            return
        limit = self.tx_power_dbm + self.max_gain_db
        over = ~unreached & (cols["power_dbm"] > limit)
        if over.any():
            row = int(np.argmax(over))
            raise self._fail(
                row0 + row,
                "power_dbm",
                f"received power {cols['power_dbm'][row]:g} dBm is beyond {limit:g} dBm, the transmit power and both "
                f"antennas' gains with {COHERENT_MARGIN_DB:g} dB for paths in phase: not physical in the far field",
            )

    def _check_range(self, column: Column, values: np.ndarray, valid: np.ndarray | None, row0: int) -> None:
        row = column.first_out_of_range(values, valid)
        if row is not None:
            raise self._fail(row0 + row, column.name, f"{values[row]:g} is outside the physical range {column.range_text()}")

    def _finish(self) -> None:
        """After the last batch: the file's receiver numbers must be unique."""
        self._finished = True
        rx = np.concatenate(self._rx_parts) if self._rx_parts else np.zeros(0, np.int32)
        self._rx_parts = []
        if len(rx) == 0:
            raise InputError(
                self.name, "no receiver rows after the header (empty or truncated file)", line=len(self.header.lines) + 1
            )
        self._check_unique(rx, 0)

    def _check_unique(self, rx: np.ndarray, row0: int) -> None:
        """Receiver numbers ``rx`` (rows ``row0``...) hold no duplicate."""
        if (np.diff(rx) > 0).all():
            return
        order = np.argsort(rx, kind="stable")
        dup = np.flatnonzero(np.diff(rx[order]) == 0)
        if dup.size:
            first, second = sorted((int(order[dup[0]]), int(order[dup[0] + 1])))
            line1 = _line_of_row(self._whole(), self.header.body_offset, len(self.header.lines), row0 + first)
            raise self._fail(row0 + second, "rx_index", f"duplicate receiver number {rx[second]} (first at line {line1})")

    @property
    def meta(self) -> ReceiverSet:
        """What the file held; available once every batch has been read."""
        if not self._finished:
            raise RuntimeError(f"{self.name}: read every batch before asking for its metadata")
        header, ident = self.header, self.ident
        return ReceiverSet(
            source=self.name,
            output=ident.output,
            project=ident.project,
            header_style=header.style,  # type: ignore[arg-type]
            tx_set_id=ident.tx_set,
            tx_point=ident.tx_point,  # type: ignore[arg-type]
            tx_set_name=header.tx["name"] if header.tx else None,
            rx_set_id=ident.rx_set,  # type: ignore[arg-type]
            rx_set_name=(header.rx["name"] or None) if header.rx else None,
            columns=self.values,
            num_rows=self._rows,
            num_reached=self._reached if self._has_reach else None,
            power_threshold_dbm=self.threshold if "power_dbm" in self.values else None,
        )


def read_p2m(
    path: str | Path,
    *,
    display: str | None = None,
    power_threshold_dbm: float | None = None,
    max_gain_db: float | None = None,
    tx_power_dbm: float | None = None,
) -> tuple[ReceiverSet, pa.Table]:
    """Read one receiver output whole: its ``ReceiverSet`` and one table of the columns ``P2MStream`` yields."""
    stream = P2MStream(
        path, display=display, power_threshold_dbm=power_threshold_dbm, max_gain_db=max_gain_db, tx_power_dbm=tx_power_dbm
    )
    tables = list(stream)
    return stream.meta, pa.concat_tables(tables)

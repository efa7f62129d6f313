"""A receiver output's name and header (``ingest.wireless_insite.p2m``): the file name's project, output, transmitter
and receiver sets (``parse_filename``), the two header styles and their column titles, the antenna gains the
outputs are corrected by, and what a failed body parse is diagnosed with (the line and field at fault)."""

from __future__ import annotations

import re
from dataclasses import dataclass

from uavplace.schemas import InputError
from uavplace.schemas.receivers import QUANTITIES, RECEIVER_OUTPUTS, SKIPPED_OUTPUTS

#: A number as every reader parses it (no ``_`` separators), or nan/inf (refused later as not finite).
_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?(?:nan|inf|infinity)", re.IGNORECASE)
_INTEGER = re.compile(rb"\+?\d+")
#: Longest number word accepted [characters] (a float has at most 17 significant digits).
_MAX_WORD = 40
NUL = b"\0"
_UTF8_BOM = b"\xef\xbb\xbf"
_UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")

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
NON_SPACE = re.compile(rb"\S")
#: Bytes read to find the header of an uncompressed file.
HEADER_PROBE = 1 << 16
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
class Header:
    lines: list[str]
    body_offset: int
    style: str
    tx: re.Match[str] | None
    rx: re.Match[str] | None
    titles: list[tuple[str, str]] | None
    titles_line: int | None


def split_header(raw: bytes) -> Header:
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
    return Header(lines, offset, style, tx, rx, titles, titles_line)


def value_columns(path: str, output: str, header: Header) -> tuple[str, ...]:
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


def line_of_row(raw: bytes, body_offset: int, n_header: int, row: int) -> int:
    """1-based file line of the ``row``-th (0-based) non-empty body line."""
    seen = -1
    for i, line in enumerate(raw[body_offset:].splitlines()):
        if line.strip():
            seen += 1
            if seen == row:
                return n_header + i + 1
    return n_header + row + 1


def diagnose(path: str, raw: bytes, header: Header, names: list[str]) -> bytes:
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


def text_conversion(probe: bytes) -> str | None:
    """What a body must be converted from before Arrow reads it: None (ASCII/UTF-8, LF or CRLF), or
    ``utf-8-sig`` (a byte-order mark), ``utf-16`` (with its byte-order mark) or ``cr`` (old Mac line ends)."""
    if probe.startswith(_UTF8_BOM):
        return "utf-8-sig"
    if probe[:2] in _UTF16_BOMS:
        return "utf-16"
    if b"\r" in probe and b"\n" not in probe:
        return "cr"
    return None


def converted(path: str, raw: bytes, conversion: str) -> bytes:
    if conversion == "utf-16":
        try:
            raw = raw.decode("utf-16").encode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputError(path, f"starts with a UTF-16 byte-order mark but is not UTF-16 text ({exc.reason})") from None
    elif conversion == "utf-8-sig":
        raw = raw[len(_UTF8_BOM) :]
    return raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")

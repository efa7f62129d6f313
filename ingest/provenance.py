"""``<city>.provenance.csv.gz``: where each receiver's value came from (``schemas.provenance``), beside an export.

The side file ``uavdata simulate`` writes: comment lines (``#``), the header ``PROVENANCE_COLUMNS``, then rows of the
codes of consecutive receivers of one transmitter and receiver set, a digit each (or, in a file of an earlier version,
``RUN_COLUMNS``: runs of receivers that share a code). Refused, with the file, line and field, unless every field is
an integer (the codes a string of digits), every code a receiver's code, and the rows of each transmitter and receiver
set follow each other from receiver 1 with no gap or overlap. ``ingest_city`` then checks that the rows cover exactly
the receivers of the .p2m files and that a receiver is "unreached" exactly where its file says no path reached it.
Without the side file, ``default_code`` says what an export's reached receivers are.
"""

from __future__ import annotations

import csv
import gzip
import hashlib
import io
import json
import zlib
from pathlib import Path

import numpy as np

from uavplace.infra.limits import check_limit
from uavplace.ingest.routes import csv_rows
from uavplace.schemas import InputError
from uavplace.schemas.provenance import (
    CODES_PER_ROW,
    EXACT_PATHS,
    NOT_RECORDED,
    PROVENANCE_COLUMNS,
    RAY_TRACED,
    RECEIVER_CODES,
    RUN_COLUMNS,
    code_name,
)

#: The longest line a side file may hold [characters]: four integers and ``CODES_PER_ROW`` digits, or a run's six
#: integers.
MAX_LINE = 4096
#: Bytes of text a side file may hold per receiver it describes, and for its comments.
BYTES_PER_RECEIVER, COMMENT_BYTES = 64, 1 << 16


def _lines(path: Path, source: str, max_bytes: float):
    """The decompressed text's lines, streamed (a small archive cannot expand into gigabytes in memory): refused
    past ``max_bytes`` in all (and the limit ``export_bytes``), or at a line longer than ``MAX_LINE``."""
    size = 0
    try:
        with gzip.open(path, "rb") if path.name.lower().endswith(".gz") else path.open("rb") as raw:
            text = io.TextIOWrapper(raw, encoding="utf-8-sig", newline="")
            while line := text.readline(MAX_LINE + 1):
                if len(line) > MAX_LINE:
                    raise InputError(source, f"a line longer than {MAX_LINE} characters: not a provenance side file", field="row")
                size += len(line)
                if size > max_bytes:
                    raise InputError(
                        source,
                        f"over {max_bytes:,.0f} characters of text: more than the codes of the export's receivers take",
                        field="row",
                    )
                check_limit("export_bytes", size, source, "size of the (decompressed) text [bytes]")
                yield line
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(source, f"not a readable gzip file ({type(exc).__name__}: {str(exc)[:120]})") from None
    except UnicodeDecodeError as exc:
        raise InputError(source, f"not UTF-8 text ({exc.reason} at byte {exc.start})", field="encoding") from None


#: The side file's comment line that ties it to its export: the sha256 of the export's .p2m files (``export_digest``).
EXPORT_LINE = "# export sha256: "


def export_digest(p2m_files: list[Path]) -> str:
    """The sha256 of an export's receiver outputs: each ``.p2m`` (or ``.p2m.gz``) file's name and text (a gzip's
    decompressed: its header's time stamp says nothing of the receivers), in name order. What a side file records of
    the export it describes."""
    digest = hashlib.sha256()
    for path in sorted(p2m_files, key=lambda p: p.name):
        digest.update(path.name.encode() + b"\0")
        with gzip.open(path, "rb") if path.name.lower().endswith(".gz") else path.open("rb") as f:
            while chunk := f.read(1 << 20):
                digest.update(chunk)
    return digest.hexdigest()


def preamble(path: Path, source: str) -> tuple[list[str], tuple[str, ...] | None]:
    """A side file's comment lines before its header, and the header's columns (``PROVENANCE_COLUMNS``, an earlier
    version's ``RUN_COLUMNS``, or whatever else it holds; None when there is none), read within ``COMMENT_BYTES``."""
    comments = []
    for line in _lines(path, source, COMMENT_BYTES):
        if not line.startswith("#"):
            return comments, tuple(c.strip() for c in line.strip().split(","))
        comments.append(line)
    return comments, None


def recorded_export(path: Path, source: str) -> str | None:
    """The export sha256 a side file records (its ``EXPORT_LINE`` among the comments before the header), or None."""
    comments, _ = preamble(path, source)
    return next((line[len(EXPORT_LINE) :].strip() for line in comments if line.startswith(EXPORT_LINE)), None)


def read_provenance(path: Path, source: str, receivers: int | None = None) -> dict[tuple[int, int, int], np.ndarray]:
    """The codes of a side file: ``{(tx_set, tx_point, rx_set): codes [N] of receivers 1..N}`` (uint8); ``InputError``
    naming the file, line and field of the first problem. Its rows are the codes of consecutive receivers, a digit
    each (``PROVENANCE_COLUMNS``), or, in a file of an earlier version, runs of receivers that share a code
    (``RUN_COLUMNS``): the header says which. ``receivers``: how many the export holds (its receiver sets times its
    transmitters, when known): the text may hold ``BYTES_PER_RECEIVER`` for each and ``COMMENT_BYTES`` more, and is
    read as a stream."""
    bound = float("inf") if receivers is None else BYTES_PER_RECEIVER * receivers + COMMENT_BYTES
    reader = csv.reader(_lines(path, source, bound))
    parts: dict[tuple[int, int, int], list[np.ndarray]] = {}
    ends: dict[tuple[int, int, int], int] = {}
    columns: tuple[str, ...] | None = None
    total = 0
    for row in csv_rows(reader, source):
        line = reader.line_num
        if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
            continue
        if columns is None:
            columns = tuple(c.strip() for c in row)
            if columns not in (PROVENANCE_COLUMNS, RUN_COLUMNS):
                raise InputError(source, f"header {row}: expected {', '.join(PROVENANCE_COLUMNS)}", line=line, field="header")
            continue
        if len(row) != len(columns):
            raise InputError(source, f"{len(row)} fields, expected {len(columns)}", line=line, field="row")
        values = dict(zip(columns, row, strict=True))
        for name in (c for c in columns if c != "codes"):
            try:
                values[name] = int(values[name])
            except ValueError:
                raise InputError(source, f"{values[name]!r} is not an integer", line=line, field=name) from None
            least = 0 if name.endswith("_set") else 1
            if name != "code" and values[name] < least:
                kind = "set id" if name.endswith("_set") else "count"
                raise InputError(source, f"{values[name]} is not a {kind} (at least {least})", line=line, field=name)
        if "code" in values and values["code"] not in RECEIVER_CODES:
            raise InputError(source, _not_a_code(values["code"]), line=line, field="code")
        codes = _digits(values["codes"], values["first_rx"], source, line) if "codes" in values else None
        count = len(codes) if codes is not None else values["count"]
        key = (values["tx_set"], values["tx_point"], values["rx_set"])
        expected = ends.get(key, 0) + 1
        if values["first_rx"] != expected:
            raise InputError(
                source,
                f"row starts at receiver {values['first_rx']}; the rows of transmitter {key[1]} of set "
                f"{key[0]} and receiver set {key[2]} reach {expected - 1}: they must follow each other from "
                "1, with no gap or overlap",
                line=line,
                field="first_rx",
            )
        total += count
        field = "codes" if codes is not None else "count"
        check_limit("export_bytes", total, source, "receivers the rows describe", line=line, field=field)
        if receivers is not None and count > receivers:  # refused before a code of it is made
            raise InputError(
                source, f"a row of {count:,} receivers, more than the export holds ({receivers:,})", line=line, field=field
            )
        # a run's codes are made only within the limit: a count of 10**12 is refused above, never allocated
        parts.setdefault(key, []).append(codes if codes is not None else np.full(count, values["code"], np.uint8))
        ends[key] = values["first_rx"] + count - 1
    if columns is None:
        raise InputError(source, f"no header line ({', '.join(PROVENANCE_COLUMNS)})", field="header")
    return {key: np.concatenate(p) for key, p in parts.items()}


def _not_a_code(code: int) -> str:
    return f"{code} is not a receiver's code (" + ", ".join(f"{c} {code_name(c)}" for c in RECEIVER_CODES) + ")"


def _digits(field: str, first_rx: int, source: str, line: int) -> np.ndarray:
    """The codes of a row's ``codes`` field, uint8, one a digit: ``InputError`` naming the first receiver that is
    not a code."""
    text = field.strip()
    if not text:
        raise InputError(source, "no code: a row holds the codes of one receiver or more", line=line, field="codes")
    if len(text) > CODES_PER_ROW:
        raise InputError(source, f"{len(text)} codes, more than a row holds ({CODES_PER_ROW})", line=line, field="codes")
    codes = np.frombuffer(text.encode("ascii", "replace"), np.uint8) - np.uint8(ord("0"))
    bad = np.flatnonzero(~np.isin(codes, RECEIVER_CODES))
    if len(bad):
        i = int(bad[0])
        what = _not_a_code(int(codes[i])) if text[i].isdigit() else f"{text[i]!r} is not a code (a digit)"
        raise InputError(source, f"receiver {first_rx + i}: {what}", line=line, field="codes")
    return codes


def default_code(provenance_json: Path | None, source: str | None = None) -> int:
    """The code of a reached receiver of an export without a side file: ``ray-traced`` for a ray tracer's export (no
    simulation.json), ``exact paths`` when its simulation.json says ``uavdata simulate --solver paths``, ``not recorded``
    for an earlier ``uavdata simulate`` export, which filled gaps without saying which."""
    if provenance_json is None:
        return RAY_TRACED
    check_limit("record_bytes", provenance_json.stat().st_size, source or provenance_json, "size [bytes]")
    try:
        record = json.loads(provenance_json.read_text(encoding="utf-8"))
        solver = (record.get("raytrace") or {}).get("solver", "radio-map") if isinstance(record, dict) else None
    except (ValueError, OSError, AttributeError):
        solver = None
    return EXACT_PATHS if solver == "paths" else NOT_RECORDED


__all__ = ["default_code", "read_provenance"]

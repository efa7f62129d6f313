"""The keyword format shared by InSite's .city, .ter, .txrx and .setup files.

A file is nested blocks::

    begin_<structure> small building #2      <- kind "structure", name "small building #2"
    begin_<face> 1
    Material 6                               <- entry: key "Material", value "6"
    nVertices 4
    602.3186950684 650.5581359863 11.0000000000
    ...
    end_<face>
    end_<structure>

``parse_keyword_file`` turns it into a tree of ``Block`` with every entry's
line number kept, so later errors can name the line.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uavplace.infra.files import regular_file_bytes
from uavplace.schemas import InputError
from uavplace.schemas.tables import XY_RANGE_M, Z_RANGE_M, Column

_BEGIN = re.compile(r"^begin_<([^>]*)>\s*(.*)$")
_END = re.compile(r"^end_<([^>]*)>\s*$")
#: Entry giving a vertex count, e.g. ``nVertices 4``.
N_VERTICES = "nVertices"


@dataclass
class Block:
    kind: str
    name: str
    line: int
    path: str
    entries: list[tuple[int, str]] = field(default_factory=list)
    children: list[Block] = field(default_factory=list)

    def blocks(self, kind: str) -> list[Block]:
        """Direct children of this kind."""
        return [c for c in self.children if c.kind == kind]

    def walk(self, kind: str) -> Iterator[Block]:
        """All descendants of this kind, depth first, in file order."""
        for c in self.children:
            if c.kind == kind:
                yield c
            yield from c.walk(kind)

    def find_entry(self, key: str) -> tuple[int, str] | None:
        """First entry whose first word is ``key``: (line, rest of the line)."""
        for lineno, text in self.entries:
            head, _, rest = text.partition(" ")
            if head == key:
                return lineno, rest.strip()
        return None

    def value(self, key: str) -> str | None:
        found = self.find_entry(key)
        return None if found is None else found[1]

    def number(self, key: str, cast: type = float, column: Column | None = None) -> float | int | None:
        """The first word of entry ``key`` as a number (None if absent).

        A float must be finite; with ``column``, it must also lie in that table
        column's physical range. Anything else is an ``InputError`` at the entry's line.
        """
        found = self.find_entry(key)
        if found is None:
            return None
        lineno, text = found
        word = text.split()[0] if text.split() else ""
        try:
            value = cast(word)
        except (ValueError, OverflowError):
            raise InputError(self.path, f"'{word[:40]}' is not a number", line=lineno, field=key) from None
        if cast is float and not math.isfinite(value):
            raise InputError(self.path, f"{word} is not a finite number", line=lineno, field=key)
        if column is not None and column.first_out_of_range(np.array([value])) is not None:
            raise InputError(self.path, f"{word} is outside the physical range {column.range_text()}", line=lineno, field=key)
        return value

    def has_word(self, word: str) -> bool:
        """True if an entry is exactly ``word`` (flags such as ``active``)."""
        return any(text == word for _, text in self.entries)

    def yes(self, key: str) -> bool | None:
        v = self.value(key)
        return None if v is None else v.split()[0].lower() in ("yes", "true", "1")

    def where(self) -> str:
        return f"{self.path}:{self.line}"

    def vertices(self) -> np.ndarray:
        """The ``nVertices K`` entry and the K ``x y z`` lines after it, as a [K, 3] float array [m]."""
        for i, (lineno, text) in enumerate(self.entries):
            head, _, rest = text.partition(" ")
            if head != N_VERTICES:
                continue
            try:
                k = int(rest.strip())
            except ValueError:
                raise InputError(self.path, f"'{rest.strip()}' is not a count", line=lineno, field=N_VERTICES) from None
            if k < 1:
                raise InputError(self.path, f"{N_VERTICES} {k}: a count of at least 1", line=lineno, field=N_VERTICES)
            lines = self.entries[i + 1 : i + 1 + k]
            if len(lines) < k:
                raise InputError(
                    self.path,
                    f"{N_VERTICES} {k} but only {len(lines)} vertex lines follow",
                    line=lineno,
                    field=N_VERTICES,
                )
            out = np.empty((k, 3))
            for j, (vline, vtext) in enumerate(lines):
                words = vtext.split()
                if len(words) != 3:
                    raise InputError(self.path, f"vertex needs 3 numbers (x y z), found {len(words)}", line=vline, field="vertex")
                try:
                    out[j] = [float(w) for w in words]
                except ValueError:
                    raise InputError(self.path, f"vertex '{vtext}' holds text, not numbers", line=vline, field="vertex") from None
            for j, (lo, hi) in enumerate((XY_RANGE_M, XY_RANGE_M, Z_RANGE_M)):
                bad = ~np.isfinite(out[:, j]) | (out[:, j] < lo) | (out[:, j] > hi)
                if bad.any():
                    k = int(np.argmax(bad))
                    raise InputError(
                        self.path,
                        f"vertex coordinate {out[k, j]:g} is not finite or outside [{lo:g}, {hi:g}] m",
                        line=lines[k][0],
                        field="xyz"[j],
                    )
            return out
        raise InputError(self.path, f"{self.kind} block has no {N_VERTICES} entry", line=self.line, field=N_VERTICES)


def read_text(path: str | Path, display: str | None = None) -> str:
    """A text file's content: UTF-8 (with or without a byte-order mark), UTF-16 with its byte-order mark,
    or (as a fallback) Latin-1; LF, CRLF or CR line ends are all split by ``str.splitlines``.

    Binary data (NUL bytes outside UTF-16) is an ``InputError``.
    """
    raw = regular_file_bytes(Path(path), str(display or path), "text_bytes")
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        try:
            return raw.decode("utf-16")
        except UnicodeDecodeError as exc:
            raise InputError(display or path, f"starts with a UTF-16 byte-order mark but is not UTF-16 ({exc.reason})") from None
    if b"\0" in raw:
        raise InputError(
            display or path,
            f"holds NUL bytes (first at byte {raw.index(0)}): binary data, or UTF-16 without a byte-order mark; "
            "InSite writes text",
        )
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def parse_keyword_file(path: str | Path, display: str | None = None) -> Block:
    """Parse a keyword file into a root ``Block`` (kind ``""``) holding the top-level blocks.

    ``display`` is the name errors use for the file (default: the path).
    Raises ``InputError`` on an ``end_`` that does not match its ``begin_`` or
    on a block left open at the end of the file.
    """
    name = display or str(path)
    root = Block(kind="", name="", line=0, path=name)
    stack = [root]
    for lineno, raw_line in enumerate(read_text(path, name).splitlines(), start=1):
        text = raw_line.strip()
        if not text:
            continue
        if text.startswith("begin_<"):
            m = _BEGIN.match(text)
            if m is None:
                raise InputError(name, f"malformed block start '{text}'", line=lineno)
            block = Block(kind=m.group(1), name=m.group(2).strip(), line=lineno, path=name)
            stack[-1].children.append(block)
            stack.append(block)
        elif text.startswith("end_<"):
            m = _END.match(text)
            if m is None:
                raise InputError(name, f"malformed block end '{text}'", line=lineno)
            if len(stack) == 1 or stack[-1].kind != m.group(1):
                opened = stack[-1].kind if len(stack) > 1 else "nothing"
                raise InputError(name, f"end_<{m.group(1)}> closes {opened}", line=lineno)
            stack.pop()
        else:
            stack[-1].entries.append((lineno, text))
    if len(stack) > 1:
        b = stack[-1]
        raise InputError(name, f"begin_<{b.kind}> at line {b.line} is never closed (file truncated?)", line=b.line)
    return root

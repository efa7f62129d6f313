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

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from uavplace.infra.limits import check_limit, limits
from uavplace.ingest.wireless_insite.p2m_header import (
    COHERENT_MARGIN_DB,
    DEFAULT_POWER_THRESHOLD_DBM,
    HEADER_PROBE,
    MAX_LINE_BYTES,
    NON_SPACE,
    NUL,
    POSITION_COLUMNS,
    converted,
    diagnose,
    line_of_row,
    parse_filename,
    split_header,
    text_conversion,
    value_columns,
)
from uavplace.schemas import InputError, ReceiverSet
from uavplace.schemas.receivers import QUANTITIES
from uavplace.schemas.tables import RECEIVERS, Column

#: Text read per batch by the streaming reader (a row is about 45 bytes: some 45 k rows a batch). Measured on a
#: 5 M-row ingest: 16 MiB peaked 150 MB higher, 1 MiB and below ran 10-20 % slower.
BATCH_BYTES = 2 << 20
#: Rows checked at a time after the line-by-line fallback.
_FALLBACK_ROWS = 250_000


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
        probe = self._read(HEADER_PROBE)
        conversion = text_conversion(probe)
        if NUL in probe and conversion != "utf-16":
            raise InputError(
                self.name,
                f"holds NUL bytes (first at byte {probe.index(NUL)}): binary data, or UTF-16 text without a "
                "byte-order mark; a .p2m is ASCII text",
            )
        if conversion is not None:
            self._raw = converted(self.name, self._read(None), conversion)
            probe = self._raw
        elif len(probe) == HEADER_PROBE and probe.count(b"\n#") + 1 >= probe.count(b"\n"):
            self._raw = self._read(None)  # an unusually long header
            probe = self._raw
        self.conversion = conversion
        header = split_header(probe)
        self.header = header
        values = value_columns(self.name, ident.output, header)
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
        whole = self._raw is not None or len(probe) < HEADER_PROBE
        if whole and NON_SPACE.search(probe, header.body_offset) is None:
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
        line = line_of_row(self._whole(), self.header.body_offset, len(self.header.lines), row)
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
            normalised = diagnose(self.name, self._whole(), self.header, self.names)
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
            line1 = line_of_row(self._whole(), self.header.body_offset, len(self.header.lines), row0 + first)
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

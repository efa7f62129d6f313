"""The receivers of a city folder: each receiver output file read against its ``.txrx`` set (its count and lattice
checked), the quantities of one transmitter x receiver set merged into one row per receiver, the transmitters' table
(steps 3 of the ingest recipe, ``ingest.pipeline``)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from uavplace.ingest.formats import Classified
from uavplace.ingest.wireless_insite.p2m import P2MStream
from uavplace.ingest.wireless_insite.p2m_header import COHERENT_MARGIN_DB, POSITION_COLUMNS, antenna_gain_dbi, parse_filename
from uavplace.schemas import (
    RECEIVERS,
    TRANSMITTERS,
    InputError,
    ReceiverSet,
    SetupInfo,
    TxRxSet,
)
from uavplace.schemas.provenance import RAY_TRACED, RECEIVER_CODES, UNREACHED, code_name

if TYPE_CHECKING:
    import pandas as pd

#: Receiver positions from two files of one set agree within this [m] (+ 1e-5 relative: 6 significant digits).
POSITION_TOL_M = 1e-3
#: A grid receiver lies on its .txrx lattice point within this [m] (+ 1e-5 relative).
LATTICE_TOL_M = 1e-2


def _positions_agree(a: np.ndarray, b: np.ndarray, tol_m: float = POSITION_TOL_M) -> np.ndarray:
    return np.abs(a - b) <= tol_m + 1e-5 * np.abs(a)


def merge_receiver_files(key: tuple[int, int, int], parts: list[tuple[ReceiverSet, pa.Table]]) -> pd.DataFrame:
    """One frame per (tx set, tx point, rx set): the quantities of several outputs side by side.

    Raises ``InputError`` if two files give the same quantity, or give the same
    receiver number at different positions.
    """
    import pandas as pd  # only for receivers given by several outputs (about 50 MB): a single file never needs it

    meta0, table0 = parts[0]
    merged = table0.to_pandas(types_mapper={pa.bool_(): pd.BooleanDtype()}.get)
    given = {c: meta0.source for c in meta0.columns}
    for meta, table in parts[1:]:
        for c in meta.columns:
            if c in given:
                raise InputError(
                    meta.source, f"{c} for t{key[1]:03d}_{key[0]:02d} r{key[2]:03d} is also given by {given[c]}", field=c
                )
            given[c] = meta.source
        frame = table.to_pandas(types_mapper={pa.bool_(): pd.BooleanDtype()}.get)
        joined = merged.merge(frame, on="rx_index", how="outer", suffixes=("", "_new"), sort=True, indicator=True)
        both = (joined["_merge"] == "both").to_numpy()
        for c in POSITION_COLUMNS:
            old, new = joined[c].to_numpy(), joined[f"{c}_new"].to_numpy()
            bad = both & ~_positions_agree(old, new)
            if bad.any():
                i = int(np.argmax(bad))
                raise InputError(
                    meta.source,
                    f"receiver {int(joined['rx_index'].iat[i])} at {c}={new[i]}, but {old[i]} in {meta0.source}",
                    field=c,
                )
            joined[c] = joined[c].fillna(joined[f"{c}_new"])
        ra, rb = joined["reached"], joined["reached_new"]
        reached = ra.fillna(True) & rb.fillna(True)
        reached[ra.isna() & rb.isna()] = pd.NA
        joined["reached"] = reached
        merged = joined.drop(columns=[f"{c}_new" for c in (*POSITION_COLUMNS, "reached")] + ["_merge"])
    merged["tx_set_id"], merged["tx_point"], merged["rx_set_id"] = key
    return merged


def _check_count(meta: ReceiverSet, rx_set: TxRxSet, warnings: list[str]) -> None:
    """A grid output must have one row per lattice point.

    A points set whose point count differs from the output's rows is a warning
    (once per set), not an error: exporters such as 5G-MIMO scripts rewrite the
    .txrx after each run.
    """
    shape = rx_set.grid_shape
    if shape is None:
        if rx_set.kind == "points" and len(rx_set.vertices_m) != meta.num_rows:
            text = (
                f"receiver set '{rx_set.name}' ({rx_set.source}) lists {len(rx_set.vertices_m)} point(s) but its "
                f"outputs have {meta.num_rows} rows (e.g. {meta.source}): the .txrx was probably rewritten after "
                "the run; positions not checked"
            )
            if text.split(" (e.g.")[0] not in (w.split(" (e.g.")[0] for w in warnings):
                warnings.append(text)
        return
    nx, ny = shape
    if meta.num_rows != nx * ny:
        raise InputError(
            meta.source,
            f"{meta.num_rows} rows, but grid '{rx_set.name}' ({rx_set.source}) is {nx} x {ny} = {nx * ny} receivers",
            field="rows",
        )


def _check_lattice(source: str, table: pa.Table, rx_set: TxRxSet) -> None:
    """Every receiver of a grid output lies on its .txrx lattice point (x varying fastest)."""
    shape = rx_set.grid_shape
    if shape is None:
        return
    nx, ny = shape
    assert rx_set.spacing_m is not None
    i = table.column("rx_index").to_numpy().astype(np.int64) - 1
    if i.max() >= nx * ny:
        k = int(np.argmax(i))
        raise InputError(
            source, f"receiver {i[k] + 1}, but grid '{rx_set.name}' ({rx_set.source}) has {nx * ny}", field="rx_index"
        )
    cx, cy, _ = rx_set.vertices_m[0]
    for col, expect in (("x_m", cx + (i % nx) * rx_set.spacing_m), ("y_m", cy + (i // nx) * rx_set.spacing_m)):
        got = table.column(col).to_numpy()
        bad = ~_positions_agree(expect, got, LATTICE_TOL_M)
        if bad.any():
            k = int(np.argmax(bad))
            raise InputError(
                source,
                f"receiver {i[k] + 1} at {col}={got[k]}, off grid '{rx_set.name}' ({rx_set.source}) which puts it at {expect[k]:.4f}",
                field=col,
            )


def _receiver_rows(key: tuple[int, int, int], table: pa.Table, source: str) -> pa.Table:
    """One group's rows as the RECEIVERS table: the group's ids, the columns its files gave, nulls for the rest."""
    n = table.num_rows
    cols: dict[str, pa.Array | pa.ChunkedArray] = {}
    for c in RECEIVERS.columns:
        if c.name in ("tx_set_id", "tx_point", "rx_set_id"):
            cols[c.name] = pa.array(np.full(n, key[("tx_set_id", "tx_point", "rx_set_id").index(c.name)], np.int32))
        elif c.name in table.column_names:
            cols[c.name] = table.column(c.name)
        else:
            cols[c.name] = pa.nulls(n, c.type)
    return RECEIVERS.conform(pa.table(cols), source)


class ReceiverReader:
    """Reads the receiver outputs of one group (transmitter point x receiver set) and appends them to receivers.parquet.

    A group of one file is streamed batch by batch (memory stays flat however
    large the file); the files of a group of several outputs (pl and power,
    say) are read whole and merged side by side. Counts what it wrote.
    """

    def __init__(
        self,
        sets: dict[int, TxRxSet],
        setup: SetupInfo | None,
        warnings: list[str],
        tick: Callable[[str], None],
        done: Callable[..., None],
    ) -> None:
        self.txrx, self.setup, self.warnings, self.tick, self.done = sets, setup, warnings, tick, done
        self.rows = 0
        self.reached = 0
        self.sets: list[ReceiverSet] = []
        #: The side file's codes (``ingest.provenance``) and its name, or None and the code of a reached receiver.
        self.codes: dict[tuple[int, int, int], np.ndarray] | None = None
        self.codes_source = ""
        self.default_code = RAY_TRACED
        self.by_code = np.zeros(len(RECEIVER_CODES), np.int64)
        self.seen: dict[tuple[int, int, int], int] = {}

    def _with_codes(self, key: tuple[int, int, int], table: pa.Table, source: str) -> pa.Table:
        """``table`` with its ``provenance`` column: the side file's codes of its receivers, checked against their
        reach (a receiver is unreached exactly where its file says no path reached it), or the export's default."""
        reached = table.column("reached").to_numpy(zero_copy_only=False) if "reached" in table.column_names else None
        unreached = np.zeros(table.num_rows, bool) if reached is None else np.equal(reached, False)
        if self.codes is None:
            codes = np.where(unreached, UNREACHED, self.default_code).astype(np.uint8)
        else:
            known = self.codes.get(key)
            if known is None:
                raise InputError(
                    self.codes_source,
                    f"no rows for transmitter {key[1]} of set {key[0]} and receiver set "
                    f"{key[2]} ({source} has {table.num_rows} receivers)",
                    field="tx_point",
                )
            index = table.column("rx_index").to_numpy(zero_copy_only=False).astype(np.int64) - 1
            off = (index < 0) | (index >= len(known))
            if off.any():
                raise InputError(
                    self.codes_source,
                    f"the rows of transmitter {key[1]} of set {key[0]} and receiver set {key[2]} "
                    f"describe receivers 1..{len(known)}, {source} has receiver {index[np.argmax(off)] + 1}",
                    field="codes",
                )
            codes = known[index]
            live = ~np.equal(reached, False) if reached is not None else np.ones(len(codes), bool)
            wrong = ((codes == UNREACHED) & live) | ((codes != UNREACHED) & unreached)
            if wrong.any():
                k = int(np.argmax(wrong))
                raise InputError(
                    self.codes_source,
                    f"transmitter {key[1]} of set {key[0]}, receiver {index[k] + 1}: code "
                    f"{codes[k]} ({code_name(int(codes[k]))}), but {source} says "
                    f"{'no path reached it' if unreached[k] else 'a path reached it'}",
                    field="code",
                )
            self.seen[key] = self.seen.get(key, 0) + len(codes)
        self.by_code += np.bincount(codes, minlength=len(self.by_code))[: len(self.by_code)]
        return table.append_column("provenance", pa.array(codes, pa.uint8()))

    def check_codes_used(self) -> None:
        """Every row of the side file described receivers of the export: none left over."""
        if self.codes is None:
            return
        for key, known in self.codes.items():
            if self.seen.get(key, 0) != len(known):
                raise InputError(
                    self.codes_source,
                    f"the rows of transmitter {key[1]} of set {key[0]} and receiver set {key[2]} "
                    f"describe {len(known)} receivers, the export has {self.seen.get(key, 0)}",
                    field="codes",
                )

    def _open(self, f: Classified) -> tuple[P2MStream, TxRxSet | None]:
        ident = parse_filename(f.path.name)
        assert ident is not None and ident.rx_set is not None
        rx_set, tx_set = self.txrx.get(ident.rx_set), self.txrx.get(ident.tx_set)
        if rx_set is None and self.txrx:
            self.warnings.append(f"{f.rel}: receiver set {ident.rx_set} is not in the .txrx; not checked")
        ant = self.setup.antenna(rx_set.rx_antenna) if self.setup and rx_set else None
        tx_ant = self.setup.antenna(tx_set.tx_antenna) if self.setup and tx_set else None
        gains = antenna_gain_dbi(tx_ant.type if tx_ant else None) + antenna_gain_dbi(ant.type if ant else None)
        stream = P2MStream(
            f.path,
            display=f.rel,
            power_threshold_dbm=ant.power_threshold_dbm if ant else None,
            max_gain_db=gains + COHERENT_MARGIN_DB,
            tx_power_dbm=tx_set.tx_power_dbm if tx_set is not None else None,
        )
        return stream, rx_set

    def _batches(self, f: Classified) -> Iterator[pa.Table]:
        """The file's checked batches; once they are all read, its ``ReceiverSet`` is ``self.sets[-1]``."""
        self.tick(f.rel)
        stream, rx_set = self._open(f)
        for batch in stream:
            if rx_set is not None:
                _check_lattice(f.rel, batch, rx_set)
            yield batch
        if rx_set is not None:
            _check_count(stream.meta, rx_set, self.warnings)
        self._record(f, stream.meta)

    def _record(self, f: Classified, meta: ReceiverSet) -> None:
        self.sets.append(meta)
        reached = meta.num_reached if meta.num_reached is not None else "n/a"
        self.done(f, rows=meta.num_rows, message=f"{meta.output}: {meta.num_rows} receivers, {reached} reached")

    def _append(self, writer: pq.ParquetWriter, rows: pa.Table) -> None:
        writer.write_table(rows)
        self.rows += rows.num_rows
        self.reached += int(pc.sum(rows.column("reached")).as_py() or 0)

    def write(self, key: tuple[int, int, int], files: list[Classified], writer: pq.ParquetWriter) -> None:
        if len(files) == 1:
            for batch in self._batches(files[0]):
                self._append(writer, _receiver_rows(key, self._with_codes(key, batch, files[0].rel), files[0].rel))
            return
        parts = []
        for f in files:
            table = pa.concat_tables(list(self._batches(f)))
            parts.append((self.sets[-1], table))
        merged = pa.Table.from_pandas(merge_receiver_files(key, parts), preserve_index=False)
        self._append(writer, _receiver_rows(key, self._with_codes(key, merged, files[0].rel), files[0].rel))


def transmitters_table(sets: list[TxRxSet], setup: SetupInfo | None, seen: set[tuple[int, int]], warnings: list[str]) -> pa.Table:
    rows: dict[str, list] = {c: [] for c in TRANSMITTERS.column_names}

    def add(**kw: object) -> None:
        for c in TRANSMITTERS.column_names:
            rows[c].append(kw.get(c))

    defined = set()
    for s in sets:
        if not s.is_transmitter:
            continue
        wave = setup.waveform(s.tx_waveform) if setup else None
        if wave is None and setup and len(setup.waveforms) == 1:
            wave = setup.waveforms[0]
        ant = setup.antenna(s.tx_antenna) if setup else None
        for point, (x, y, z) in enumerate(s.vertices_m, start=1):
            defined.add((s.project_id, point))
            add(
                tx_set_id=s.project_id,
                tx_point=point,
                set_name=s.name,
                x_m=x,
                y_m=y,
                z_m=z,
                power_dbm=s.tx_power_dbm,
                frequency_hz=wave.carrier_frequency_hz if wave else None,
                antenna=(ant.type or ant.name) if ant else None,
                source=s.source,
            )
    for tx_set, point in sorted(seen - defined):
        warnings.append(f"transmitter set {tx_set} point {point} has outputs but no .txrx definition: position unknown")
        add(tx_set_id=tx_set, tx_point=point, source="receiver outputs")
    return TRANSMITTERS.conform(pa.Table.from_pydict(rows))


def export_receivers(sets: dict[int, TxRxSet], groups: dict) -> int | None:
    """How many receivers an export's ``.p2m`` files hold: each (transmitter point, receiver set) group's receivers,
    from the ``.txrx`` sets (a grid's rows times columns, else its vertices); None when a set is not known."""
    total = 0
    for _tx_set, _tx_point, rx_set in groups:
        s = sets.get(rx_set)
        if s is None:
            return None
        shape = s.grid_shape
        total += shape[0] * shape[1] if shape is not None else len(s.vertices_m)
    return total

"""The ingest recipe: a city folder of raw exports -> validated tables in ``<out>/<city>/ingested/``.

1. discover and classify every file (``classify``);
2. read the .setup and .txrx (frequencies, thresholds, sets);
3. read receiver outputs, check them against their .txrx sets, merge the
   quantities of one transmitter x receiver set into one row per receiver;
4. read building geometry and terrain;
5. write the tables, the manifest and the ingest report atomically.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import shapely

from uavplace.infra.files import atomic_directory, check_name, sha256_file, write_model_json
from uavplace.ingest.buildings import BuildingRecord, buildings_tables
from uavplace.ingest.formats import EXPORT_SUFFIXES, FORMATS, Format, folder_format, format_of
from uavplace.ingest.provenance import default_code, export_digest, read_provenance, recorded_export
from uavplace.ingest.routes import read_routes
from uavplace.ingest.wireless_insite.city import read_terrain
from uavplace.ingest.wireless_insite.p2m import COHERENT_MARGIN_DB, POSITION_COLUMNS, P2MStream, antenna_gain_dbi, parse_filename
from uavplace.ingest.wireless_insite.setup import read_setup
from uavplace.ingest.wireless_insite.txrx import read_txrx
from uavplace.ingest.written import made_by, write_tables
from uavplace.schemas import (
    BUILDING_PARTS,
    BUILDINGS,
    RECEIVERS,
    ROUTES,
    TRANSMITTERS,
    CityManifest,
    FileReport,
    IngestReport,
    InputError,
    Origin,
    ReceiverSet,
    Rejection,
    SetupInfo,
    SourceFile,
    TerrainInfo,
    TxRxSet,
)
from uavplace.schemas.provenance import RAY_TRACED, RECEIVER_CODES, UNREACHED, code_name

if TYPE_CHECKING:
    import pandas as pd

INGESTED = "ingested"
MANIFEST = "manifest.json"
REPORT = "ingest_report.json"
TERRAIN = "terrain.npz"

#: Receiver positions from two files of one set agree within this [m] (+ 1e-5 relative: 6 significant digits).
POSITION_TOL_M = 1e-3
#: A grid receiver lies on its .txrx lattice point within this [m] (+ 1e-5 relative).
LATTICE_TOL_M = 1e-2


@dataclass(frozen=True)
class Classified:
    path: Path
    rel: str
    kind: str
    skip_reason: str | None = None
    #: Its entry of the reader table (None: not a format ingest reads).
    fmt: Format | None = None


def classify(folder: Path) -> list[Classified]:
    """Every non-hidden file below ``folder``, sorted, with its format family.

    A symbolic link that leads out of ``folder`` is listed as skipped (kind
    ``link``) and never opened: a city folder cannot make ingest read files
    elsewhere on the machine. Whatever is not a regular file (a FIFO, a device, a
    socket, a broken or looping link, a folder named like an export) is listed as
    skipped too (kind ``special``), never opened: it would block or say nothing.
    """
    out = []
    inside = folder.resolve()
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if any(part.startswith(".") for part in Path(rel).parts):
            continue
        low = path.name.lower()
        kind, reason, fmt = "other", None, None
        try:
            target = path.resolve()
        except (OSError, RuntimeError):  # a link loop
            target = None
        if target is not None and not target.is_relative_to(inside):
            kind, reason = "link", f"symbolic link to {target}, outside the city folder: not read"
        elif path.is_dir() and target is not None:
            if not low.endswith(EXPORT_SUFFIXES):
                continue  # a folder of the city: its files are listed themselves
            kind, reason = "special", "a folder named like an export: not read"
        elif target is None or not path.is_file():
            kind, reason = "special", "not a regular file (a FIFO, device, socket, or a broken or looping link): not read"
        elif (fmt := format_of(path)) is not None:
            kind, reason = fmt.kind, fmt.skip_reason(path.name)
        out.append(Classified(path, rel, kind, reason, fmt))
    return out


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


class _ReceiverReader:
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


def _transmitters(sets: list[TxRxSet], setup: SetupInfo | None, seen: set[tuple[int, int]], warnings: list[str]) -> pa.Table:
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


def _single(files: list[Classified], kind: str) -> Classified | None:
    if len(files) > 1:
        raise InputError(
            files[1].rel, f"several .{kind} files ({', '.join(f.rel for f in files)}): keep one per city folder", field="file"
        )
    return files[0] if files else None


def ingest_city(
    folder: str | Path,
    out_root: str | Path = "data/processed",
    *,
    name: str | None = None,
    command: str = "",
    on_file: Callable[[str, int], None] | None = None,
) -> tuple[Path, CityManifest, IngestReport]:
    """Ingest one city folder; returns (output folder, manifest, report).

    ``on_file(rel_path, total)`` is called before each of the ``total`` files that are read
    (for progress display). Raises ``InputError`` on bad input; nothing is
    written then, and an earlier ingest of the city stays as it was.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "not a folder")
    city = (
        check_name(name, "city name")
        if name is not None
        else check_name(folder.resolve().name, "city name (the folder's; or pass --name)")
    )
    if (whole := folder_format(folder)) is not None:  # a folder format (a RadioMapSeer-style folder), not files
        out_dir = Path(out_root) / city / INGESTED
        return (out_dir, *whole.ingest(folder, out_dir, city, (MANIFEST, REPORT), command))
    files = classify(folder)
    if not files:
        raise InputError(folder, "empty folder: nothing to ingest")
    by_kind: dict[str, list[Classified]] = defaultdict(list)
    for f in files:
        by_kind[f.kind].append(f)
    usable = [f for f in files if f.kind not in ("other",) and f.skip_reason is None]
    if not usable:
        raise InputError(
            folder,
            f"no receiver output, .txrx, .setup or geometry file among {len(files)} file(s): {', '.join(f.rel for f in files[:5])}",
        )

    warnings: list[str] = []
    reports: dict[str, FileReport] = {}
    rejections: list[Rejection] = []

    def tick(rel: str) -> None:
        if on_file is not None:
            on_file(rel, len(usable))

    def done(f: Classified, rows: int = 0, rejected: int = 0, message: str | None = None, status: str = "parsed") -> None:
        reports[f.rel] = FileReport(
            path=f.rel, kind=f.kind, status=status, rows_read=rows, rows_rejected=rejected, message=message
        )  # type: ignore[arg-type]

    for f in files:
        if f.kind == "other":
            warnings.append(f"{f.rel}: unknown file type, ignored")
            done(f, status="unknown", message="unknown file type")
        elif f.skip_reason is not None:
            done(f, status="skipped", message=f.skip_reason)
            if f.kind in ("link", "special"):
                warnings.append(f"{f.rel}: {f.skip_reason}")

    setup = None
    if (f := _single(by_kind["setup"], "setup")) is not None:
        tick(f.rel)
        setup = read_setup(f.path, f.rel)
        done(
            f,
            message=f"{len(setup.waveforms)} waveform(s), {len(setup.antennas)} antenna(s), {len(setup.comm_systems)} comm system(s)",
        )
        present = {Path(x.rel).name for x in files}
        for feat in setup.features:
            if feat.active and Path(feat.filename).name not in present:
                warnings.append(f"{f.rel}: active {feat.kind} feature '{feat.filename}' is not in the folder")

    sets: dict[int, TxRxSet] = {}
    for f in by_kind["txrx"]:
        tick(f.rel)
        file_sets = read_txrx(f.path, f.rel)
        for s in file_sets:
            if s.project_id in sets:
                raise InputError(
                    f.rel, f"set project_id {s.project_id} also defined at {sets[s.project_id].source}", field="project_id"
                )
            sets[s.project_id] = s
        done(f, rows=len(file_sets), message=f"{len(file_sets)} set(s)")

    # Receiver outputs, one group per transmitter point x receiver set. They are read after the rest, streamed
    # batch by batch into receivers.parquet inside the output's temporary folder (memory stays flat).
    groups: dict[tuple[int, int, int], list[Classified]] = defaultdict(list)
    for f in by_kind["p2m"]:
        if f.skip_reason is None:
            ident = parse_filename(f.path.name)
            assert ident is not None and ident.rx_set is not None and ident.tx_point is not None
            groups[(ident.tx_set, ident.tx_point, ident.rx_set)].append(f)
    if groups and not sets:
        warnings.append("no .txrx: receiver grids were not checked and transmitter positions are unknown")
    transmitters = _transmitters(list(sets.values()), setup, {(k[0], k[1]) for k in groups}, warnings)
    receivers = _ReceiverReader(sets, setup, warnings, tick, done)
    if (f := _single(by_kind["cells"], "provenance.csv.gz")) is not None:
        tick(f.rel)
        receivers.codes, receivers.codes_source = read_provenance(f.path, f.rel, export_receivers(sets, groups)), f.rel
        recorded = recorded_export(f.path, f.rel)
        if recorded is None:
            warnings.append(f"{f.rel} records no sha256 of its export: not checked against these .p2m files")
        elif recorded != export_digest([p.path for p in by_kind["p2m"] if p.skip_reason is None]):
            raise InputError(
                f.rel,
                "written for another export: the sha256 of the .p2m files it records is not this "
                "folder's (another simulation of the city?); it does not describe these receivers",
                field="export",
            )
        done(
            f,
            rows=sum(len(c) for c in receivers.codes.values()),
            message=f"provenance of {len(receivers.codes)} transmitter(s) x receiver set(s)",
        )
    else:
        simulated = next((x for x in by_kind["provenance"] if Path(x.rel).name == "simulation.json"), None)
        receivers.default_code = default_code(simulated.path if simulated else None, simulated.rel if simulated else None)

    records: list[BuildingRecord] = []
    origin = None
    if setup and setup.longitude is not None and setup.latitude is not None and (setup.longitude, setup.latitude) != (0.0, 0.0):
        origin = Origin(longitude=setup.longitude, latitude=setup.latitude, source=setup.source)
    rank = {kind: i for i, kind in reversed(list(enumerate(f.kind for f in FORMATS)))}  # the table's order of kinds
    for f in sorted(files, key=lambda f: rank.get(f.kind, len(rank))):
        if f.fmt is None or f.fmt.read is None or f.skip_reason is not None:
            continue
        tick(f.rel)
        got = f.fmt.read(f.path, f.rel, None)
        records += got.records
        rejections += got.rejected
        if not got.records:
            warnings.append(f"{f.rel}: no building in this {f.fmt.title} file")
        message = f"{len(got.records)} {f.fmt.unit}" + (f"; heights: {got.heights}" if got.heights else "")
        done(f, rows=len(got.records) + len(got.rejected), rejected=len(got.rejected), message=message)
    terrain_arrays = None
    terrain_info = None
    if by_kind["terrain"]:
        verts, tris = [], []
        for f in by_kind["terrain"]:
            tick(f.rel)
            v, t = read_terrain(f.path, f.rel)
            tris.append(t + sum(len(x) for x in verts))
            verts.append(v)
            done(f, rows=len(t), message=f"{len(v)} vertices, {len(t)} triangles")
        terrain_arrays = (np.vstack(verts), np.vstack(tris))
        terrain_info = TerrainInfo(
            source=", ".join(f.rel for f in by_kind["terrain"]),
            num_vertices=len(terrain_arrays[0]),
            num_faces=len(terrain_arrays[1]),
            z_min_m=float(terrain_arrays[0][:, 2].min()),
            z_max_m=float(terrain_arrays[0][:, 2].max()),
        )

    buildings, parts, rej = buildings_tables(records, ground_z_m=None if terrain_info else 0.0)
    rejections += rej
    for r in rej:
        rel = r.file.split("#", 1)[0]  # "file#features[3]" or "file#body[2]": the file's report
        old = reports[rel]
        reports[rel] = old.model_copy(update={"rows_rejected": old.rows_rejected + r.count})
    routes = None
    if (f := _single(by_kind["routes"], "routes.csv")) is not None:
        tick(f.rel)
        # The footprints a user on the ground could walk into: parts reaching down to the users' 1.5 m (all of them
        # over terrain, whose heights are absolute).
        low = [
            shapely.from_wkb(w)
            for w, z in zip(parts.column("footprint_wkb").to_pylist(), parts.column("base_z_m").to_pylist(), strict=True)
            if terrain_info is not None or z <= 1.5
        ]
        routes = read_routes(f.path, f.rel, transmitters, low)
        done(
            f, rows=routes.num_rows, message=f"{len(set(routes.column('route').to_pylist()))} route(s), {routes.num_rows} points"
        )

    freqs = sorted({float(x) for x in transmitters.column("frequency_hz").drop_null().to_pylist()})
    if not freqs and setup and len(setup.waveforms) == 1:
        freqs = [setup.waveforms[0].carrier_frequency_hz]
    powers = tuple(sorted({float(x) for x in transmitters.column("power_dbm").drop_null().to_pylist()}))

    out_dir = Path(out_root) / city / INGESTED
    with atomic_directory(out_dir, marker=MANIFEST, what="ingested city") as tmp:
        tables = {}
        with pq.ParquetWriter(tmp / RECEIVERS.filename, RECEIVERS.arrow_schema(), compression="zstd") as writer:
            for key in sorted(groups):
                receivers.write(key, groups[key], writer)
        receivers.check_codes_used()
        tables[RECEIVERS.name] = sha256_file(tmp / RECEIVERS.filename)
        written = [(TRANSMITTERS, transmitters), (BUILDINGS, buildings), (BUILDING_PARTS, parts)]
        tables |= write_tables(tmp, written + ([(ROUTES, routes)] if routes is not None else []))
        if terrain_arrays is not None:
            np.savez_compressed(tmp / TERRAIN, vertices_m=terrain_arrays[0], triangles=terrain_arrays[1])
            tables["terrain"] = sha256_file(tmp / TERRAIN)
        report = IngestReport(
            city=city, files=tuple(reports[f.rel] for f in files), rejections=tuple(rejections), warnings=tuple(warnings)
        )
        manifest = CityManifest(
            **made_by(city, command, folder),
            origin=origin,
            frequency_hz=freqs[0] if len(freqs) == 1 else None,
            tx_power_dbm=powers,
            counts={
                "files": len(files),
                "files_parsed": sum(r.status == "parsed" for r in report.files),
                "files_skipped": sum(r.status == "skipped" for r in report.files),
                "files_unknown": sum(r.status == "unknown" for r in report.files),
                "transmitters": transmitters.num_rows,
                "receiver_sets": len({k[2] for k in groups}),
                "receiver_rows": receivers.rows,
                "receiver_rows_reached": receivers.reached,
                **{f"receiver_rows_{code_name(c).replace(' ', '_')}": int(n) for c, n in enumerate(receivers.by_code)},
                "buildings": buildings.num_rows,
                "building_parts": parts.num_rows,
                "terrain_triangles": terrain_info.num_faces if terrain_info else 0,
                "rows_rejected": report.rows_rejected,
                "route_points": routes.num_rows if routes is not None else 0,
            },
            sources=tuple(
                SourceFile(
                    path=f.rel,
                    sha256=None if f.kind in ("link", "special") else sha256_file(f.path),
                    size_bytes=None if f.kind in ("link", "special") else f.path.stat().st_size,
                    kind=f.kind,
                    status=reports[f.rel].status,
                )
                for f in files
            ),
            tables=tables,
            setup=setup,
            txrx_sets=tuple(sets.values()),
            receiver_sets=tuple(sorted(receivers.sets, key=lambda m: m.source)),
            terrain=terrain_info,
        )
        write_model_json(manifest, tmp / MANIFEST)
        write_model_json(report, tmp / REPORT)
    return out_dir, manifest, report


__all__ = ["classify", "ingest_city", "merge_receiver_files"]

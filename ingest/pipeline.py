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
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow.parquet as pq
import shapely

from uavplace.infra.files import atomic_directory, check_name, sha256_file, write_model_json
from uavplace.ingest.buildings import BuildingRecord, buildings_tables
from uavplace.ingest.formats import FORMATS, GEOMETRY_TITLES, Classified, classify, folder_format
from uavplace.ingest.provenance import default_code, export_digest, read_provenance, recorded_export
from uavplace.ingest.receivers import ReceiverReader, export_receivers, transmitters_table
from uavplace.ingest.routes import read_routes
from uavplace.ingest.wireless_insite.city import read_terrain
from uavplace.ingest.wireless_insite.p2m_header import parse_filename
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
    Rejection,
    SourceFile,
    TerrainInfo,
    TxRxSet,
)
from uavplace.schemas.provenance import code_name
from uavplace.schemas.receivers import RECEIVER_OUTPUTS

if TYPE_CHECKING:
    pass

INGESTED = "ingested"
MANIFEST = "manifest.json"
REPORT = "ingest_report.json"
TERRAIN = "terrain.npz"


def _single(files: list[Classified], kind: str) -> Classified | None:
    if len(files) > 1:
        raise InputError(
            files[1].rel, f"several .{kind} files ({', '.join(f.rel for f in files)}): keep one per city folder", field="file"
        )
    return files[0] if files else None


def nothing_usable(files: list[Classified]) -> str:
    """Why a folder of ``files`` holds nothing ingest reads: each reason a file was passed over, with how many files
    and the first, and what ingest reads."""
    reasons: dict[str, list[str]] = {}
    for f in files:
        reasons.setdefault(f.skip_reason or "not a format uavplace reads", []).append(f.rel)
    why = "; ".join(f"{len(rels)} x {reason} (e.g. {rels[0]})" for reason, rels in reasons.items())
    return (
        f"no receiver output, .txrx, .setup or geometry file among {len(files)} file(s): {why}. Ingest reads Wireless "
        "InSite receiver outputs by their own names, <project>.<output>.tTTT_SS.rRRR.p2m (outputs "
        f"{', '.join(RECEIVER_OUTPUTS)}; per-path outputs such as cir are not read), the .txrx and .setup, and "
        f"buildings as {GEOMETRY_TITLES}"
    )


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
        others = [f.rel for f in classify(folder) if f.kind not in ("other", "provenance")]
        if others:  # an export beside it would be neither read nor named
            raise InputError(
                folder,
                f"is a {whole.title} and also holds {len(others)} file(s) of other formats ({', '.join(others[:3])}): "
                "one format a city folder; move one of them to a folder of its own",
            )
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
        raise InputError(folder, nothing_usable(files))

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
    transmitters = transmitters_table(list(sets.values()), setup, {(k[0], k[1]) for k in groups}, warnings)
    receivers = ReceiverReader(sets, setup, warnings, tick, done)
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


__all__ = ["ingest_city"]

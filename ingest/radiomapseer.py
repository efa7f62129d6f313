"""A RadioMapSeer-style folder (the layout `uavdata export --format radiomapseer` writes; dataset/export.py documents
it) read as data, and ingested as a city: ``uavdata ingest FOLDER`` takes such a folder as it takes a Wireless InSite
export, so that external radio-map data sets in this layout become cities (and train the searcher's predictor).

The folder gives, on one grid, the cells the UAV may not enter, the building heights (cm), each user's cell and
position, and each user's SINR quantised to ``step_db`` (0: no path). The ingested city holds one receiver per grid
cell and user at the cell's centre and the altitude (its SINR, unreached where the code is 0, the provenance "not
recorded"), one transmitter per user, and the buildings as the union of the cells of each height (one building a
connected patch): `uavdata build` at the folder's grid and altitude gives back the same maps, the SINR to the
quantisation.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import shapely

from uavplace.infra.files import atomic_directory, check_inside, check_name, read_small_file, sha256_file, write_model_json
from uavplace.infra.limits import check_limit
from uavplace.ingest.buildings import BuildingRecord, Part, buildings_tables
from uavplace.ingest.written import made_by, write_tables
from uavplace.schemas import BUILDING_PARTS, BUILDINGS, RECEIVERS, TRANSMITTERS, CityManifest, InputError
from uavplace.schemas.city import FileReport, IngestReport, SourceFile
from uavplace.schemas.provenance import NOT_RECORDED, RECEIVER_CODES, UNREACHED, code_name
from uavplace.schemas.tables import RATIO_RANGE_DB

#: The folder's format name (``scale.json``'s ``format``).
RADIOMAPSEER = "uavplace-radiomapseer/1"
#: The users' height above the ground [m] (a transmitter's z).
USER_HEIGHT_M = 1.5


@dataclass
class RadioMapFolder:
    """A RadioMapSeer-style folder's content, row 0 of every array the southernmost (as bundles hold maps)."""

    city: str
    version: str
    settings: dict  # scale.json's settings (altitude_m, noise_dbm, tx_power_dbm, frequency_hz, ...)
    grid: dict  # x_min_m, y_min_m, spacing_m, num_x, num_y
    floor_db: float
    step_db: float
    blocked: np.ndarray  # bool [ny, nx]: the UAV may not enter
    ground_m: np.ndarray  # float [ny, nx]: building height above the ground (0: open ground)
    user_ids: list[int]
    cells: np.ndarray  # int [U, 2]: each user's (iy, ix)
    positions_m: np.ndarray  # float [U, 2]: each user's (x, y)
    codes: np.ndarray  # uint8 [U, ny, nx]: the quantised SINR (0: dead)
    files: list[Path]  # every file read, for the record


def decode_sinr(codes: np.ndarray, floor_db: float, step_db: float) -> tuple[np.ndarray, np.ndarray]:
    """(SINR [dB] float32, dead bool) of quantised codes: 0 dead, else ``floor + (code - 1) x step``."""
    dead = codes == 0
    sinr = (floor_db + (np.maximum(codes.astype(np.float32), 1) - 1) * np.float32(step_db)).astype(np.float32)
    return sinr, dead


def is_radiomapseer(folder: str | Path) -> bool:
    """Whether ``folder`` holds a ``scale.json`` of this format (a regular file; read as data)."""
    path = Path(folder) / "scale.json"
    if not path.is_file() or path.is_symlink():
        return False
    try:
        return json.loads(read_small_file(path, "a RadioMapSeer-style folder's scale.json")).get("format") == RADIOMAPSEER
    except (InputError, ValueError, AttributeError):
        return False


#: The PNG modes each raster is read in (PIL's names): a gain or building map 8-bit gray, the heights 16-bit gray.
GRAY_8, GRAY_16 = ("L",), ("I;16", "I;16B", "I")


def _image(folder: Path, path: Path, shape: tuple[int, int], dtype: type, modes: tuple[str, ...]) -> np.ndarray:
    """A gray PNG of ``shape`` in one of ``modes`` (a palette or colour image is refused, never read as its indices
    or cut to a byte), inside ``folder``, read as data; ``InputError`` naming it otherwise."""
    from PIL import Image, UnidentifiedImageError

    data = read_small_file(check_inside(folder, path, "a raster"), "a PNG of a RadioMapSeer-style folder")
    try:
        with Image.open(io.BytesIO(data)) as im:
            if im.size != (shape[1], shape[0]):  # before any pixel is decoded
                raise InputError(path, f"{im.size[0]} x {im.size[1]} pixels, the grid is {shape[1]} x {shape[0]}", field="shape")
            if im.mode not in modes:
                raise InputError(path, f"PNG mode {im.mode}, expected {' or '.join(modes)} (gray, one channel)", field="mode")
            a = np.asarray(im)
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as err:
        raise InputError(path, f"not a readable PNG ({str(err)[:120]})") from None
    if a.shape != shape:
        raise InputError(path, f"{a.shape[1]} x {a.shape[0]} pixels, the grid is {shape[1]} x {shape[0]}", field="shape")
    return a.astype(dtype)


#: The bounds of a scale.json's numbers: (field, low, high), each finite.
SCALE_BOUNDS = (
    ("spacing_m", 0.01, 1000.0),
    ("x_min_m", -1e7, 1e7),
    ("y_min_m", -1e7, 1e7),
    ("floor_db", -400.0, 400.0),
    ("step_db", 1e-3, 10.0),
    ("altitude_m", 0.1, 10_000.0),
)


#: The public settings of a map folder or pack (``dataset.bundle.public_settings``): key -> (low, high, required);
#: each a finite number within its range (dataset/trainmaps.py's packs hold them too).
PUBLIC_SETTINGS: dict[str, tuple[float, float, bool]] = {
    "spacing_m": (0.01, 1000.0, True),
    "altitude_m": (0.1, 10_000.0, True),
    "floor_db": (-400.0, 400.0, True),
    "noise_dbm": (-300.0, 100.0, False),
    "tx_power_dbm": (-100.0, 100.0, False),
    "frequency_hz": (1e6, 1e12, False),
}
#: The largest SINR a map may hold [dB] (``schemas.tables.RATIO_RANGE_DB``'s, as a bundle's check).
SINR_MAX_DB = RATIO_RANGE_DB[1]


def settings_problem(settings: dict, required: tuple[str, ...] | None = None) -> str | None:
    """What is wrong with ``settings`` against ``PUBLIC_SETTINGS`` (``required``: the keys that must be there, default
    the table's), or None."""
    for key, (low, high, needed) in PUBLIC_SETTINGS.items():
        x = settings.get(key)
        if x is None and not (needed if required is None else key in required):
            continue
        if isinstance(x, bool) or not isinstance(x, int | float) or not low <= x <= high:  # NaN and inf fail too
            return f"{key} {x!r}: expected a number in [{low:g}, {high:g}]"
    return None


def check_scale(path: Path, city: str, grid: dict, shape: tuple[int, int], floor: float, step: float, altitude: float) -> None:
    """Refuse (``InputError`` naming ``path`` and the field) a scale.json whose city is not a plain name (it names
    the PNGs: never a path), whose numbers are not finite or out of ``SCALE_BOUNDS``, or whose grid is empty or
    over the ``grid_cells`` limit (checked before any raster is decoded)."""
    try:
        check_name(city, "city")
    except InputError as err:
        raise InputError(path, err.message, field="city") from None
    values = {
        "spacing_m": float(grid["spacing_m"]),
        "x_min_m": float(grid["x_min_m"]),
        "y_min_m": float(grid["y_min_m"]),
        "floor_db": floor,
        "step_db": step,
        "altitude_m": altitude,
    }
    for name, low, high in SCALE_BOUNDS:
        if not low <= values[name] <= high:  # NaN fails too
            raise InputError(path, f"{values[name]!r} is not a finite number in [{low:g}, {high:g}]", field=name)
    if min(shape) <= 0:
        raise InputError(path, f"the grid has {shape[1]} x {shape[0]} cells: it needs some", field="grid")
    check_limit("grid_cells", shape[0] * shape[1], path, "the grid's cells", field="grid")


def read_folder(folder: str | Path) -> RadioMapFolder:
    """A RadioMapSeer-style folder as data; ``InputError`` naming the file, line and field of the first problem."""
    folder = Path(folder)
    try:
        scale = json.loads(read_small_file(folder / "scale.json", "a RadioMapSeer-style folder's scale.json"))
        city, grid, sinr, settings = str(scale["city"]), dict(scale["grid"]), scale["sinr"], dict(scale["settings"])
        shape = (int(grid["num_y"]), int(grid["num_x"]))
        floor, step = float(sinr["floor_db"]), float(sinr["step_db"])
        float(grid["x_min_m"]), float(grid["y_min_m"]), float(grid["spacing_m"]), float(settings["altitude_m"])
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(
            folder / "scale.json", f"not this format's scale ({type(err).__name__}: {str(err)[:80]})", field="scale"
        ) from None
    if scale.get("format") != RADIOMAPSEER:
        raise InputError(folder / "scale.json", f"format {scale.get('format')!r}, expected {RADIOMAPSEER}", field="format")
    check_scale(folder / "scale.json", city, grid, shape, floor, step, float(settings["altitude_m"]))
    problem = settings_problem(settings, required=("altitude_m",))
    if problem is not None:
        raise InputError(folder / "scale.json", problem, field="settings")
    files = [folder / "scale.json", folder / "png/buildings_complete" / f"{city}.png", folder / "png/heights" / f"{city}.png"]
    blocked = np.flipud(_image(folder, files[1], shape, np.uint8, GRAY_8)) > 127
    ground = np.flipud(_image(folder, files[2], shape, np.int64, GRAY_16)) / 100.0
    users_csv = check_inside(folder, folder / "users.csv", "the users' table")
    files.append(users_csv)
    rows = list(csv.DictReader(io.StringIO(read_small_file(users_csv, "the users' table").decode("utf-8-sig"))))
    # each user a receiver row per cell: bounded before a raster of theirs is decoded
    check_limit("receiver_rows", len(rows) * shape[0] * shape[1], users_csv, "users x grid cells", field="user")
    ids, cells, positions, codes = [], [], [], []
    extent = {  # the grid's x and y ranges [m], which each user's position must lie in
        "x_m": (float(grid["x_min_m"]), float(grid["x_min_m"]) + shape[1] * float(grid["spacing_m"])),
        "y_m": (float(grid["y_min_m"]), float(grid["y_min_m"]) + shape[0] * float(grid["spacing_m"])),
    }
    for k, row in enumerate(rows, start=2):
        try:
            u, r, c = int(row["user"]), int(row["row"]), int(row["col"])
            x, y = float(row["x_m"]), float(row["y_m"])
        except (KeyError, TypeError, ValueError):
            raise InputError(users_csv, "user, row and col must be integers, x_m and y_m numbers", line=k, field="user") from None
        for name, v in (("x_m", x), ("y_m", y)):
            low, high = extent[name]
            if not low <= v <= high:  # NaN too
                raise InputError(users_csv, f"{v!r} is not on the grid ({low:g} .. {high:g} m)", line=k, field=name)
        if not (0 <= r < shape[0] and 0 <= c < shape[1]):
            raise InputError(users_csv, f"pixel ({r}, {c}) is off the {shape[1]} x {shape[0]} grid", line=k, field="row")
        if u in ids:
            raise InputError(users_csv, f"user {u} is listed twice", line=k, field="user")
        files.append(folder / "gain" / f"{city}_{u}.png")
        codes.append(np.flipud(_image(folder, files[-1], shape, np.uint8, GRAY_8)))
        top = floor + (int(codes[-1].max(initial=0)) - 1) * step
        if top > SINR_MAX_DB:
            raise InputError(
                files[-1], f"SINR up to {top:g} dB (floor_db + (pixel - 1) x step_db), over {SINR_MAX_DB:g} dB", field="sinr"
            )
        ids.append(u)
        cells.append((shape[0] - 1 - r, c))
        positions.append((x, y))
    if not ids:
        raise InputError(users_csv, "no user", field="user")
    return RadioMapFolder(
        city,
        str(scale.get("bundle_version", "")),
        settings,
        grid,
        floor,
        step,
        blocked,
        ground,
        ids,
        np.array(cells, np.int64),
        np.array(positions, np.float64),
        np.stack(codes),
        files,
    )


def _buildings(m: RadioMapFolder, source: str) -> list[BuildingRecord]:
    """The buildings of the height raster: per height, the union of its cells, one building each connected patch."""
    d, x0, y0 = float(m.grid["spacing_m"]), float(m.grid["x_min_m"]), float(m.grid["y_min_m"])
    records = []
    for h in np.unique(m.ground_m[m.ground_m > 0]):
        iy, ix = np.nonzero(m.ground_m == h)
        boxes = shapely.box(x0 + ix * d, y0 + iy * d, x0 + (ix + 1) * d, y0 + (iy + 1) * d)
        union = shapely.union_all(boxes)
        for poly in getattr(union, "geoms", [union]):
            records.append(BuildingRecord(None, source, None, [Part(poly, 0.0, float(h))]))
    return records


def _receivers(m: RadioMapFolder) -> pa.Table:
    """One receiver per user and cell, at the cell's centre and the altitude, its SINR (null where dead)."""
    ny, nx = m.blocked.shape
    d = float(m.grid["spacing_m"])
    iy, ix = np.divmod(np.arange(ny * nx), nx)
    x, y = float(m.grid["x_min_m"]) + (ix + 0.5) * d, float(m.grid["y_min_m"]) + (iy + 0.5) * d
    columns: dict[str, list[np.ndarray]] = {c.name: [] for c in RECEIVERS.columns}
    for point, codes in enumerate(m.codes, start=1):
        sinr, dead = decode_sinr(codes.ravel(), m.floor_db, m.step_db)
        n = len(sinr)
        given = {
            "tx_set_id": np.ones(n, np.int32),
            "tx_point": np.full(n, point, np.int32),
            "rx_set_id": np.ones(n, np.int32),
            "rx_index": np.arange(1, n + 1, dtype=np.int32),
            "x_m": x,
            "y_m": y,
            "z_m": np.full(n, float(m.settings["altitude_m"])),
            "sinr_db": np.where(dead, np.nan, sinr.astype(np.float64)),
            "reached": ~dead,
            "provenance": np.where(dead, UNREACHED, NOT_RECORDED).astype(np.uint8),
        }
        for c in RECEIVERS.columns:
            columns[c.name].append(given.get(c.name, np.full(n, np.nan)))
    arrays = {}
    for c in RECEIVERS.columns:
        v = np.concatenate(columns[c.name])
        arrays[c.name] = pa.array(v, type=c.type, from_pandas=True)  # NaN: null
    return pa.table(arrays, schema=RECEIVERS.arrow_schema())


def _transmitters(m: RadioMapFolder, source: str) -> pa.Table:
    n = len(m.user_ids)
    power, freq = m.settings.get("tx_power_dbm"), m.settings.get("frequency_hz")
    values = {
        "tx_set_id": [1] * n,
        "tx_point": list(range(1, n + 1)),
        "set_name": [f"user {u}" for u in m.user_ids],
        "x_m": m.positions_m[:, 0].tolist(),
        "y_m": m.positions_m[:, 1].tolist(),
        "z_m": [USER_HEIGHT_M] * n,
        "power_dbm": [power] * n,
        "frequency_hz": [freq] * n,
        "antenna": [None] * n,
        "source": [source] * n,
    }
    return pa.table(
        {c.name: pa.array(values[c.name], type=c.type) for c in TRANSMITTERS.columns}, schema=TRANSMITTERS.arrow_schema()
    )


def ingest_radiomapseer(
    folder: str | Path, out_dir: Path, city: str, names: tuple[str, str], command: str = ""
) -> tuple[CityManifest, IngestReport]:
    """Ingest the RadioMapSeer-style ``folder`` as the city ``city`` into ``out_dir`` (written whole or not at all):
    the tables an InSite export gives (``pipeline.ingest_city``'s), from the folder's rasters, and the manifest and
    the report under ``names`` (``pipeline``'s file names)."""
    manifest_json, report_json = names
    folder = Path(folder)
    m = read_folder(folder)
    rel = {p: str(p.relative_to(folder)) for p in m.files}
    buildings, parts, rejected = buildings_tables(_buildings(m, rel[m.files[2]]), ground_z_m=0.0)
    receivers, transmitters = _receivers(m), _transmitters(m, rel[m.files[3]])
    reached = int(np.count_nonzero(m.codes))
    codes = np.bincount(receivers.column("provenance").to_numpy(), minlength=len(RECEIVER_CODES))
    by_code = {f"receiver_rows_{code_name(c).replace(' ', '_')}": int(codes[c]) for c in RECEIVER_CODES}
    reports = tuple(FileReport(path=r, kind="radiomapseer", status="parsed") for r in rel.values())
    report = IngestReport(city=city, files=reports, rejections=tuple(rejected), warnings=())
    with atomic_directory(out_dir, marker=manifest_json, what="ingested city") as tmp:
        tables = write_tables(
            tmp, [(RECEIVERS, receivers), (TRANSMITTERS, transmitters), (BUILDINGS, buildings), (BUILDING_PARTS, parts)]
        )
        freq, power = m.settings.get("frequency_hz"), m.settings.get("tx_power_dbm")
        manifest = CityManifest(
            **made_by(city, command, folder),
            frequency_hz=freq,
            tx_power_dbm=() if power is None else (float(power),),
            counts={
                "files": len(m.files),
                "files_parsed": len(m.files),
                "files_skipped": 0,
                "files_unknown": 0,
                "transmitters": len(m.user_ids),
                "receiver_sets": 1,
                "receiver_rows": receivers.num_rows,
                "receiver_rows_reached": reached,
                **by_code,
                "buildings": buildings.num_rows,
                "building_parts": parts.num_rows,
                "terrain_triangles": 0,
                "rows_rejected": report.rows_rejected,
                "route_points": 0,
            },
            sources=tuple(
                SourceFile(path=rel[p], sha256=sha256_file(p), size_bytes=p.stat().st_size, kind="radiomapseer", status="parsed")
                for p in m.files
            ),
            tables=tables,
        )
        write_model_json(manifest, tmp / manifest_json)
        write_model_json(report, tmp / report_json)
    return manifest, report

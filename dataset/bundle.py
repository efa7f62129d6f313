"""Reading map bundles: the one way `rl/` and `eval/` get at a city.

``load_bundle("cityA")`` resolves the city's ``latest`` pointer (or a given
version), checks the schema version and the sha256 of every file against the
manifest, and returns a read-only ``Bundle``. Anything else (a missing file, a
half-written folder, a tampered array) is an ``InputError`` naming the file.
This module needs only numpy, pandas, pyarrow and the contracts.
"""

from __future__ import annotations

import functools
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from pydantic import ValidationError

from uavplace.dataset.catalog import DEFAULT_ROOT, nearest_names

#: Name of the per-city file holding the version ``load_bundle`` picks by default.
from uavplace.dataset.checks import (
    check_cells,
    check_identity,
    check_provenance,
    check_users,
    check_values,
    expected_shapes,
    read_arrays,
)
from uavplace.infra.files import array_digest, atomic_write_text, check_name, read_small_file, sha256_file
from uavplace.schemas import SCHEMA_VERSION, InputError
from uavplace.schemas.base import validation_message
from uavplace.schemas.bundle import (
    BUNDLE_FILES,
    BUNDLE_MANIFEST,
    CELLS,
    MAP_ARRAYS,
    ROUTE_ARRAYS,
    ROUTE_POINTS,
    USERS,
    BundleManifest,
)
from uavplace.schemas.provenance import CODES, code_name

LATEST = "latest"
_VERSION = re.compile(r"[0-9a-f]{12}")


@dataclass(frozen=True, eq=False)
class Bundle:
    """One city's maps at one grid and altitude. Arrays are read-only; shapes as in ``schemas.bundle.MAP_ARRAYS``."""

    path: Path
    manifest: BundleManifest
    users: pd.DataFrame
    x_m: np.ndarray  # [num_x]
    y_m: np.ndarray  # [num_y]
    height_rel_m: np.ndarray  # [num_y, num_x] float32
    blocked: np.ndarray  # [num_y, num_x] bool
    building_id: np.ndarray  # [num_y, num_x] int32
    sinr_db: np.ndarray  # [num_users, num_y, num_x] float32
    dead: np.ndarray  # [num_users, num_y, num_x] bool
    num_rx: np.ndarray  # [num_users, num_y, num_x] uint16
    provenance: np.ndarray  # [num_users, num_y, num_x] uint8: where each value came from (schemas/provenance.py)
    routes: pd.DataFrame | None = None  # ``ROUTE_POINTS``: the tracking task's route points, in route order (None: no routes)
    route_sinr_db: np.ndarray | None = None  # [num_route_points, num_y, num_x] float32
    route_dead: np.ndarray | None = None  # [num_route_points, num_y, num_x] bool
    route_provenance: np.ndarray | None = None  # [num_route_points, num_y, num_x] uint8

    @property
    def city(self) -> str:
        return self.manifest.city

    @property
    def version(self) -> str:
        return self.manifest.version

    @property
    def num_users(self) -> int:
        return self.manifest.num_users

    @functools.cached_property
    def public_digest(self) -> str:
        """The sha256 of what a UAV knows of the city before it flies: the grid's cell centres, the altitude, the
        building heights and the blocked cells, never a user's map or the bundle's version. What a policy's
        per-episode random draws are keyed by (``rl.randomness``): a rebuild that leaves these alone keeps them."""
        return array_digest(self.x_m, self.y_m, self.height_rel_m, self.blocked, extra=f"altitude {self.altitude_m!r}")

    @property
    def shape(self) -> tuple[int, int]:
        """``(num_y, num_x)``."""
        return self.manifest.grid.shape

    @property
    def spacing_m(self) -> float:
        return self.manifest.grid.spacing_m

    @property
    def altitude_m(self) -> float:
        return self.manifest.config.altitude_m

    @property
    def sinr_floor_db(self) -> float:
        return self.manifest.sinr.floor_db

    def cell_sources(self) -> dict[str, int]:
        """How many of the users' cells outside buildings (user x cell) came from where: provenance code name -> count,
        the codes present only (``schemas.provenance``)."""
        counts = np.bincount(self.provenance[:, ~self.blocked].ravel(), minlength=len(CODES))
        return {code_name(c): int(n) for c, n in enumerate(counts) if n}

    def user_cells(self, users: np.ndarray) -> np.ndarray:
        """``[U, 2]`` int64: the cell ``(iy, ix)`` of each of ``users`` (bundle user indices), in their order."""
        table = self.users.set_index("user")
        chosen = np.asarray(users, np.int64).ravel()
        return table.loc[chosen, ["iy", "ix"]].to_numpy().astype(np.int64).reshape(-1, 2)

    def user_indices(self, split: str | None = None) -> np.ndarray:
        """Bundle user indices, all or those of one split (train, val, test)."""
        if split is None:
            return self.users["user"].to_numpy()
        return self.users.loc[self.users["split"] == split, "user"].to_numpy()


def city_dir(city: str, root: str | Path = DEFAULT_ROOT) -> Path:
    return Path(root) / city


def read_latest(city: str, root: str | Path = DEFAULT_ROOT) -> str | None:
    """The version the city's ``latest`` pointer names, or None if it has no bundle yet.

    The pointer must hold one bundle version (12 hex digits), a folder of that city: anything else (a path such
    as ``../../x``, garbage) is an ``InputError`` naming the file, never followed.
    """
    path = city_dir(city, root) / LATEST
    if not path.is_file():
        return None
    try:
        text = path.read_text(encoding="utf-8").strip()
    except (UnicodeDecodeError, OSError) as exc:
        raise InputError(path, f"unreadable ({type(exc).__name__}): run `uavdata build --city {city}` again") from None
    if not text:
        return None
    if not _VERSION.fullmatch(text):
        raise InputError(
            path,
            f"{text[:40]!r} is not a bundle version (12 hex digits): run `uavdata build --city {city}` again",
            field=LATEST,
        )
    return text


def write_latest(city: str, version: str, root: str | Path = DEFAULT_ROOT) -> None:
    """Point ``latest`` at ``version`` (written to a temporary file, then renamed)."""
    atomic_write_text(city_dir(city, root) / LATEST, version + "\n")


def list_versions(city: str, root: str | Path = DEFAULT_ROOT) -> list[BundleManifest]:
    """Manifests of every bundle of a city (unchecked; oldest first). Unreadable ones are skipped by design:
    a bundle is only ever used through ``load_bundle``, which checks it."""
    out = []
    for p in city_dir(city, root).glob(f"[0-9a-f]*/{BUNDLE_MANIFEST}"):
        try:
            out.append(BundleManifest.model_validate_json(read_small_file(p, "a bundle manifest")))
        except (ValidationError, ValueError, OSError, InputError):
            continue
    return sorted(out, key=lambda m: m.created_utc)


def read_manifest(folder: Path) -> BundleManifest:
    path = folder / BUNDLE_MANIFEST
    data = read_small_file(path, "a bundle manifest", missing="no bundle manifest: not a bundle, or a build that did not finish")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(path, "not UTF-8 text: not a bundle manifest") from None
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise InputError(path, f"not JSON: {exc}") from None
    version = doc.get("schema_version") if isinstance(doc, dict) else None
    if version != SCHEMA_VERSION:
        raise InputError(
            path,
            f"bundle schema version {version!r}, this uavplace reads {SCHEMA_VERSION!r}: rebuild with `uavdata build`",
            field="schema_version",
        )
    try:
        return BundleManifest.model_validate_json(text)
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise InputError(path, message, field=field) from None


def verify_files(folder: Path, manifest: BundleManifest) -> None:
    """Check that the bundle holds exactly the files its manifest lists, with their sha256."""
    expected_files = set(BUNDLE_FILES) | ({"routes.npz", ROUTE_POINTS.filename} if manifest.num_route_points else set())
    if set(manifest.files) != expected_files:
        raise InputError(folder / BUNDLE_MANIFEST, f"lists files {sorted(manifest.files)}, expected {sorted(expected_files)}")
    for name, expected in manifest.files.items():
        path = folder / name
        if not path.is_file():
            raise InputError(path, "missing bundle file")
        actual = sha256_file(path)
        if actual != expected:
            raise InputError(
                path,
                f"sha256 {actual[:12]}... differs from the manifest's {expected[:12]}...: the file was changed after the build",
                field="sha256",
            )


def resolve(city: str, version: str | None = None, root: str | Path = DEFAULT_ROOT) -> Path:
    """Folder of a city's bundle: ``version`` or the ``latest`` one. ``city`` may be ``name@version``."""
    if "@" in city and version is None:
        city, version = city.split("@", 1)
    check_name(city, "city name")
    if version is not None:
        check_name(version, "bundle version")
    folder = city_dir(city, root)
    if version is None:
        version = read_latest(city, root)
        if version is None:
            known = sorted(p.name for p in Path(root).glob("*") if (p / LATEST).is_file()) if Path(root).is_dir() else []
            if (folder / "ingested").is_dir():
                raise InputError(folder, f"city '{city}' is ingested but not built: run `uavdata build --city {city}`")
            ingested = sorted(p.parent.name for p in Path(root).glob("*/ingested")) if Path(root).is_dir() else []
            near = nearest_names(city, sorted(set(known) | set(ingested)), "built or ingested")
            raise InputError(folder, f"no city '{city}' is built here{near}")
    path = folder / version
    if not path.is_dir():
        raise InputError(path, f"no bundle version '{version}' of city '{city}'")
    return path


def load_bundle(city: str, version: str | None = None, root: str | Path = DEFAULT_ROOT, *, verify: bool = True) -> Bundle:
    """Load a city's bundle (the latest, or ``version``), checking it before any array is used.

    ``city`` is a city name, ``name@version``, or a path to a bundle folder.
    Checked: the schema version; that the manifest is this folder's (its city and version name the folder, and its
    version is the hash of its inputs and config); the sha256 of every file (skipped with ``verify=False``); every
    array's header against the manifest's grid before it is read; every value's range; the users' table.
    """
    as_path = Path(city)
    folder = as_path if (as_path / BUNDLE_MANIFEST).is_file() else resolve(city, version, root)
    manifest = read_manifest(folder)
    check_identity(folder, manifest)
    if verify:
        verify_files(folder, manifest)
    arrays = read_arrays(folder / "maps.npz", expected_shapes(manifest), MAP_ARRAYS)
    check_values(folder / "maps.npz", manifest, arrays)
    if verify:
        check_cells(folder / CELLS.filename, arrays)
    users = _read_table(folder, USERS)
    check_users(folder / USERS.filename, manifest, users)
    routes = read_routes(folder, manifest) if manifest.num_route_points else {}
    return Bundle(path=folder, manifest=manifest, users=users, **arrays, **routes)


def _read_table(folder: Path, spec) -> pd.DataFrame:  # noqa: ANN001 - a TableSpec
    try:
        table = pq.read_table(folder / spec.filename)
    except (OSError, ValueError) as exc:
        raise InputError(folder / spec.filename, f"unreadable ({str(exc)[:160]})") from None
    return spec.conform(table, str(folder / spec.filename)).to_pandas()


def read_routes(folder: Path, manifest: BundleManifest) -> dict:
    """A bundle's routes (``routes.npz``, ``routes.parquet``), checked: the arrays' headers against the manifest
    before they are read, the SINR in range and at the floor on dead cells, the points 0..P-1 in order, each route's
    ``order`` 0, 1, ... and its times increasing, cells on the grid or -1."""
    ny, nx = manifest.grid.shape
    p = manifest.num_route_points
    path = folder / "routes.npz"
    arrays = read_arrays(path, {k: (p, ny, nx) for k in ROUTE_ARRAYS}, ROUTE_ARRAYS)
    floor = manifest.sinr.floor_db
    sinr, dead = arrays["sinr_db"], arrays["dead"]
    bad = CELLS.column("sinr_db").first_out_of_range(sinr.ravel())
    if bad is not None or (sinr < floor - 1e-3).any() or (sinr[dead] != np.float32(floor)).any():
        raise InputError(
            path, f"SINR out of range, below the manifest's floor {floor} dB, or a dead cell not at it", field="sinr_db"
        )
    check_provenance(path, arrays["provenance"], dead)
    table = _read_table(folder, ROUTE_POINTS)
    source = folder / ROUTE_POINTS.filename
    if len(table) != p or not np.array_equal(table["point"].to_numpy(), np.arange(p)):
        raise InputError(source, f"points are not 0..{p - 1} in order (the manifest says {p} route points)", field="point")
    first = np.r_[True, np.diff(table["route"].to_numpy()) != 0]
    order, time = table["order"].to_numpy(), table["time_s"].to_numpy()
    expected = np.arange(p) - np.maximum.accumulate(np.where(first, np.arange(p), 0))
    if (
        not np.array_equal(order, expected)
        or (np.diff(time)[~first[1:]] <= 0).any()
        or len(set(table["route"][first])) != first.sum()
    ):
        raise InputError(source, "routes are not each in one run of rows, ordered 0, 1, ... with increasing times", field="order")
    for name, n in (("ix", nx), ("iy", ny)):
        v = table[name].to_numpy()
        if ((v < -1) | (v >= n)).any():
            raise InputError(source, f"row {int(np.argmax((v < -1) | (v >= n)))}: cell off the grid's {n} cells", field=name)
    for a in arrays.values():
        a.setflags(write=False)
    return {"routes": table, "route_sinr_db": sinr, "route_dead": dead, "route_provenance": arrays["provenance"]}


def public_settings(bundle: Bundle) -> dict:
    """A bundle's settings that every UAV of the system knows: none is a user's position or map."""
    sinr = bundle.manifest.sinr
    freqs = bundle.users["frequency_hz"].dropna().unique()
    return {
        "city": bundle.city,
        "version": bundle.version,
        "spacing_m": bundle.spacing_m,
        "altitude_m": bundle.altitude_m,
        "noise_dbm": sinr.noise_dbm,
        "floor_db": sinr.floor_db,
        "tx_power_dbm": sinr.tx_power_dbm[0] if sinr.tx_power_dbm else None,
        "frequency_hz": float(freqs[0]) if len(freqs) else None,
    }

"""Reading map bundles: the one way `rl/` and `eval/` get at a city.

``load_bundle("cityA")`` resolves the city's ``latest`` pointer (or a given
version), checks the schema version and the sha256 of every file against the
manifest, and returns a read-only ``Bundle``. Anything else (a missing file, a
half-written folder, a tampered array) is an ``InputError`` naming the file.
This module needs only numpy, pandas, pyarrow and the contracts.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from pydantic import ValidationError

from uavplace.dataset.catalog import DEFAULT_ROOT
from uavplace.schemas import SCHEMA_VERSION, InputError
from uavplace.schemas.base import validation_message
from uavplace.schemas.bundle import BUNDLE_FILES, BUNDLE_MANIFEST, MAP_ARRAYS, USERS, BundleManifest
from uavplace.schemas.files import atomic_write_text, check_name, sha256_file

#: Name of the per-city file holding the version ``load_bundle`` picks by default.
LATEST = "latest"


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

    @property
    def city(self) -> str:
        return self.manifest.city

    @property
    def version(self) -> str:
        return self.manifest.version

    @property
    def num_users(self) -> int:
        return self.manifest.num_users

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

    def user_indices(self, split: str | None = None) -> np.ndarray:
        """Bundle user indices, all or those of one split (train, val, test)."""
        if split is None:
            return self.users["user"].to_numpy()
        return self.users.loc[self.users["split"] == split, "user"].to_numpy()


def city_dir(city: str, root: str | Path = DEFAULT_ROOT) -> Path:
    return Path(root) / city


def read_latest(city: str, root: str | Path = DEFAULT_ROOT) -> str | None:
    """The version the city's ``latest`` pointer names, or None if it has no bundle yet."""
    path = city_dir(city, root) / LATEST
    if not path.is_file():
        return None
    return path.read_text(encoding="utf-8").strip() or None


def write_latest(city: str, version: str, root: str | Path = DEFAULT_ROOT) -> None:
    """Point ``latest`` at ``version`` (written to a temporary file, then renamed)."""
    atomic_write_text(city_dir(city, root) / LATEST, version + "\n")


def list_versions(city: str, root: str | Path = DEFAULT_ROOT) -> list[BundleManifest]:
    """Manifests of every bundle of a city (unchecked; oldest first). Unreadable ones are skipped by design:
    a bundle is only ever used through ``load_bundle``, which checks it."""
    out = []
    for p in city_dir(city, root).glob(f"[0-9a-f]*/{BUNDLE_MANIFEST}"):
        try:
            out.append(BundleManifest.model_validate_json(p.read_text(encoding="utf-8")))
        except (ValidationError, ValueError, OSError):
            continue
    return sorted(out, key=lambda m: m.created_utc)


def read_manifest(folder: Path) -> BundleManifest:
    path = folder / BUNDLE_MANIFEST
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, "no bundle manifest: not a bundle, or a build that did not finish") from None
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
    if set(manifest.files) != set(BUNDLE_FILES):
        raise InputError(folder / BUNDLE_MANIFEST, f"lists files {sorted(manifest.files)}, expected {list(BUNDLE_FILES)}")
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
            raise InputError(
                folder,
                f"no bundle of city '{city}' (built cities: {', '.join(known) or 'none'}); run `uavdata build --city {city}`",
            )
    path = folder / version
    if not path.is_dir():
        raise InputError(path, f"no bundle version '{version}' of city '{city}'")
    return path


def load_bundle(city: str, version: str | None = None, root: str | Path = DEFAULT_ROOT, *, verify: bool = True) -> Bundle:
    """Load a city's bundle (the latest, or ``version``), checking schema version and file hashes.

    ``city`` is a city name, ``name@version``, or a path to a bundle folder.
    ``verify=False`` skips the sha256 check (the schema check always runs).
    """
    as_path = Path(city)
    folder = as_path if (as_path / BUNDLE_MANIFEST).is_file() else resolve(city, version, root)
    manifest = read_manifest(folder)
    if verify:
        verify_files(folder, manifest)
    try:
        with np.load(folder / "maps.npz", allow_pickle=False) as npz:
            missing = sorted(set(MAP_ARRAYS) - set(npz.files))
            if missing:
                raise InputError(folder / "maps.npz", f"missing arrays {missing}")
            arrays = {k: npz[k] for k in MAP_ARRAYS}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:  # garbage, a pickle, a truncated archive
        raise InputError(folder / "maps.npz", f"not a readable map archive ({type(exc).__name__}: {str(exc)[:160]})") from None
    ny, nx = manifest.grid.shape
    expected = {"x_m": (nx,), "y_m": (ny,), "height_rel_m": (ny, nx), "blocked": (ny, nx), "building_id": (ny, nx)}
    expected |= {k: (manifest.num_users, ny, nx) for k in ("sinr_db", "dead", "num_rx")}
    for name, shape in expected.items():
        a = arrays[name]
        if a.shape != shape or a.dtype != np.dtype(MAP_ARRAYS[name][0]):
            raise InputError(
                folder / "maps.npz", f"array {a.dtype}{list(a.shape)}, expected {MAP_ARRAYS[name][0]}{list(shape)}", field=name
            )
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            bad = np.argwhere(~np.isfinite(a))[0].tolist()
            raise InputError(folder / "maps.npz", f"value {a[tuple(bad)]} at {bad} is not finite", field=name)
        a.setflags(write=False)
    try:
        users = pq.read_table(folder / USERS.filename).to_pandas()
    except (OSError, ValueError) as exc:
        raise InputError(folder / USERS.filename, f"unreadable ({str(exc)[:160]})") from None
    if len(users) != manifest.num_users:
        raise InputError(folder / USERS.filename, f"{len(users)} users, manifest says {manifest.num_users}")
    return Bundle(path=folder, manifest=manifest, users=users, **arrays)

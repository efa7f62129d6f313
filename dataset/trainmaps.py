"""Training maps: a bundle's maps in the compact form kept in git (``data/trainmaps/<city>.npz``).

The learned radio-map predictor trains on many ray-traced users (``uavrl train-predictor --maps``). Their bundles are
large (float32 SINR, the receivers table); what the predictor reads of them is small: the building heights, the
cells the UAV may not enter, the users' cells, each user's SINR and dead cells, and where each value came from. A
*pack* keeps exactly that, quantised, in one ``.npz`` of LZMA-compressed members (about 7 kB a user of a 100 x 100 grid):

- ``height_dm`` [ny, nx] int16: building height minus the UAV altitude, in decimetres (the bundle's ``height_rel_m``
  to 0.05 m);
- ``blocked`` [ny, nx] uint8 (0 or 1);
- ``users`` [U, 2] int16: each user's cell ``(iy, ix)``;
- ``sinr`` [U, ny, nx] uint8: 0 a dead cell, else ``q``: the SINR ``floor + (q - 1) * step_db`` (rounded to the
  nearest ``step_db``, at most ``floor + 254 * step_db``);
- ``provenance`` [U, ny, nx] uint8: the bundle's provenance codes (``schemas/provenance.py``);
- ``meta``: the JSON of ``PackMeta`` as bytes: the format, the city, the bundle it came from, the public settings,
  the step, the simulation that traced it (seed and settings, from its ``simulation.json``) and the sha256 of every
  array above.

``read_pack`` checks a pack before any array is used (its size, its members' sizes, the format, every array's shape,
dtype and sha256, the codes) and returns ``TrainingMaps``, the form the predictor's trainer reads, which
``TrainingMaps.of_bundle`` also makes from a bundle.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from collections.abc import Iterable
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path

import numpy as np
from pydantic import Field, ValidationError, field_validator

from uavplace.dataset.bundle import Bundle, public_settings
from uavplace.infra.files import ARCHIVE_ERRORS, atomic_write_bytes, check_inside, check_own_npz, read_small_file
from uavplace.infra.limits import limits
from uavplace.ingest.radiomapseer import decode_sinr as dequantise  # the codes of packs and RadioMapSeer folders
from uavplace.ingest.radiomapseer import settings_problem
from uavplace.schemas import InputError
from uavplace.schemas.base import Contract, validation_message
from uavplace.schemas.provenance import CODES

#: The pack format this module writes and reads.
FORMAT = "uavplace-training-maps/1"
#: The quantisation step of the packed SINR [dB].
STEP_DB = 0.5
#: The arrays of a pack, in order, with their dtypes.
ARRAYS = {"height_dm": np.int16, "blocked": np.uint8, "users": np.int16, "sinr": np.uint8, "provenance": np.uint8}


class PackMeta(Contract):
    """A pack's ``meta``: what it holds and where it came from."""

    format: str = Field(pattern=r"^uavplace-training-maps/1$")
    city: str = Field(min_length=1, max_length=200)
    bundle_version: str = Field(pattern=r"^[0-9a-f]{12}$", description="The bundle it was packed from")
    settings: dict = Field(description="The bundle's public settings (dataset.bundle.public_settings)")
    step_db: float = Field(gt=0, le=10, description="SINR quantisation step [dB]")
    shape: tuple[int, int] = Field(description="(num_y, num_x)")
    num_users: int = Field(ge=1)
    clipped_cells: int = Field(ge=0, description="Live cells whose SINR was above the largest packed value")
    simulation: dict = Field(default_factory=dict, description="The spec and ray-trace settings of its simulation.json")
    sha256: dict[str, str] = Field(description="Array name -> sha256 of its C-ordered bytes")

    @field_validator("step_db")
    @classmethod
    def _the_formats_step(cls, v: float) -> float:
        if v != STEP_DB:
            raise ValueError(f"{v:g} dB: this format's step is {STEP_DB:g} dB")
        return v

    @field_validator("settings")
    @classmethod
    def _settings_in_range(cls, v: dict) -> dict:
        problem = settings_problem(v)  # ingest.radiomapseer.PUBLIC_SETTINGS
        if problem is not None:
            raise ValueError(problem)
        return v


@dataclass(frozen=True)
class TrainingMaps:
    """The maps the predictor trains on, from a bundle or a pack: ``settings`` (the public settings), ``height_rel_m``
    [ny, nx] float32, ``blocked`` [ny, nx] bool, ``users`` [U, 2] int64 cells ``(iy, ix)``, ``sinr_db`` [U, ny, nx]
    float32 (the floor on dead cells), ``dead`` [U, ny, nx] bool, ``provenance`` [U, ny, nx] uint8."""

    city: str
    version: str
    settings: dict
    height_rel_m: np.ndarray
    blocked: np.ndarray
    users: np.ndarray
    sinr_db: np.ndarray
    dead: np.ndarray
    provenance: np.ndarray

    @property
    def floor_db(self) -> float:
        return float(self.settings["floor_db"])

    @classmethod
    def of_bundle(cls, bundle: Bundle, users: np.ndarray | None = None) -> TrainingMaps:
        """``users`` (bundle user indices; default all) of ``bundle``."""
        chosen = bundle.user_indices() if users is None else np.asarray(users, np.int64)
        cells = bundle.user_cells(chosen)
        return cls(
            bundle.city,
            bundle.version,
            public_settings(bundle),
            bundle.height_rel_m,
            bundle.blocked,
            cells,
            bundle.sinr_db[chosen],
            bundle.dead[chosen],
            bundle.provenance[chosen],
        )


def _digest(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


def quantise(sinr_db: np.ndarray, dead: np.ndarray, floor_db: float, step_db: float = STEP_DB) -> tuple[np.ndarray, int]:
    """(``sinr`` uint8 codes as the module says, live cells clipped at the top)."""
    q = np.rint((sinr_db.astype(np.float64) - floor_db) / step_db) + 1
    clipped = int(((q > 255) & ~dead).sum())
    q = np.clip(q, 1, 255).astype(np.uint8)
    q[dead] = 0
    return q, clipped


def pack_bytes(maps: TrainingMaps, simulation: dict | None = None, step_db: float = STEP_DB) -> tuple[bytes, PackMeta]:
    """The ``.npz`` bytes of ``maps`` packed (the module's format) and its meta."""
    height_dm = np.rint(np.asarray(maps.height_rel_m, np.float64) * 10)
    if np.abs(height_dm).max(initial=0) > np.iinfo(np.int16).max:
        raise ValueError(f"{maps.city}: a building height beyond +-3276 m does not fit a pack")
    sinr, clipped = quantise(maps.sinr_db, maps.dead, maps.floor_db, step_db)
    arrays = {
        "height_dm": height_dm.astype(np.int16),
        "blocked": np.asarray(maps.blocked, np.uint8),
        "users": np.asarray(maps.users, np.int16),
        "sinr": sinr,
        "provenance": np.asarray(maps.provenance, np.uint8),
    }
    meta = PackMeta(
        format=FORMAT,
        city=maps.city,
        bundle_version=maps.version,
        settings=maps.settings,
        step_db=step_db,
        shape=tuple(maps.blocked.shape),
        num_users=len(maps.users),
        clipped_cells=clipped,
        simulation=simulation or {},
        sha256={k: _digest(a) for k, a in arrays.items()},
    )
    buf = io.BytesIO()
    members = {"meta": np.frombuffer(meta.model_dump_json().encode(), np.uint8), **arrays}
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_LZMA) as z:  # an .npz numpy reads; LZMA: ~20 % smaller
        for name, a in members.items():
            with z.open(f"{name}.npy", "w") as f:
                np.lib.format.write_array(f, a, allow_pickle=False)
    return buf.getvalue(), meta


def write_pack(path: str | Path, maps: TrainingMaps, simulation: dict | None = None) -> PackMeta:
    """Pack ``maps`` into ``path`` (written to a temporary file, then renamed; a regular file or absent)."""
    check_own_npz(path, "uavplace-training-maps/", "training-maps pack")
    data, meta = pack_bytes(maps, simulation)
    atomic_write_bytes(path, data)
    return meta


def read_pack(path: str | Path) -> TrainingMaps:
    """The maps of the pack at ``path``, checked (the module's docstring); ``InputError`` naming the file and the
    field at the first problem."""
    path = Path(path)
    what = "a training-maps pack (`uavdata pack` writes them)"
    data = read_small_file(path, what)
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            inflated = sum(i.file_size for i in z.infolist())
            bound = limits().map_bytes
            if inflated > bound:
                raise InputError(path, f"inflates to {inflated:,} bytes, over the limit map_bytes {bound:,}")
            with np.load(io.BytesIO(data), allow_pickle=False) as npz:
                arrays = {name: npz[name] for name in ("meta", *ARRAYS)}
    except InputError:
        raise
    except KeyError as err:
        raise InputError(path, f"no array {err}: not {what}", field=str(err).strip("'")) from None
    except ARCHIVE_ERRORS as err:
        raise InputError(path, f"unreadable ({str(err)[:160]}): not {what}") from None
    try:
        meta = PackMeta.model_validate_json(arrays.pop("meta").tobytes())
    except (ValidationError, ValueError) as err:
        message = validation_message(err) if isinstance(err, ValidationError) else str(err)[:160]
        raise InputError(path, f"meta: {message}", field="meta") from None
    ny, nx = meta.shape
    u = meta.num_users
    shapes = {"height_dm": (ny, nx), "blocked": (ny, nx), "users": (u, 2), "sinr": (u, ny, nx), "provenance": (u, ny, nx)}
    for name, dtype in ARRAYS.items():
        a = arrays[name]
        if a.dtype != dtype or a.shape != shapes[name]:
            raise InputError(path, f"{a.dtype}{list(a.shape)}, expected {np.dtype(dtype)}{list(shapes[name])}", field=name)
        if _digest(a) != meta.sha256.get(name):
            raise InputError(path, "sha256 differs from the one meta records: the pack is damaged", field=name)
    users = arrays["users"].astype(np.int64)
    if (users < 0).any() or (users[:, 0] >= ny).any() or (users[:, 1] >= nx).any():
        raise InputError(path, "a user's cell is off the grid", field="users")
    if arrays["blocked"].max(initial=0) > 1 or arrays["provenance"].max(initial=0) >= len(CODES):
        bad = "blocked" if arrays["blocked"].max(initial=0) > 1 else "provenance"
        raise InputError(path, "a value that is not a code of the format", field=bad)
    try:
        floor = float(meta.settings["floor_db"])
    except (KeyError, TypeError, ValueError):
        raise InputError(path, "settings hold no floor_db", field="meta") from None
    sinr, dead = dequantise(arrays["sinr"], floor, meta.step_db)
    return TrainingMaps(
        meta.city,
        meta.bundle_version,
        dict(meta.settings),
        arrays["height_dm"].astype(np.float32) / 10,
        arrays["blocked"].astype(bool),
        users,
        sinr,
        dead,
        arrays["provenance"],
    )


def list_packs(folder: str | Path) -> list[Path]:
    """The packs (``*.npz``) of ``folder``, by name; ``InputError`` when it is not a folder, holds none, or holds a
    link (a pack is read from the folder itself, never through a link out of it)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "not a folder of training-maps packs (`uavdata pack` writes them)")
    packs = sorted(check_inside(folder, p, "a pack") for p in folder.glob("*.npz") if p.is_file() or p.is_symlink())
    if not packs:
        raise InputError(folder, "holds no training-maps pack (*.npz)")
    return packs


def select_packs(folders: Iterable[str | Path], patterns: Iterable[str] = ()) -> list[Path]:
    """The packs of ``folders`` (``list_packs``) whose city's name matches one of ``patterns``, shell-style and whole
    (``tt-*``, ``tt-00[0-4]``, a city's name), or every pack without a pattern. A pattern names its packs for good: a
    pack added later is selected by ``tt-*`` and not by ``tt-00[0-4]``."""
    patterns = tuple(patterns)
    found = [p for f in folders for p in list_packs(f) if not patterns or any(fnmatchcase(p.stem, q) for q in patterns)]
    once: dict[Path, Path] = {}  # a folder given twice: each pack once, where it first came
    for p in found:
        once.setdefault(p.resolve(), p)
    return list(once.values())


def simulation_record(raw_folder: str | Path) -> dict:
    """The spec and ray-trace settings of ``raw_folder/simulation.json`` (empty when there is none)."""
    path = Path(raw_folder) / "simulation.json"
    if not path.is_file() and not path.is_symlink():
        return {}
    check_inside(raw_folder, path, "a simulation record")  # a link out of the city folder is not copied into a pack
    try:
        record = json.loads(read_small_file(path, "a simulation record"))
    except ValueError:
        raise InputError(path, "not JSON: a simulation record") from None
    if not isinstance(record, dict):
        raise InputError(path, "not a JSON object: a simulation record")
    return {k: record[k] for k in ("spec", "raytrace", "geometry", "packages") if k in record}

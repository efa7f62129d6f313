"""What ``load_bundle`` checks of a bundle it reads (``dataset.bundle``): its identity against its folder, every
array's shape, type and values against its manifest, the provenance codes against the dead cells, the cells' and
users' tables; a bundle that fails any is refused, naming the file and field."""

from __future__ import annotations

import hashlib
import json
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from uavplace.dataset.raster import cell_index
from uavplace.infra.limits import check_limit
from uavplace.schemas import SCHEMA_VERSION, InputError
from uavplace.schemas.bundle import (
    BUNDLE_MANIFEST,
    CELLS,
    BuildConfig,
    BundleManifest,
)
from uavplace.schemas.provenance import CODES, DEAD, NEAREST_RECEIVER, NO_RECEIVER, code_name

#: Name of the per-city file holding the version ``load_bundle`` picks by default.


def bundle_version(inputs: dict[str, str], config: BuildConfig) -> str:
    """12 hex digits of sha256 over the input hashes, the config and the schema version."""
    doc = {"schema_version": SCHEMA_VERSION, "inputs": inputs, "config": config.model_dump(mode="json")}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]


def check_cells(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """``InputError`` naming ``cells.parquet``'s first row that disagrees with ``maps.npz`` (the two copies of one
    bundle's maps: SINR, dead, provenance, blocked and height at each user and cell), or that is missing or out of the grid."""
    columns = ["user", "iy", "ix", "sinr_db", "dead", "provenance", "blocked", "height_rel_m"]
    try:
        table = pq.read_table(path, columns=columns)
    except (OSError, ValueError, pa.ArrowException) as exc:
        raise InputError(path, f"unreadable ({str(exc)[:160]})") from None
    users, ny, nx = arrays["sinr_db"].shape
    if table.num_rows != users * ny * nx:
        raise InputError(path, f"{table.num_rows} rows, maps.npz holds {users} users x {ny} x {nx} cells", field="rows")
    user, iy, ix = (table.column(c).to_numpy().astype(np.int64) for c in ("user", "iy", "ix"))
    outside = (user < 0) | (user >= users) | (iy < 0) | (iy >= ny) | (ix < 0) | (ix >= nx)
    refuse_first(outside, path, "user", lambda k: f"row {k}: user {user[k]}, cell ({iy[k]}, {ix[k]}) is not in maps.npz")
    expected = {
        "sinr_db": arrays["sinr_db"][user, iy, ix],
        "dead": arrays["dead"][user, iy, ix],
        "provenance": arrays["provenance"][user, iy, ix],
        "blocked": arrays["blocked"][iy, ix],
        "height_rel_m": arrays["height_rel_m"][iy, ix],
    }
    for name, want in expected.items():
        got = table.column(name).to_numpy(zero_copy_only=False)
        refuse_first(
            got != want,
            path,
            name,
            lambda k, got=got, want=want: (
                f"row {k} (user {user[k]}, cell ({iy[k]}, {ix[k]})): {got[k]}, but maps.npz "
                f"holds {want[k]}: the bundle's two copies disagree; rebuild it (`uavdata build --force`)"
            ),
        )


def refuse_first(bad: np.ndarray, path: Path | None, field: str, message: Callable[[int], str]) -> None:
    """Refuse at the first true row of ``bad`` (``message(row)`` says what is wrong there); nothing when none is."""
    if bad.any():
        raise InputError(path, message(int(np.argmax(bad))), field=field)


def check_identity(folder: Path, manifest: BundleManifest) -> None:
    """Refuse a manifest that is not this folder's: a renamed city or version, or a version that is not the hash of
    the manifest's own inputs and config (an edited manifest). A city's identity is what a test-city refusal rests on."""
    path = folder / BUNDLE_MANIFEST
    if manifest.version != folder.name:
        raise InputError(path, f"version {manifest.version} is not its folder's name {folder.name!r}", field="version")
    if manifest.city != folder.resolve().parent.name:
        raise InputError(
            path, f"city {manifest.city!r} is not its folder's {folder.resolve().parent.name!r}: a renamed bundle", field="city"
        )
    expected = bundle_version(manifest.inputs, manifest.config)
    if expected != manifest.version:
        raise InputError(
            path,
            f"version {manifest.version} is not the hash of its inputs and config ({expected}): the manifest was "
            "edited after the build",
            field="version",
        )


def expected_shapes(manifest: BundleManifest) -> dict[str, tuple[int, ...]]:
    """Every array of ``maps.npz`` and the shape the manifest gives it."""
    ny, nx = manifest.grid.shape
    shapes = {"x_m": (nx,), "y_m": (ny,), "height_rel_m": (ny, nx), "blocked": (ny, nx), "building_id": (ny, nx)}
    return shapes | {k: (manifest.num_users, ny, nx) for k in ("sinr_db", "dead", "num_rx", "provenance")}


def read_arrays(path: Path, shapes: dict[str, tuple[int, ...]], dtypes: dict[str, tuple[str, str]]) -> dict[str, np.ndarray]:
    """The arrays ``shapes`` names in an archive (``maps.npz``, ``routes.npz``), each header (shape, dtype: ``dtypes``)
    checked before its data is read, so a header that claims terabytes is refused, not allocated."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            missing = sorted(k for k in shapes if f"{k}.npy" not in names)
            if missing:
                raise InputError(path, f"missing arrays {missing}")
            arrays = {}
            for name, shape in shapes.items():
                dtype = np.dtype(dtypes[name][0])
                with zf.open(f"{name}.npy") as f:
                    major, minor = np.lib.format.read_magic(f)
                    reader = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
                    got_shape, fortran, got_dtype = reader(f)
                    if got_shape != shape or got_dtype != dtype or fortran:
                        raise InputError(
                            path,
                            f"array {got_dtype}{list(got_shape)}{' (Fortran order)' if fortran else ''}, expected "
                            f"{dtype}{list(shape)}",
                            field=name,
                        )
                    check_limit("array_bytes", dtype.itemsize * int(np.prod(shape)), path, "array size [bytes]", field=name)
                    f.seek(0)
                    arrays[name] = np.lib.format.read_array(f, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, NotImplementedError, RuntimeError) as exc:
        # garbage, a pickle, a truncated archive; zipfile's NotImplementedError (a compression or version it lacks) and
        # RuntimeError (an encrypted member)
        raise InputError(path, f"not a readable map archive ({type(exc).__name__}: {str(exc)[:160]})") from None
    return arrays


def check_values(path: Path, manifest: BundleManifest, arrays: dict[str, np.ndarray]) -> None:
    """Every map value physical and consistent: the cell centres on the manifest's grid, heights and SINR in their
    columns' ranges (``CELLS``), SINR at or above the floor and equal to it on dead cells, building ids from -1 to the buildings' count, at
    least one open cell. The arrays are made read-only."""
    grid = manifest.grid
    for name, lo, n in (("x_m", grid.x_min_m, grid.num_x), ("y_m", grid.y_min_m, grid.num_y)):
        centres = lo + (np.arange(n) + 0.5) * grid.spacing_m
        off = ~np.isclose(arrays[name], centres, rtol=0, atol=1e-6 * grid.spacing_m + 1e-9)
        refuse_first(off, path, name, lambda k, name=name: f"cell centre {arrays[name][k]} at {k} is off the manifest's grid")
    floor = manifest.sinr.floor_db
    for name in ("height_rel_m", "sinr_db"):
        column = CELLS.column(name)
        bad = column.first_out_of_range(arrays[name].ravel())
        if bad is not None:
            where = list(map(int, np.unravel_index(bad, arrays[name].shape)))
            value = arrays[name].flat[bad]
            what = "is not finite" if not np.isfinite(value) else f"is outside {column.range_text()}"
            raise InputError(path, f"value {float(value):g} at {where} {what}", field=name)
    sinr, dead = arrays["sinr_db"], arrays["dead"]
    if (sinr < floor - 1e-3).any() or (sinr[dead] != np.float32(floor)).any():
        raise InputError(path, f"SINR below the manifest's floor {floor} dB, or a dead cell not at it", field="sinr_db")
    check_provenance(path, arrays["provenance"], dead, arrays["num_rx"])
    buildings = manifest.counts.get("buildings")
    ids = arrays["building_id"]
    if (ids < -1).any() or (buildings is not None and (ids >= buildings).any()):
        raise InputError(
            path,
            f"building id outside -1 .. {buildings - 1 if buildings is not None else 'n'} (the manifest's {buildings} buildings)",
            field="building_id",
        )
    if arrays["blocked"].all():
        raise InputError(path, "every cell is blocked: the UAV has nowhere to fly", field="blocked")
    for a in arrays.values():
        a.setflags(write=False)


def check_provenance(path: Path, provenance: np.ndarray, dead: np.ndarray, num_rx: np.ndarray | None = None) -> None:
    """``InputError`` naming the first cell whose provenance code disagrees with the maps: not a code
    (``schemas.provenance.CODES``), a dead code (unreached, no receiver) on a live cell or a live code on a dead one,
    and, given ``num_rx``, a no-receiver code (no receiver, nearest receiver) on a cell with receivers or the reverse."""
    wrong = (provenance > max(CODES)) | (np.isin(provenance, DEAD) != dead)
    if num_rx is not None:
        wrong |= np.isin(provenance, (NO_RECEIVER, NEAREST_RECEIVER)) != (num_rx == 0)
    if wrong.any():
        where = tuple(int(i) for i in np.unravel_index(int(np.argmax(wrong)), wrong.shape))
        code = int(provenance[where])
        if code not in CODES:
            raise InputError(
                path,
                f"cell {list(where)}: {code} is not a provenance code (0 .. {max(CODES)}: schemas/provenance.py)",
                field="provenance",
            )
        raise InputError(
            path,
            f"cell {list(where)}: code {code} ({code_name(code)}) but the cell is "
            f"{'dead' if dead[where] else 'live'}"
            + ("" if num_rx is None else f" with {num_rx[where]} receiver(s)")
            + ": the provenance disagrees with the maps",
            field="provenance",
        )


def check_users(path: Path, manifest: BundleManifest, users: pd.DataFrame) -> None:
    """The users' table matches the maps: one row per map, ``user`` 0..n-1 in order, cells on the grid or -1."""
    if len(users) != manifest.num_users:
        raise InputError(path, f"{len(users)} users, manifest says {manifest.num_users}")
    if not np.array_equal(users["user"].to_numpy(), np.arange(len(users))):
        raise InputError(path, f"user ids are not 0..{len(users) - 1} in order", field="user")
    ny, nx = manifest.grid.shape
    for name, n in (("ix", nx), ("iy", ny)):
        v = users[name].to_numpy()
        refuse_first((v < -1) | (v >= n), path, name, lambda k, v=v, n=n: f"row {k}: cell {v[k]} is off the grid's {n} cells")
    # a position is in its cell (-1 outside the grid); an unknown (null) position has no cell
    x, y = (users[c].to_numpy(dtype=np.float64, na_value=np.nan) for c in ("x_m", "y_m"))
    expect_x, expect_y, _ = cell_index(manifest.grid, x, y)  # as the build placed them (NaN: outside, -1)
    wrong = (users["ix"].to_numpy() != expect_x) | (users["iy"].to_numpy() != expect_y)
    refuse_first(
        wrong,
        path,
        "x_m",
        lambda k: (
            f"row {k}: position ({x[k]:g}, {y[k]:g}) m is not in its cell ({users['ix'].iloc[k]}, "
            f"{users['iy'].iloc[k]}) of the grid"
        ),
    )
    splits = set(users["split"].dropna())
    if not splits <= {"train", "val", "test"}:
        raise InputError(path, f"unknown splits {sorted(splits - {'train', 'val', 'test'})}", field="split")

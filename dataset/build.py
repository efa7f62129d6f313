"""`uavdata build`: turn an ingested city into a versioned map bundle.

The recipe, per city:

1. read the ingested tables and check them against their manifest hashes;
2. version = hash(input hashes, build config, schema version): an existing
   valid bundle of that version means there is nothing to do;
3. take the receivers at the UAV altitude (height above the terrain under
   them), find the users (transmitters with receivers there) and the grid;
4. per user, received power (or the export's SINR) averaged in the linear
   domain over the receivers that fall into each cell, then SINR against
   noise plus interference, a floor for dead and very weak cells;
5. the building height map; blocked cells;
6. write maps.npz, cells.parquet, users.parquet, manifest.json into a
   temporary folder, rename it into place, move ``latest``.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from uavplace.dataset.bundle import load_bundle, read_latest, write_latest
from uavplace.dataset.catalog import DEFAULT_ROOT
from uavplace.dataset.checks import bundle_version, refuse_first
from uavplace.dataset.difficulty import difficulty
from uavplace.dataset.ingested import Ingested, read_ingested, split_routes
from uavplace.dataset.raster import cell_centres, cell_index, height_map
from uavplace.dataset.receivers import check_coverage, columns_of, export_lattice, grid_of, receivers_at_altitude
from uavplace.infra.files import atomic_directory, sha256_file, write_model_json
from uavplace.schemas import InputError
from uavplace.schemas.base import uavplace_version
from uavplace.schemas.bundle import (
    BUNDLE_MANIFEST,
    CELLS,
    ROUTE_ARRAYS,
    ROUTE_POINTS,
    USERS,
    BuildConfig,
    BundleManifest,
    GridSpec,
    SinrInfo,
    SinrSource,
)
from uavplace.schemas.provenance import CODES, NEAREST_RECEIVER, NO_RECEIVER, TRUST, UNREACHED, code_name
from uavplace.schemas.tables import BUILDINGS, RECEIVERS, ROUTES, TRANSMITTERS

#: Each receiver code's place in ``TRUST`` (-1: not a live code): a cell takes its least trusted reached receiver's.
TRUST_RANK = np.array([TRUST.index(c) if c in TRUST else -1 for c in range(max(CODES) + 1)])
#: Order in which export quantities are used to make SINR.
_SINR_SOURCES: tuple[tuple[SinrSource, str], ...] = (
    ("export_sinr", "sinr_db"),
    ("power", "power_dbm"),
    ("path_gain", "path_gain_db"),
    ("path_loss", "path_loss_db"),
)


@dataclass(frozen=True)
class BuildResult:
    city: str
    path: Path
    manifest: BundleManifest
    built: bool  # False: an identical bundle existed (nothing was written)
    previous_latest: str | None = None  # the version ``latest`` named before, when this build moved it


def _sinr_source(ing: Ingested, rx: pd.DataFrame) -> tuple[SinrSource, str]:
    reached = rx["reached"].fillna(True).to_numpy(bool)
    for source, column in _SINR_SOURCES:
        values = rx[column].to_numpy(dtype=float, na_value=np.nan)
        if reached.any() and not np.isnan(values[reached]).any():
            return source, column
    present = [c for _, c in _SINR_SOURCES if rx[c].notna().any()]
    raise InputError(
        ing.folder / RECEIVERS.filename,
        "no quantity to make SINR from on every reached receiver (need sinr, power, path gain or path loss);"
        f" partly present: {present or 'none'}",
        field="power_dbm",
    )


def _tx_power(ing: Ingested, users: pd.DataFrame, config: BuildConfig, source: SinrSource) -> tuple[np.ndarray, np.ndarray]:
    """(power used [dBm], shift applied to exported received power [dB]) per user."""
    export = users["power_dbm"].to_numpy(dtype=float, na_value=np.nan)
    if config.tx_dbm is not None:
        if source in ("power", "export_sinr") and np.isnan(export).any():
            raise InputError(
                ing.folder / TRANSMITTERS.filename,
                "--tx-dbm rescales exported received power, but the export's transmit power is unknown for some users",
                field="power_dbm",
            )
        used = np.full(len(users), config.tx_dbm)
        return used, (used - export if source in ("power", "export_sinr") else np.zeros(len(users)))
    if source in ("path_gain", "path_loss") and np.isnan(export).any():
        i = int(np.flatnonzero(np.isnan(export))[0])
        u = users.iloc[i]
        raise InputError(
            ing.folder / TRANSMITTERS.filename,
            f"user t{u.tx_point:03d}_{u.tx_set_id:02d} has no transmit power in the .txrx and the export gives only"
            " path loss/gain: pass --tx-dbm",
            field="power_dbm",
        )
    return export, np.zeros(len(users))


def rasterise(
    ing: Ingested, config: BuildConfig
) -> tuple[GridSpec, dict[str, np.ndarray], pd.DataFrame, SinrInfo, dict[str, int], list[str]]:
    """The arrays of a bundle (see ``schemas.bundle.MAP_ARRAYS``), its users table, SINR info, counts, warnings."""
    warnings: list[str] = []
    rx = receivers_at_altitude(ing, config)
    tx = ing.transmitters.set_index(["tx_set_id", "tx_point"])
    keys = sorted(set(zip(rx["tx_set_id"].astype(int), rx["tx_point"].astype(int), strict=True)))
    users = pd.DataFrame(keys, columns=["tx_set_id", "tx_point"])
    users = users.join(tx, on=["tx_set_id", "tx_point"])
    without = len(tx) - len(set(keys) & set(tx.index))
    if without:
        warnings.append(f"{without} transmitter(s) have no receivers at the altitude and are not users of the bundle")
    export_spacing = export_lattice(ing, rx)
    grid = grid_of(ing, rx, config, export_spacing, len(users))
    check_coverage(ing, rx, tol_m=max(export_spacing or 0.0, config.grid_m) / 2 + 1e-6)

    source, column = _sinr_source(ing, rx)
    tx_used, shift = _tx_power(ing, users, config, source)
    user_of = pd.Series(np.arange(len(users)), index=pd.MultiIndex.from_frame(users[["tx_set_id", "tx_point"]]))
    u = user_of.loc[list(zip(rx["tx_set_id"], rx["tx_point"], strict=True))].to_numpy()
    ix, iy, inside = cell_index(grid, rx["x_m"].to_numpy(), rx["y_m"].to_numpy())
    outside = int((~inside).sum())
    if outside == len(rx):
        raise InputError(ing.folder / RECEIVERS.filename, "no receiver at the altitude lies inside the grid bounds (empty map)")
    if outside:
        warnings.append(f"{outside} receiver(s) at the altitude lie outside the grid bounds and are not used")

    # Received power [dBm] (or exported SINR [dB]) per receiver; unreached receivers contribute 0 mW.
    value = rx[column].to_numpy(dtype=float, na_value=np.nan)
    if source == "path_gain":
        value = tx_used[u] + value
    elif source == "path_loss":
        value = tx_used[u] - value
    else:
        value = value + shift[u]
    reached = rx["reached"].fillna(True).to_numpy(bool) & ~np.isnan(value)
    lin = np.where(reached, 10.0 ** (np.where(reached, value, 0.0) / 10.0), 0.0)

    ny, nx = grid.shape
    flat = (u * ny + iy) * nx + ix
    flat, lin, reached = flat[inside], lin[inside], reached[inside]
    size = len(users) * ny * nx
    num_rx = np.bincount(flat, minlength=size).reshape(len(users), ny, nx)
    num_reached = np.bincount(flat, weights=reached, minlength=size).reshape(len(users), ny, nx)
    mean_mw = np.bincount(flat, weights=lin, minlength=size).reshape(len(users), ny, nx) / np.maximum(num_rx, 1)
    # The cell's provenance: the least trusted of its reached receivers' (schemas.provenance.TRUST)
    rank = np.full(size, -1)
    np.maximum.at(rank, flat[reached], TRUST_RANK[rx["provenance"].to_numpy(np.int64)[inside][reached]])
    rank = rank.reshape(len(users), ny, nx)

    if export_spacing is not None and export_spacing > config.grid_m * (1 + 1e-6):
        # Export coarser than the grid: cells between receivers take their nearest sampled cell.
        from scipy import ndimage

        reach = export_spacing / config.grid_m
        for k in range(len(users)):
            dist, (jy, jx) = ndimage.distance_transform_edt(num_rx[k] == 0, return_indices=True)
            fill = (num_rx[k] == 0) & (dist <= reach)
            mean_mw[k][fill] = mean_mw[k][jy[fill], jx[fill]]
            num_reached[k][fill] = num_reached[k][jy[fill], jx[fill]]
        warnings.append(f"export spacing {export_spacing:g} m is coarser than the grid: cells filled from the nearest receiver")
    dead = num_reached == 0
    provenance = np.select(
        [(num_rx == 0) & dead, num_rx == 0, dead],
        [NO_RECEIVER, NEAREST_RECEIVER, UNREACHED],
        np.array(TRUST)[np.maximum(rank, 0)],
    ).astype(np.uint8)

    rng = np.random.default_rng(config.seed)
    with np.errstate(divide="ignore"):
        level_db = 10.0 * np.log10(mean_mw)  # [num_users, ny, nx] dBm, or dB for exported SINR
    if source == "export_sinr":
        sinr = level_db
        if config.interference_std_db > 0:
            warnings.append("the export carries SINR: --noise-dbm and --interference-std-db are not applied")
    else:
        offset = rng.normal(0.0, config.interference_std_db, size=(ny, nx)) if config.interference_std_db > 0 else 0.0
        sinr = level_db - (config.noise_dbm + offset)
    clipped = int(((sinr < config.sinr_floor_db) & ~dead).sum())
    sinr = np.where(dead, config.sinr_floor_db, np.maximum(sinr, config.sinr_floor_db)).astype(np.float32)

    hm = height_map(grid, ing.buildings, ing.parts)
    if len(hm.outside):
        names = ing.buildings.set_index("building_id").loc[hm.outside, "name"].fillna("?").tolist()
        msg = (
            f"{len(hm.outside)} building(s) lie wholly outside the grid "
            f"x {grid.x_min_m:g}..{grid.x_max_m:g}, y {grid.y_min_m:g}..{grid.y_max_m:g}: "
            f"ids {hm.outside[:5].tolist()} ({', '.join(map(str, names[:5]))})"
        )
        if not config.crop:
            raise InputError(
                ing.folder / BUILDINGS.filename,
                msg + " (wrong frame? use --bounds buildings to widen the grid, or --crop to drop them)",
                field="footprint_wkb",
            )
        warnings.append(msg + ": dropped (the city is cropped: --crop, or `crop` in data/raw/cities.toml)")
    if len(hm.unresolved):
        warnings.append(f"{len(hm.unresolved)} building(s) cover no cell centre (smaller than a {grid.spacing_m:g} m cell)")
    height_rel = (hm.height_m - config.altitude_m).astype(np.float32)
    blocked = (hm.building_id >= 0) & (hm.height_m >= config.altitude_m)

    x_m, y_m = cell_centres(grid)
    ux, uy, uin = cell_index(
        grid, users["x_m"].to_numpy(dtype=float, na_value=np.nan), users["y_m"].to_numpy(dtype=float, na_value=np.nan)
    )
    tallies = {
        "num_receivers": np.bincount(u[inside], minlength=len(users)),
        "num_dead_cells": dead.reshape(len(users), -1).sum(axis=1),
    }
    placed = {
        "ix": ux,
        "iy": uy,
        "tx_power_dbm": tx_used,
        "frequency_hz": users["frequency_hz"],
        "split": _split(len(users), config),
    }
    copied = columns_of(users, "tx_set_id", "tx_point", "x_m", "y_m", "z_m")
    users_table = pd.DataFrame({"user": np.arange(len(users)), **copied, **placed, **tallies})
    arrays = {
        "x_m": x_m,
        "y_m": y_m,
        "height_rel_m": height_rel,
        "blocked": blocked,
        "building_id": hm.building_id.astype(np.int32),
        "sinr_db": sinr,
        "dead": dead,
        "num_rx": np.minimum(num_rx, np.iinfo(np.uint16).max).astype(np.uint16),
        "provenance": provenance,
    }
    info = SinrInfo(
        source=source,
        noise_dbm=None if source == "export_sinr" else config.noise_dbm,
        interference_std_db=config.interference_std_db,
        floor_db=config.sinr_floor_db,
        tx_power_dbm=tuple(sorted({float(t) for t in tx_used if not np.isnan(t)})),
        resampled=export_spacing is None or abs(export_spacing - config.grid_m) > 1e-6,
        export_spacing_m=export_spacing,
    )
    counts = {
        "cells": ny * nx,
        "blocked_cells": int(blocked.sum()),
        "building_cells": int((hm.building_id >= 0).sum()),
        "dead_cells": int(dead.sum()),
        **{
            f"cells_{code_name(c).replace(' ', '_')}": int(n)
            for c, n in enumerate(np.bincount(provenance.ravel(), minlength=len(CODES)))
        },
        "clipped_to_floor_cells": clipped,
        "receivers_used": int(inside.sum()),
        "receivers_outside_grid": outside,
        "receivers_other_heights": len(ing.receivers) - len(rx),
        "transmitters_without_receivers": without,
        "buildings": len(ing.buildings),
        "buildings_in_grid": len(ing.buildings) - len(hm.outside),
        "buildings_cropped": len(hm.outside),
        "buildings_unresolved": len(hm.unresolved),
        "users_without_position": int((~uin).sum()),
    }
    return grid, arrays, users_table, info, counts, warnings


def rasterise_routes(ing: Ingested, config: BuildConfig, grid: GridSpec) -> tuple[dict[str, np.ndarray], pd.DataFrame]:
    """The route points' maps (``schemas.bundle.ROUTE_ARRAYS``) on the users' ``grid``, made as the users' are, and
    the ``ROUTE_POINTS`` table; ``InputError`` when a route point has no receivers or they span another grid."""
    rgrid, arrays, points, *_ = rasterise(ing, config.model_copy(update={"role": None, "val_users": 0}))
    source = ing.folder / ROUTES.filename
    if rgrid != grid:
        raise InputError(
            source,
            f"the route points' receivers span another grid ({rgrid.num_x} x {rgrid.num_y} cells) than "
            f"the users' ({grid.num_x} x {grid.num_y})",
            field="tx_point",
        )
    index = pd.Series(np.arange(len(points)), index=pd.MultiIndex.from_frame(points[["tx_set_id", "tx_point"]].astype("int64")))
    routes = ing.routes.sort_values(["route", "order"], kind="stable").reset_index(drop=True)
    keys = pd.MultiIndex.from_frame(routes[["tx_set_id", "tx_point"]].astype("int64"))
    refuse_first(
        ~keys.isin(index.index),
        source,
        "tx_point",
        lambda k: (
            f"route {routes['route'][k]} point {routes['order'][k]} (t{routes['tx_point'][k]:03d}_"
            f"{routes['tx_set_id'][k]:02d}) has no receivers at the altitude"
        ),
    )
    order = index.loc[keys].to_numpy()  # the rasterised map of each route point, in route order
    ix, iy, inside = cell_index(grid, routes["x_m"].to_numpy(), routes["y_m"].to_numpy())
    where = {"ix": np.where(inside, ix, -1), "iy": np.where(inside, iy, -1)}
    copied = columns_of(routes, "route", "order", "time_s", "tx_set_id", "tx_point", "x_m", "y_m")
    table = pd.DataFrame({"point": np.arange(len(routes)), **copied, **where, **columns_of(routes, "kind", "speed_mps")})
    return {k: arrays[k][order] for k in ROUTE_ARRAYS}, table


def _split(num_users: int, config: BuildConfig) -> list[str | None]:
    if config.role is None:
        return [None] * num_users
    if config.role in ("val", "test"):
        return [config.role] * num_users
    if config.val_users >= num_users:
        raise InputError(None, f"--val-users {config.val_users} leaves no training user of {num_users}", field="val_users")
    split = np.array(["train"] * num_users, dtype=object)
    val = np.random.default_rng([config.seed, 1]).choice(num_users, size=config.val_users, replace=False)
    split[val] = "val"
    return split.tolist()


def _write_parquet(spec, frame: pd.DataFrame, path: Path) -> None:
    table = spec.conform(pa.Table.from_pandas(frame, preserve_index=False))
    pq.write_table(table, path)


def cells_frame(grid: GridSpec, arrays: dict[str, np.ndarray]) -> pd.DataFrame:
    """The long table of ``cells.parquet``: one row per user x cell, user-major then iy then ix."""
    num_users = arrays["sinr_db"].shape[0]
    ny, nx = grid.shape
    iy, ix = np.divmod(np.arange(ny * nx), nx)
    return pd.DataFrame(
        {
            "user": np.repeat(np.arange(num_users, dtype=np.int32), ny * nx),
            "ix": np.tile(ix, num_users),
            "iy": np.tile(iy, num_users),
            "x_m": np.tile(arrays["x_m"][ix], num_users),
            "y_m": np.tile(arrays["y_m"][iy], num_users),
            "sinr_db": arrays["sinr_db"].ravel(),
            "dead": arrays["dead"].ravel(),
            "provenance": arrays["provenance"].ravel(),
            "blocked": np.tile(arrays["blocked"].ravel(), num_users),
            "height_rel_m": np.tile(arrays["height_rel_m"].ravel(), num_users),
        }
    )


#: The share of dead legal user-cells over which the build warns that a city's maps are mostly cells no ray reached.
DEAD_WARNING = 0.9


def unplayable(d: dict[str, float | None]) -> list[str]:
    """The build's warnings when the city's maps leave little or nothing to play (``difficulty``'s figures ``d``): no
    start cell for any user (no legal cell reaches P_T, or none can be reached), or nearly every legal cell dead."""
    shares = f"{100 * d['target_share']:.1f} % of legal user-cells reach P_T {d['p_t_db']:g} dB, {100 * d['dead_share']:.1f} % are dead"
    if not d["num_starts"]:
        why = (
            "do the receivers cover the streets? is the noise level the export's?"
            if not d["target_share"]
            else "every live cell already reaches it, or none reaches a target: is P_T or the noise level too low?"
        )
        return [
            f"nothing can be played here: {shares}; no user has a cell below P_T that a target can be reached from, "
            f"so `uavrl train` and `uavrl report` will refuse the city ({why})"
        ]
    if d["dead_share"] >= DEAD_WARNING:
        return [f"{shares}: most of the maps are cells no ray reached (do the receivers cover the streets?)"]
    return []


def build_city(
    city: str,
    config: BuildConfig,
    root: str | Path = DEFAULT_ROOT,
    *,
    command: str = "",
    force: bool = False,
    on_stage: Callable[[str], None] | None = None,
) -> BuildResult:
    """Build (or find up to date) the bundle of one ingested city; ``InputError`` on bad input.

    The bundle is written into a temporary folder and renamed into
    ``root/city/<version>``; ``latest`` moves only after that. An interrupted
    build leaves earlier bundles and ``latest`` as they were.
    """

    def stage(name: str) -> None:
        if on_stage is not None:
            on_stage(name)

    stage("read")
    ing = read_ingested(city, root)
    version = bundle_version(ing.hashes, config)
    final = Path(root) / city / version
    if not force and (final / BUNDLE_MANIFEST).is_file():
        try:
            bundle = load_bundle(str(final))
        except InputError:
            bundle = None  # damaged: rebuild it below
        if bundle is not None:
            before = read_latest(city, root)
            if before != version:
                write_latest(city, version, root)
            return BuildResult(city, final, bundle.manifest, built=False, previous_latest=_moved(before, version))

    stage("rasterise")
    of_users, of_routes = split_routes(ing)
    grid, arrays, users, info, counts, warnings = rasterise(of_users, config)
    routes = None if of_routes is None else rasterise_routes(of_routes, config, grid)
    stage("write")
    # one lock for every bundle of the city (.<city>.lock beside its folder), not one file per version ever built
    with atomic_directory(final, marker=BUNDLE_MANIFEST, what="map bundle", lock=final.parent) as tmp:
        np.savez(tmp / "maps.npz", **arrays)
        _write_parquet(CELLS, cells_frame(grid, arrays), tmp / CELLS.filename)
        _write_parquet(USERS, users, tmp / USERS.filename)
        files = ["maps.npz", CELLS.filename, USERS.filename]
        if routes is not None:
            np.savez(tmp / "routes.npz", **routes[0])
            _write_parquet(ROUTE_POINTS, routes[1], tmp / ROUTE_POINTS.filename)
            files += ["routes.npz", ROUTE_POINTS.filename]
        split = users["split"].value_counts().to_dict()
        hardness = difficulty(arrays["blocked"], arrays["dead"], arrays["sinr_db"], config.p_t_db)
        warnings += unplayable(hardness)
        manifest = BundleManifest(
            city=city,
            version=version,
            created_utc=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            uavplace_version=uavplace_version(),
            command=command,
            config=config,
            grid=grid,
            sinr=info,
            num_users=len(users),
            num_route_points=0 if routes is None else len(routes[1]),
            split={k: int(split.get(k, 0)) for k in ("train", "val", "test")},
            counts={"users": len(users), **counts},
            difficulty=hardness,
            files={name: sha256_file(tmp / name) for name in files},
            inputs=ing.hashes,
            warnings=tuple(warnings),
        )
        write_model_json(manifest, tmp / BUNDLE_MANIFEST)
    before = read_latest(city, root)
    write_latest(city, version, root)
    return BuildResult(city, final, manifest, built=True, previous_latest=_moved(before, version))


def _moved(before: str | None, now: str) -> str | None:
    return before if before is not None and before != now else None

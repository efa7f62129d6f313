"""The receivers ``uavdata build`` rasterises: those at the UAV altitude (height above the terrain under them), the
lattice of the export and the grid they span, checked to cover it (steps 3 of the build recipe, ``dataset.build``)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from uavplace.dataset.ingested import Ingested
from uavplace.dataset.raster import grid_over, ground_z
from uavplace.infra.limits import check_limit
from uavplace.schemas import InputError
from uavplace.schemas.bundle import (
    BuildConfig,
    GridSpec,
)
from uavplace.schemas.tables import RECEIVERS

#: How many distinct receiver heights an altitude error lists.
HEIGHTS_SHOWN = 8


def receivers_at_altitude(ing: Ingested, config: BuildConfig) -> pd.DataFrame:
    rx = ing.receivers
    src = ing.folder / RECEIVERS.filename
    if len(rx) == 0:
        raise InputError(src, "the city has no receiver outputs: nothing to build a SINR map from (empty city)")
    above = rx["z_m"].to_numpy() - ground_z(ing.terrain, rx["x_m"].to_numpy(), rx["y_m"].to_numpy())
    keep = np.abs(above - config.altitude_m) <= config.altitude_tol_m
    if not keep.any():
        heights, counts = np.unique(np.round(above, 2), return_counts=True)
        top = np.argsort(-counts)[:HEIGHTS_SHOWN]
        listed = ", ".join(f"{heights[i]:g} m ({counts[i]} rx)" for i in sorted(top))
        raise InputError(
            src,
            f"no receiver at {config.altitude_m:g} +/- {config.altitude_tol_m:g} m above ground; heights present: {listed}"
            + (" ..." if len(heights) > HEIGHTS_SHOWN else "")
            + " (choose one with --alt, or widen --alt-tol)",
            field="z_m",
        )
    return rx.loc[keep].reset_index(drop=True)


def columns_of(frame: pd.DataFrame, *names: str) -> dict[str, pd.Series]:
    """``frame``'s columns ``names``, in that order, as a table's columns are given to ``pd.DataFrame``."""
    return {n: frame[n] for n in names}


def export_lattice(ing: Ingested, rx: pd.DataFrame) -> float | None:
    """The receiver spacing if the receivers used lie on one square lattice, else None.

    From the .txrx when every receiver set used is a grid of one spacing;
    otherwise (a .p2m published without its .txrx, or point sets) from the
    positions themselves: one spacing when every x and every y step between
    neighbouring receiver columns and rows is the same multiple-free value.
    """
    sets = {s.project_id: s for s in ing.manifest.txrx_sets}
    used = [sets.get(int(i)) for i in np.unique(rx["rx_set_id"])]
    spacings = {s.spacing_m for s in used if s is not None and s.kind == "grid"}
    if len(spacings) == 1 and all(s is not None and s.kind == "grid" for s in used):
        return float(spacings.pop())
    return lattice_spacing(rx["x_m"].to_numpy(), rx["y_m"].to_numpy())


def lattice_spacing(x: np.ndarray, y: np.ndarray, tol_m: float = 1e-3) -> float | None:
    """The spacing d [m] if the points' x and y values are each an arithmetic sequence of step d, else None."""

    def step(v: np.ndarray) -> float | None:
        u = np.unique(np.round(v / tol_m)) * tol_m
        if len(u) < 2:
            return None
        d = np.diff(u)
        return float(np.median(d)) if np.abs(d - np.median(d)).max() <= tol_m + 1e-6 * abs(np.median(d)) else None

    dx, dy = step(x), step(y)
    if dx is None or dy is None or abs(dx - dy) > tol_m:
        return None
    return round((dx + dy) / 2, 6)


def grid_of(ing: Ingested, rx: pd.DataFrame, config: BuildConfig, export_spacing: float | None, num_users: int) -> GridSpec:
    """The bundle's grid; ``InputError`` naming ``--grid`` when it passes the limits ``grid_cells`` or ``map_bytes`` (the
    users' maps held in memory), checked before anything is allocated."""
    half = (export_spacing or 0.0) / 2
    rx_box = (rx["x_m"].min() - half, rx["y_m"].min() - half, rx["x_m"].max() + half, rx["y_m"].max() + half)
    mode = config.bounds
    if mode == "auto":
        mode = "receivers" if export_spacing is not None else "buildings"
    if isinstance(mode, tuple):
        box = mode
    elif mode == "receivers" or len(ing.buildings) == 0:
        box = rx_box
    else:
        import shapely

        bx = shapely.total_bounds(shapely.from_wkb(ing.buildings["footprint_wkb"].to_numpy()))
        box = (min(rx_box[0], bx[0]), min(rx_box[1], bx[1]), max(rx_box[2], bx[2]), max(rx_box[3], bx[3]))
    w, h = float(box[2] - box[0]), float(box[3] - box[1])
    cells = max(1.0, w / config.grid_m) * max(1.0, h / config.grid_m)
    what = f"{w:g} x {h:g} m at {config.grid_m:g} m"
    check_limit("grid_cells", cells, "--grid", f"cells of {what}", field="grid_m")
    check_limit("map_bytes", cells * num_users * 8, "--grid", f"maps of {num_users} users over {what} [bytes]", field="grid_m")
    return grid_over(*box, config.grid_m)


def check_coverage(ing: Ingested, rx: pd.DataFrame, tol_m: float) -> None:
    """Every user's receivers must span the same area (users are compared on one map)."""
    ext = rx.groupby(["tx_set_id", "tx_point"])[["x_m", "y_m"]].agg(["min", "max"])
    ref = ext.median()
    off = (ext - ref).abs().max(axis=1)
    bad = off[off > tol_m]
    if len(bad):
        (s, p) = bad.index[0]
        e = ext.loc[(s, p)]
        raise InputError(
            ing.folder / RECEIVERS.filename,
            f"users' receivers do not cover the same area: user t{p:03d}_{s:02d} spans x {e[('x_m', 'min')]:g}..{e[('x_m', 'max')]:g},"
            f" y {e[('y_m', 'min')]:g}..{e[('y_m', 'max')]:g}; most span x {ref[('x_m', 'min')]:g}..{ref[('x_m', 'max')]:g},"
            f" y {ref[('y_m', 'min')]:g}..{ref[('y_m', 'max')]:g} ({len(bad)} of {len(ext)} users differ)",
            field="x_m",
        )

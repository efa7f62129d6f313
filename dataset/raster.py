"""Rasterising an ingested city onto a regular grid: the height map and the receivers' cells.

Everything here is vectorised (shapely 2 array functions, numpy bincount);
there is no Python loop over cells or receivers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
import shapely

from uavplace.schemas.bundle import GridSpec

#: Relative slack when counting cells over an extent (a 100 m extent at 4 m is 25 cells, not 26).
_EPS = 1e-6


def grid_over(x_min: float, y_min: float, x_max: float, y_max: float, spacing_m: float) -> GridSpec:
    """The grid of ``spacing_m`` cells whose lower-left corner is ``(x_min, y_min)`` and that covers the box."""
    nx = max(1, math.ceil((x_max - x_min) / spacing_m - _EPS))
    ny = max(1, math.ceil((y_max - y_min) / spacing_m - _EPS))
    return GridSpec(x_min_m=float(x_min), y_min_m=float(y_min), spacing_m=spacing_m, num_x=nx, num_y=ny)


def cell_centres(grid: GridSpec) -> tuple[np.ndarray, np.ndarray]:
    """``(x_m [num_x], y_m [num_y])`` of the cell centres."""
    x = grid.x_min_m + (np.arange(grid.num_x) + 0.5) * grid.spacing_m
    y = grid.y_min_m + (np.arange(grid.num_y) + 0.5) * grid.spacing_m
    return x, y


def cell_index(grid: GridSpec, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(ix, iy, inside)`` of points; ``ix``/``iy`` are -1 where ``inside`` is False."""
    fx = np.floor((np.asarray(x, dtype=float) - grid.x_min_m) / grid.spacing_m)
    fy = np.floor((np.asarray(y, dtype=float) - grid.y_min_m) / grid.spacing_m)
    inside = (fx >= 0) & (fx < grid.num_x) & (fy >= 0) & (fy < grid.num_y)
    ix = np.where(inside, fx, -1).astype(np.int64)
    iy = np.where(inside, fy, -1).astype(np.int64)
    return ix, iy, inside


@dataclass(frozen=True)
class HeightMap:
    height_m: np.ndarray  # [num_y, num_x] float64, building height above ground (0 where none)
    building_id: np.ndarray  # [num_y, num_x] int32, tallest building at the cell centre, -1 where none
    outside: np.ndarray  # building ids whose footprint does not touch the grid
    unresolved: np.ndarray  # building ids inside the grid that cover no cell centre (smaller than a cell)


def height_map(grid: GridSpec, buildings: pd.DataFrame, parts: pd.DataFrame) -> HeightMap:
    """Rasterise building parts: each cell takes the tallest part whose footprint holds its centre.

    Heights are above the building's own base (``part roof - building base``),
    so a city drawn on terrain and one drawn at sea level give the same map.
    ``buildings``/``parts`` are the BUILDINGS and BUILDING_PARTS tables.
    """
    ny, nx = grid.shape
    height = np.zeros(ny * nx)
    bid = np.full(ny * nx, -1, dtype=np.int32)
    if len(buildings) == 0:
        return HeightMap(height.reshape(ny, nx), bid.reshape(ny, nx), np.array([], int), np.array([], int))
    base = buildings.set_index("building_id")["base_z_m"]
    part_geom = shapely.from_wkb(parts["footprint_wkb"].to_numpy())
    part_bid = parts["building_id"].to_numpy(np.int32)
    part_h = parts["roof_z_m"].to_numpy() - base.loc[part_bid].to_numpy()
    x, y = cell_centres(grid)
    xx, yy = np.meshgrid(x, y)  # [num_y, num_x]
    points = shapely.points(xx.ravel(), yy.ravel())
    tree = shapely.STRtree(part_geom)
    pt, part = tree.query(points, predicate="intersects")  # pairs (cell, part)
    if pt.size:
        # Per cell, keep the tallest part: sort by (cell, height) and take each cell's last pair.
        order = np.lexsort((part_h[part], pt))
        pt, part = pt[order], part[order]
        last = np.r_[pt[1:] != pt[:-1], True]
        height[pt[last]] = part_h[part[last]]
        bid[pt[last]] = part_bid[part[last]]
    box = shapely.box(grid.x_min_m, grid.y_min_m, grid.x_max_m, grid.y_max_m)
    foot = shapely.from_wkb(buildings["footprint_wkb"].to_numpy())
    ids = buildings["building_id"].to_numpy()
    touches = shapely.intersects(foot, box)
    outside = ids[~touches]
    unresolved = np.setdiff1d(ids[touches], bid[bid >= 0])
    return HeightMap(height.reshape(ny, nx), bid.reshape(ny, nx), outside, unresolved)


def ground_z(terrain: dict[str, np.ndarray] | None, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Terrain z under points (linear on the terrain's triangles); 0 without terrain.

    Points outside the terrain mesh take the z of the nearest terrain vertex.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if terrain is None:
        return np.zeros_like(x)
    import matplotlib.tri as mtri

    v, t = terrain["vertices_m"], terrain["triangles"]
    tri = mtri.Triangulation(v[:, 0], v[:, 1], t)
    z = np.ma.filled(mtri.LinearTriInterpolator(tri, v[:, 2])(x, y), np.nan).astype(float)
    far = np.isnan(z)
    if far.any():
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(v[:, :2]).query(np.c_[x[far], y[far]])
        z[far] = v[nearest, 2]
    return z

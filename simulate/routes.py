"""User routes for the tracking task: paths along open ground, sampled every <= 2 m, each point traced as a user.

A route is drawn on a 1 m raster of the open ground (no building footprint within ``CLEARANCE_M``,
inside the grid): from a random open cell of the largest open region, the shortest 8-connected path
(Dijkstra, ``scipy.sparse.csgraph``) to a random cell at least ``length_m`` away along the ground, cut
at ``length_m``, straightened where the straight line stays ``CLEARANCE_M`` / 2 from every footprint,
and resampled at equal steps of at most ``MAX_STEP_M``. Every point and step of a route is at least
0.25 m clear of every building (a diagonal step between raster cells 1 m clear comes no closer than
0.29 m). A route's kind sets its speed (``KINDS``): ``time_s`` of a point is its distance
along the route over that speed. The tracking env (rl/tasks/tracking/) moves the user along a route and back.

The export stays InSite-shaped: the route points are a second transmitter points set of the ``.txrx``
(``ROUTE_SET``), each traced as a user, and ``<name>.routes.csv`` (``ROUTE_COLUMNS``) says which point
of which route each is.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
import shapely.ops

from uavplace.schemas.tables import ROUTE_KINDS, ROUTE_MAX_STEP_M

#: Speeds of the route kinds [m/s]: a walking pedestrian and a vehicle in town traffic (schemas.tables).
KINDS = ROUTE_KINDS
#: Route points are at most this far apart along the route [m] (ingest refuses longer jumps).
MAX_STEP_M = ROUTE_MAX_STEP_M
#: The raster cells a route is searched on keep this distance from every building footprint [m].
CLEARANCE_M = 1.0
#: The raster the paths are searched on [m].
RASTER_M = 1.0
#: The .txrx points set of the route points: (set id, name).
ROUTE_SET = (3, "Route")
#: The columns of ``<name>.routes.csv``, in order.
ROUTE_COLUMNS = ("route", "order", "time_s", "tx_set", "tx_point", "x_m", "y_m", "kind", "speed_mps")


@dataclass(frozen=True)
class Route:
    route: int
    kind: str
    points_m: np.ndarray  # [n, 2], consecutive points <= MAX_STEP_M apart

    @property
    def speed_mps(self) -> float:
        return KINDS[self.kind]

    @property
    def times_s(self) -> np.ndarray:
        steps = np.linalg.norm(np.diff(self.points_m, axis=0), axis=1)
        return np.r_[0.0, np.cumsum(steps)] / self.speed_mps


def _open_raster(
    footprints: list[shapely.Geometry], box: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(open [ny, nx] bool, x [nx], y [ny]) of the 1 m raster over ``box`` less the footprints grown by the clearance."""
    x0, y0, x1, y1 = box
    xs = np.arange(x0 + CLEARANCE_M, x1 - CLEARANCE_M + 1e-9, RASTER_M)
    ys = np.arange(y0 + CLEARANCE_M, y1 - CLEARANCE_M + 1e-9, RASTER_M)
    gx, gy = np.meshgrid(xs, ys)
    if not footprints:
        return np.ones(gx.shape, bool), xs, ys
    near = shapely.union_all([shapely.buffer(f, CLEARANCE_M) for f in footprints])
    return ~shapely.contains_xy(near, gx, gy), xs, ys


def _graph(open_: np.ndarray):  # noqa: ANN202 - a scipy sparse matrix
    """The 8-connected graph of the open raster cells (edge weights in metres), as a CSR matrix. A diagonal step
    between two open cells cannot touch a building: both ends keep the clearance and no point of the step is more
    than 0.71 m from one of them."""
    from scipy.sparse import coo_matrix

    ny, nx = open_.shape
    idx = np.arange(ny * nx).reshape(ny, nx)
    rows, cols, weights = [], [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        lo, hi = max(0, -dx), nx - max(0, dx)  # the columns of the cells whose neighbour (y + dy, x + dx) exists
        both = open_[: ny - dy, lo:hi] & open_[dy:, lo + dx : hi + dx]
        rows.append(idx[: ny - dy, lo:hi][both])
        cols.append(idx[dy:, lo + dx : hi + dx][both])
        weights.append(np.full(int(both.sum()), RASTER_M * math.hypot(dx, dy)))
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    n = ny * nx
    return coo_matrix((np.r_[w, w], (np.r_[r, c], np.r_[c, r])), shape=(n, n)).tocsr()


def draw_routes(
    footprints: list[shapely.Geometry],
    box: tuple[float, float, float, float],
    count: int,
    length_m: float,
    kinds: tuple[str, ...],
    rng: np.random.Generator,
) -> list[Route]:
    """``count`` routes of ``length_m`` over the open ground of ``box`` (kinds in turn from ``kinds``); ``ValueError``
    when the open ground holds no path that long."""
    from scipy.sparse.csgraph import dijkstra

    open_, xs, ys = _open_raster(footprints, box)
    if not open_.any():
        raise ValueError("no open ground for routes (every cell is within the clearance of a building)")
    graph = _graph(open_)
    free = np.flatnonzero(open_.ravel())
    raw = shapely.union_all(footprints) if footprints else shapely.Polygon()
    routes = []
    for k in range(count):
        for _attempt in range(50):
            start = int(rng.choice(free))
            dist, pred = dijkstra(graph, indices=start, return_predecessors=True)
            far = np.flatnonzero(np.isfinite(dist) & (dist >= length_m))
            if len(far):
                break
        else:
            raise ValueError(f"no path of {length_m:g} m along the open ground (from 50 random starts)")
        node = int(rng.choice(far))
        path = [node]
        while path[-1] != start:
            path.append(int(pred[path[-1]]))
        iy, ix = np.divmod(np.array(path[::-1]), len(xs))
        line = shapely.LineString(np.c_[xs[ix], ys[iy]])
        straight = line.simplify(RASTER_M, preserve_topology=False)
        if not shapely.intersects(shapely.buffer(straight, CLEARANCE_M / 2), raw):
            line = straight
        line = shapely.ops.substring(line, 0.0, length_m) if line.length > length_m else line
        steps = max(1, math.ceil(line.length / MAX_STEP_M - 1e-9))
        points = np.array([line.interpolate(d).coords[0] for d in np.linspace(0.0, line.length, steps + 1)])
        if footprints and shapely.intersects(shapely.LineString(points), raw):
            raise AssertionError("a route crosses a building")  # the raster path keeps its clearance: cannot happen
        routes.append(Route(k, kinds[k % len(kinds)], points))
    return routes


def write_routes_csv(path: str | Path, routes: list[Route], first_point: int = 1) -> Path:
    """``<name>.routes.csv``: one row per route point, the points numbered in the ``ROUTE_SET`` points set from
    ``first_point`` in route order."""
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(ROUTE_COLUMNS)
        point = first_point
        for r in routes:
            for order, ((x, y), t) in enumerate(zip(r.points_m, r.times_s, strict=True)):
                w.writerow([r.route, order, f"{t:.4f}", ROUTE_SET[0], point, f"{x:.4f}", f"{y:.4f}", r.kind, f"{r.speed_mps:g}"])
                point += 1
    return path

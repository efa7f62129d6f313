"""The tracking task's routes on the placement canvases, its episodes' metrics and its oracle."""

from __future__ import annotations

import numpy as np

from uavplace.dataset.bundle import Bundle
from uavplace.dataset.difficulty import UNREACHABLE, steps_to_target
from uavplace.rl.tasks.tracking.config import STAY, TRACK_MOVES, TrackingConfig
from uavplace.rl.world.maps import MOVES, MapSet, transform


def user_point(times_s: np.ndarray, start_s: np.ndarray, t: np.ndarray, step_s: np.ndarray) -> np.ndarray:
    """Index along each route of the point the user is at after ``t`` steps of ``step_s`` seconds from ``start_s``:
    the user walks to the route's end and back (period twice the route's duration), at the point nearest in time.
    ``times_s``: ``[K, n_max]`` point times per route (``inf`` past a route's last point); the others ``[K]``."""
    rows = np.arange(len(times_s))
    final = np.isfinite(times_s).sum(axis=1) - 1  # each route's last point
    last = times_s[rows, final]
    s = np.mod(start_s + t * step_s, 2 * last)
    s = np.where(s > last, 2 * last - s, s)  # on the way back
    after = np.clip((times_s <= s[:, None]).sum(axis=1), 1, times_s.shape[1] - 1)  # the first point later than s
    lo, hi = np.minimum(after - 1, final), np.minimum(after, final)
    nearer_hi = np.abs(times_s[rows, hi] - s) < np.abs(s - times_s[rows, lo])
    return np.where(nearer_hi, hi, lo)


class RouteSet:
    """The routes of one or more bundles laid on the placement canvases (``MapSet``): as they are, or with
    ``rotate`` (training) also under the MapSet's other symmetries, each (route, symmetry) a route of its own.

    ``sinr`` / ``dead`` ``[P, L, L]`` (every route point's map on the canvas; beyond the edge P_L / dead),
    ``steps`` ``[P, L, L]`` (moves to a target of that point's map), ``times`` ``[R, n_max]`` (inf padded),
    ``first`` ``[R]`` (each route's first point in ``sinr``), ``count`` ``[R]``, ``bundle`` ``[R]``, ``canvas``
    ``[R]`` (its row of the MapSet's height and blocked canvases), ``step_s`` ``[R]``.
    """

    def __init__(self, bundles: list[Bundle], config: TrackingConfig, rotate: bool = False) -> None:
        with_routes = [b for b in bundles if b.routes is not None]
        if not with_routes:
            raise ValueError(f"no bundle with routes among {[b.city for b in bundles]}: simulate them with --routes")
        self.bundles, self.config = with_routes, config
        self.maps = MapSet(with_routes, config.canvas())
        p, L, S = self.maps.pad, self.maps.side, self.maps.symmetries
        self.turns = S if rotate else 1  # the symmetries each route is laid under (the identity first)
        total = self.turns * sum(len(b.routes) for b in with_routes)
        self.sinr = np.full((total, L, L), config.p_l_db, np.float32)
        self.dead = np.ones((total, L, L), bool)
        self.steps = np.full((total, L, L), UNREACHABLE, np.int32)
        first, count, bundle, canvas, step_s, times, keys, names = [], [], [], [], [], [], [], []
        start_cells: list[np.ndarray] = []  # per route point: the canvas cells an episode may start in then
        offset = 0
        for i, b in enumerate(with_routes):
            target = config.reaches(b.route_sinr_db, b.route_dead, ~b.blocked)
            steps = steps_to_target(~b.blocked, target)
            for k in range(self.turns):
                ny, nx = self.maps.shapes[S * i + k]
                sl = slice(offset, offset + len(b.routes))
                self.sinr[sl, p : p + ny, p : p + nx] = transform(b.route_sinr_db, k)
                self.dead[sl, p : p + ny, p : p + nx] = transform(b.route_dead, k)
                self.steps[sl, p : p + ny, p : p + nx] = transform(steps, k)
                starts = ~self.maps.blocked[S * i + k] & ~self.dead[sl] & ~config.reaches(self.sinr[sl])
                start_cells += [np.flatnonzero(ok) for ok in starts & (self.steps[sl] != UNREACHABLE)]
                for route, rows in b.routes.groupby("route", sort=False):
                    first.append(offset + int(rows.index[0]))
                    count.append(len(rows))
                    bundle.append(i)
                    canvas.append(S * i + k)
                    step_s.append(b.spacing_m / config.uav_speed_mps)
                    times.append(rows["time_s"].to_numpy())
                    keys.append(self.maps.canvas_keys[S * i + k])  # its canvas's public map: no route, no user
                    names.append((b.city, int(route), str(rows["kind"].iloc[0])))
                offset += len(b.routes)
        n_max = max(len(t) for t in times)
        self.times = np.full((len(times), n_max), np.inf)
        for r, t in enumerate(times):
            self.times[r, : len(t)] = t
        self.first, self.count, self.bundle, self.canvas = np.array(first), np.array(count), np.array(bundle), np.array(canvas)
        self.step_s = np.array(step_s)
        self.route_keys = np.array(keys, np.uint64)
        self.names = names  # (city, route id, kind) per route
        self.start_cells = start_cells

    @property
    def num_routes(self) -> int:
        return len(self.first)

    def point(self, route: np.ndarray, start_s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Row in ``sinr`` of the point the user of each episode is at after ``t`` steps."""
        return self.first[route] + user_point(self.times[route], start_s, t, self.step_s[route])

    def sample_episodes(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``[n, 4]`` float64 episode specs ``(route, start_s, y, x)``: a route (uniform), a start time on it (uniform
        over the route's duration) and a start cell: legal, live, below P_T, with a target reachable at that time."""
        out = np.zeros((n, 4))
        for k in range(n):
            for _attempt in range(100):
                r = int(rng.integers(self.num_routes))
                start = float(rng.random() * self.times[r, self.count[r] - 1])
                cells = self.start_cells[int(self.point(np.array([r]), np.array([start]), np.array([0]))[0])]
                if len(cells):
                    y, x = divmod(int(cells[rng.integers(len(cells))]), self.maps.side)
                    out[k] = (r, start, y, x)
                    break
            else:
                raise ValueError("no route has a time and a start cell below P_T with a reachable target")
        return out


def episode_metrics(covered: np.ndarray) -> dict[str, np.ndarray]:
    """Per-episode metrics of ``covered`` ``[K, H]`` (step 1..H at or above P_T): ``first_reach`` (steps to the first
    covered step, inf if none), ``coverage`` (share of the steps from it on that are covered, 0 if none),
    ``longest_outage`` (longest run of uncovered steps after it; the horizon if never reached) and ``covered_share``
    (share of all H steps covered)."""
    k, h = covered.shape
    ever = covered.any(axis=1)
    first = np.where(ever, covered.argmax(axis=1) + 1, np.inf)
    after = np.arange(1, h + 1)[None, :] >= np.where(ever, first, h + 1)[:, None]
    coverage = np.where(ever, (covered & after).sum(axis=1) / np.maximum(after.sum(axis=1), 1), 0.0)
    outage = np.zeros(k, np.int64)
    run = np.zeros(k, np.int64)
    for t in range(h):
        run = np.where(after[:, t] & ~covered[:, t], run + 1, 0)
        outage = np.maximum(outage, run)
    return {
        "first_reach": first,
        "coverage": coverage,
        "longest_outage": np.where(ever, outage, h),
        "covered_share": covered.mean(axis=1),
    }


#: The actions of one step of ``oracle_path``'s path, in the order its ties go (stay, then moves 0-3), and their moves.
_ORDER = np.array([STAY, *range(STAY)])
_ORDER_MOVES = TRACK_MOVES[_ORDER]


def oracle_path(legal: np.ndarray, covered: np.ndarray, start: tuple[int, int]) -> tuple[np.ndarray, int]:
    """The UAV's cells ``[H + 1, 2]`` (start first) that cover the most of steps 1..H, by dynamic programming over
    (time, cell): ``covered`` ``[H, ny, nx]`` (step t's map: the cell covers the user then), ``legal`` ``[ny, nx]``;
    moves to a 4-neighbour or stay. Returns (path, covered steps). Ties go to staying, then actions 0-3 in order.

    The programme keeps, for every step, the count of being in each cell then (a border of blocked cells around the
    grid, so that a move's neighbour is a view, not a copy), and takes the moves only along the path it returns."""
    h, ny, nx = covered.shape
    dtype = np.int16 if h < np.iinfo(np.int16).max // 4 else np.int32
    neg = np.iinfo(dtype).min // 2  # blocked: below any count, and no count added to it reaches one
    inner = (slice(1, ny + 1), slice(1, nx + 1))
    illegal = ~legal
    here = np.full((h, ny + 2, nx + 2), neg, dtype)  # being in the cell at step t (covered from t on)
    value = np.zeros((ny, nx), dtype)  # best covered count from step t on, standing in the cell after step t - 1
    best = np.empty((ny, nx), dtype)
    for t in range(h - 1, -1, -1):
        now = here[t]
        np.add(covered[t], value, out=now[inner])
        np.copyto(now[inner], neg, where=illegal)
        best[...] = now[inner]
        for dy, dx in MOVES:  # from cell c, moving to c + (dy, dx)
            np.maximum(best, now[1 + dy : ny + 1 + dy, 1 + dx : nx + 1 + dx], out=best)
        np.copyto(best, neg, where=illegal)
        value, best = best, value
    path = np.empty((h + 1, 2), np.int64)
    path[0] = start
    for t in range(h):
        cells = path[t] + _ORDER_MOVES + 1  # the candidates' cells on the bordered grid
        path[t + 1] = path[t] + _ORDER_MOVES[np.argmax(here[t, cells[:, 0], cells[:, 1]])]
    return path, int(value[start])

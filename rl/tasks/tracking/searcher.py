"""The tracking searcher: the map searcher's belief carried through time for a user who walks (``rl.tasks.tracking``).

Its candidates and their predicted maps are the placement searcher's (``rl.tasks.placement.searcher.MapSearchPolicy``: open-ground
cells on a lattice of ``stride`` cells, a map of each predicted from the buildings and cached). Each row keeps a
belief over (speed class, candidate): the user walks at one of the speeds of the training routes
(``MotionModel``, fitted by ``fit_motion``), unknown to the UAV, with the share of routes of that speed as its prior.
Every step:

1. **motion**: the user walks ``speed x step_s`` metres on, along open ground. The belief of each speed class flows
   from each candidate to its lattice neighbours on open ground (four, ``stride`` cells away) with probability
   ``q = min(1, speed x step_s / (stride x cell side))`` split evenly over the four directions, a direction into a
   building keeping its share in place (``transition``): the belief leaves a candidate as often as the user leaves a
   lattice cell at that speed;
2. **measurement**: the SINR the UAV measures where it is, now, updates every class and candidate as the placement
   searcher's likelihood does (``MapSearchPolicy.update_rows``, a canvas's rows at once);
3. **move**: on a cell that measured P_T or more it stays; else it takes one step along a shortest legal path to the
   cell of best discounted posterior probability of reaching P_T (the placement planner, every cell but its own a
   candidate, since the user moves and an old measurement says little; its discount far flatter than placement's,
   ``tracking_search``).

It reads what the UAV knows: its position, the step, its own current measurement and the public maps; never the
route, the user's point or a map of the user (``tests/test_tracking.py`` scrambles them).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from uavplace.dataset.bundle import Bundle
from uavplace.rl.belief import CandidateMaps, posterior_cover
from uavplace.rl.config import PLACEMENT_PLAN_SETTINGS
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.tasks.tracking.config import STAY, MotionModel
from uavplace.rl.tasks.tracking.env import TrackingView
from uavplace.rl.tasks.tracking.maps import RouteSet
from uavplace.rl.world.view import PublicMaps

#: The tracking searcher's name in tables.
TRACKING_SEARCHER = "tracking searcher"


def fit_motion(bundles: list[Bundle]) -> MotionModel:
    """The speeds of the routes of ``bundles`` (training cities: each route's ``speed_mps``, to 0.1 m/s) and the share
    of routes at each."""
    speeds = []
    for b in bundles:
        if b.routes is not None:
            speeds += b.routes.groupby("route")["speed_mps"].first().round(1).tolist()
    if not speeds:
        raise ValueError(f"no route among {[b.city for b in bundles]} to fit the user's motion on")
    values, counts = np.unique(speeds, return_counts=True)
    return MotionModel(speeds_mps=tuple(float(v) for v in values), weights=tuple(float(c / counts.sum()) for c in counts))


def transition(cells: np.ndarray, stride: int, q: float) -> sparse.csr_matrix:
    """``[C, C]`` column-stochastic: the probability of moving from candidate ``j`` (``cells[j]``, ``(iy, ix)``) to
    candidate ``i`` in one step: ``q / 4`` to each of the four lattice neighbours (``stride`` cells away) that is a
    candidate, and the rest (``1 - q`` and the shares of the missing neighbours) staying."""
    index = {(int(y), int(x)): i for i, (y, x) in enumerate(cells)}
    rows, cols, vals = [], [], []
    stay = np.ones(len(cells))
    for j, (y, x) in enumerate(cells):
        for dy, dx in ((stride, 0), (-stride, 0), (0, stride), (0, -stride)):
            i = index.get((int(y) + dy, int(x) + dx))
            if i is not None:
                rows.append(i)
                cols.append(j)
                vals.append(q / 4)
                stay[j] -= q / 4
    rows += list(range(len(cells)))
    cols += list(range(len(cells)))
    vals += stay.tolist()
    return sparse.csr_matrix((vals, (rows, cols)), shape=(len(cells), len(cells)))


class TrackingSearchPolicy:
    """The tracking searcher of the module's docstring as a tracking method (``reset``, ``act(obs, mask, view)`` of a
    ``rl.tasks.tracking.TrackingView``, 5 actions)."""

    reads_observation = False  # it reads its measurements from the view

    name = TRACKING_SEARCHER
    #: The ``SearchConfig`` fields it does not read (it plans as the cover planner, a step at a time).
    unread_settings = PLACEMENT_PLAN_SETTINGS | {"planner", "fleet_plan", "info_weight", "info_radius", "info_bin_db"}

    def __init__(self, searcher: MapSearchPolicy, motion: MotionModel, name: str | None = None) -> None:
        self.searcher, self.motion = searcher, motion
        self.name = name or TRACKING_SEARCHER
        self.prior = np.log(np.asarray(motion.weights, np.float64))
        self.belief: list[np.ndarray | None] = []  # per row: [speed classes, candidates] log-belief
        self._moves: dict[tuple, list[sparse.csr_matrix]] = {}

    def predict(self, routes: RouteSet) -> None:
        """The predicted maps of every canvas of ``routes``, made now (and kept in the cache, where the hybrid's channel
        reads the same): a report does it before its Ray tasks, which then read them instead of each predicting them."""
        public = PublicMaps.of(routes.maps)
        for canvas in np.unique(routes.canvas):
            self.searcher.canvas_maps(public, int(canvas))

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        if len(self.belief) != num_envs:
            self.belief = [None] * num_envs
        for r in np.asarray(rows, np.int64):
            self.belief[r] = None

    def moves(self, city: str, canvas: int, maps: CandidateMaps, step_s: float, cell_m: float) -> list[sparse.csr_matrix]:
        """One ``transition`` per speed class for the candidates of ``canvas`` of ``city`` (its bundle version: a
        canvas number names a canvas of one city's maps only), kept."""
        key = (city, canvas, step_s)
        if key not in self._moves:
            stride = self.searcher.config.stride
            qs = [min(1.0, v * step_s / (stride * cell_m)) for v in self.motion.speeds_mps]
            self._moves[key] = [transition(maps.cells, stride, q) for q in qs]
        return self._moves[key]

    def step_belief(self, log_b: np.ndarray, moves: list[sparse.csr_matrix]) -> np.ndarray:
        """``log_b`` [R, K, C] (each row's speed classes over the candidates) after one step of motion, each speed
        class by its own transition: row by row the same numbers as the rows at once."""
        b = np.exp(log_b - log_b.max(axis=(1, 2), keepdims=True))
        moved = np.stack([(m @ b[:, k].T).T for k, m in enumerate(moves)], axis=1)
        return np.log(np.maximum(moved, 1e-300))

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingView) -> np.ndarray:
        n = len(mask)
        if len(self.belief) != n:
            self.reset(np.arange(n), n)
        public = env.public
        p, s = public.pad, self.searcher
        actions = np.full(n, STAY, np.int64)
        live = np.flatnonzero(~env.exhausted)
        canvases = env.canvas[live]
        for canvas in np.unique(canvases):  # a canvas's rows at once: each row's numbers as alone
            rows = live[canvases == canvas]
            maps = s.canvas_maps(public, int(canvas))
            settings = public.settings[public.bundle_of(int(canvas))]
            y, x = env.pos[rows, 0], env.pos[rows, 1]
            measured = env.memory[rows, y, x].astype(np.float64)  # measured now, at these cells
            columns = maps.index[y - p, x - p]
            classes, cells = len(self.prior), len(maps.cells)
            log_b = np.empty((len(rows), classes, cells))
            fresh = np.array([self.belief[r] is None for r in rows]) | (env.t[rows] == 0)
            log_b[fresh] = self.prior[:, None]
            if not fresh.all():
                step_s = float(settings["spacing_m"]) / env.config.uav_speed_mps
                moves = self.moves(settings["version"], int(canvas), maps, step_s, float(settings["spacing_m"]))
                log_b[~fresh] = self.step_belief(np.stack([self.belief[r] for r in rows[~fresh]]), moves)
            at, values = np.repeat(columns, classes), np.repeat(measured, classes)
            log_b = s.update_rows(maps, log_b.reshape(-1, cells), at, values, float(settings["floor_db"]))
            log_b = log_b.reshape(len(rows), classes, cells)
            log_b -= log_b.max(axis=(1, 2), keepdims=True)
            for r, row in zip(rows, log_b, strict=True):
                self.belief[r] = row
            going = ~env.config.reaches(measured)
            if not going.any():
                continue
            # the plans, the canvas's rows still below P_T in one product
            scores = posterior_cover(np.logaddexp.reduce(log_b[going], axis=1), maps, s.on_device, s.config.precision)
            for r, score in zip(rows[going], scores, strict=True):
                here = int(maps.index[env.pos[r, 0] - p, env.pos[r, 1] - p])
                others = np.zeros(len(maps.legal), bool)
                others[here] = True  # only its own cell is not a target: the user moves
                actions[r] = s.first_move(public, int(canvas), maps, here, score, others, mask[r, :4])
        return actions

"""The map searcher run for the fleet (``FleetSearcher``)."""

from __future__ import annotations

import numpy as np

from uavplace.rl.config import PLACEMENT_PLAN_SETTINGS
from uavplace.rl.tasks.fleet.config import FLEET_MOVES, STAY
from uavplace.rl.tasks.fleet.env import FleetView
from uavplace.rl.tasks.fleet.maps import FleetMaps, assignments, user_subsets

#: The most rounds of the ``union`` plan's coordinate ascent (on the validation cities it settles within two).
UNION_ROUNDS = 4


def _nearest_first(moves: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the cells nearest first by ``moves`` [M], unreachable (inf) last; for every length ``D`` of ``lengths``, the
    position in that order of the farthest cell within ``D`` moves, -1 where none is): what ``_best_within`` reads,
    sorted once per UAV and step."""
    order = np.argsort(moves, kind="stable")
    return order, np.searchsorted(moves[order], lengths, side="right") - 1


def _best_within(value: np.ndarray, ranked: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """For every length ``D`` of ``ranked`` (``_nearest_first``), the largest ``value`` [M] of a cell within ``D``
    moves (0 where none is) and that cell, the nearest of equals: each ``[len(lengths)]``."""
    order, last = ranked
    v = value[order]
    best = np.maximum.accumulate(v)
    rises = np.flatnonzero(np.r_[True, v[1:] > best[:-1]])  # where the running best rises: its nearest cell
    at = rises[np.searchsorted(rises, last, side="right") - 1]
    return np.where(last >= 0, best[last], 0.0), order[at]


class FleetSearcher:
    """The map searcher run for the fleet (``rl.tasks.placement.searcher``): one belief per user over its candidate
    cells, updated by every UAV's first measurement of each cell (a cell measured again tells nothing new), and one plan for the fleet.

    Per user ``n`` the posterior probability ``P_n(c)`` that each legal cell ``c`` serves it (1 or 0 at a visited
    cell: its SINR is known). A set of users ``S`` is served at ``c`` with probability ``prod_{n in S} P_n(c)``. Over
    the K^N assignments of users to UAVs and the cells of the UAVs that have users, the plan takes the largest score
    (``SearchConfig.fleet_plan``): with ``makespan``, the product of the UAVs' probabilities times the searcher's
    distance discount of the longest of their paths, since the fleet succeeds when its last UAV arrives; with
    ``product``, the product over UAVs of each one's probability times the discount of its own path. With ``union``
    (the default) the makespan plan's cells are then moved, a UAV at a time, while that raises the probability that
    every user is served by some UAV times the discount of the longest path: a UAV may serve users assigned to
    another, and a UAV without users goes where it adds most. Each UAV moves one cell along a shortest legal path to
    its cell (staying when it stands on it; in the other plans a UAV without users stays). Needs the bundles' public
    maps (``FleetMaps.of``)."""

    name = "map searcher"
    #: The ``SearchConfig`` fields it does not read (its planner is cover, or cover with information: ``planners``).
    unread_settings = PLACEMENT_PLAN_SETTINGS
    planners = ("cover", "info")

    def __init__(self, predictor, config=None, cache=None, device: str = "cpu") -> None:  # noqa: ANN001 - the searcher's types
        from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

        self.searcher = MapSearchPolicy(predictor, config, cache, device=device)
        self.public = None
        self.log_b: list[list[np.ndarray]] = []

    def bind(self, maps: FleetMaps) -> FleetSearcher:
        """Read ``maps``' public maps (its bundles' heights, grid and settings; never a user's map)."""
        from uavplace.rl.world.maps import MapSet
        from uavplace.rl.world.settings import CanvasSettings
        from uavplace.rl.world.view import PublicMaps

        if maps.bundles is None:
            raise ValueError("the fleet searcher predicts from bundles: FleetMaps.of(bundles, config)")
        env = CanvasSettings(window=maps.config.window, p_t_db=maps.config.p_t_db, rotate=False)
        self.public, self.symmetries = PublicMaps.of(MapSet(maps.bundles, env)), env.symmetries
        return self

    def predict(self) -> None:
        """Every bound city's predicted maps, made now (and kept in the cache): a report does it before its Ray tasks,
        which then read them instead of each predicting them again."""
        if self.public is None:
            raise ValueError("FleetSearcher.bind(maps) first: it predicts from the bundles' public maps")
        for city in range(len(self.public.settings)):
            self.searcher.canvas_maps(self.public, self.symmetries * city)

    def reset(self, rows: np.ndarray, num_envs: int, uavs: int) -> None:
        if len(self.log_b) != num_envs:
            self.log_b = [[] for _ in range(num_envs)]
        for r in rows:
            self.log_b[int(r)] = []

    def act(self, mask: np.ndarray, view: FleetView) -> np.ndarray:
        from uavplace.rl.belief import posterior_cover

        if self.public is None:
            raise ValueError("FleetSearcher.bind(maps) first: it predicts from the bundles' public maps")
        public, cfg, p = self.public, view.config, view.config.window // 2
        e, k = mask.shape[:2]
        out = np.full((e, k), STAY, np.int64)
        by_canvas: dict[int, list[int]] = {}
        uav_cells: dict[int, list[np.ndarray]] = {}  # per canvas, its rows' UAVs' cells: their paths fetched at once
        for r in np.flatnonzero(~view.done):  # the beliefs of the rows still playing, row by row
            canvas = self.symmetries * int(view.city[r])
            cm = self.searcher.canvas_maps(public, canvas)
            floor_db = float(public.settings[int(view.city[r])]["floor_db"])
            y, x = view.pos[r, :, 0], view.pos[r, :, 1]
            cols = cm.index[y - p, x - p]
            if not self.log_b[r]:
                self.log_b[r] = [np.zeros(len(cm.cells), np.float32) for _ in range(cfg.users)]
            first = view.visits[r, y, x] == 1  # measured for the first time this step (or at the start)
            for n in range(cfg.users):
                for uav in np.flatnonzero(first):
                    value = float(view.memory[r, n, y[uav], x[uav]])
                    self.log_b[r][n] = self.searcher.update(cm, self.log_b[r][n], int(cols[uav]), value, floor_db)
            by_canvas.setdefault(canvas, []).append(r)
            uav_cells.setdefault(canvas, []).append(cols)
        for canvas, rows in by_canvas.items():  # the plans: a city's rows' users in one matrix product
            cm = self.searcher.canvas_maps(public, canvas)
            self.searcher.prefetch_paths(public, canvas, cm, np.concatenate(uav_cells[canvas]))
            log_b = np.concatenate([np.stack(self.log_b[r]) for r in rows])
            covers = posterior_cover(log_b, cm, self.searcher.on_device, self.searcher.config.precision)
            for i, r in enumerate(rows):
                out[r] = self._plan(cm, canvas, covers[i * cfg.users : (i + 1) * cfg.users], view, r, mask[r])
        return out

    def _plan(self, cm, canvas: int, cover: np.ndarray, view: FleetView, r: int, mask: np.ndarray) -> np.ndarray:  # noqa: ANN001
        """Row ``r``'s moves [K] from its users' posterior covers [N, M] (the class's docstring)."""
        cfg, p, k = view.config, view.config.window // 2, len(mask)
        cols = cm.index[view.pos[r, :, 0] - p, view.pos[r, :, 1] - p]
        seen = view.visits[r, cm.legal[:, 0] + p, cm.legal[:, 1] + p] > 0
        known = cfg.reaches(view.memory[r][:, cm.legal[:, 0] + p, cm.legal[:, 1] + p])  # [N, M]
        cover = np.where(seen[None], known.astype(np.float32), cover)
        paths = [self.searcher.paths_from(self.public, canvas, cm, int(c)) for c in cols]  # (discount, predecessors, moves)
        if self.searcher.config.planner == "info":
            cover = self._with_information(cm, cover, seen, paths, r, view)
        served = {mine: np.prod(cover[list(mine)], axis=0) for mine in user_subsets(cfg.users)}  # [M] a set of users
        kind = self.searcher.config.fleet_plan
        if kind == "product":
            plan = self._product_plan(served, cfg.users, paths)
        else:
            reach = self._reach(paths)  # what both plans read, sorted once a step
            plan = self._makespan_plan(served, cfg.users, reach)
            if kind == "union":
                plan = self._union_plan(cover, paths, reach, {u: plan.get(u, int(cols[u])) for u in range(k)})
        return np.array([self._step(cm, int(cols[u]), plan.get(u, int(cols[u])), paths[u][1], mask[u]) for u in range(k)])

    def _with_information(self, cm, cover: np.ndarray, seen: np.ndarray, paths: list, r: int, view: FleetView) -> np.ndarray:  # noqa: ANN001
        """``cover`` [N, M] plus ``info_weight`` times the information a measurement tells about each user's cell at every
        unvisited cell within ``info_radius`` moves of a UAV (the placement searcher's ``info`` planner per user)."""
        d = np.min([moves for _, _, moves in paths], axis=0)
        near = np.flatnonzero((d <= self.searcher.config.info_radius) & ~seen)
        if not len(near):
            return cover
        floor_db = float(self.public.settings[int(view.city[r])]["floor_db"])
        out = cover.astype(np.float64)
        for n in range(len(cover)):
            bits = self.searcher.information(cm, self.log_b[r][n], near, floor_db, view.config.p_t_db)
            out[n, near] = np.minimum(1.0, out[n, near] + self.searcher.config.info_weight * bits)
        return out

    @staticmethod
    def _product_plan(served: dict, users: int, paths: list[tuple[np.ndarray, ...]]) -> dict[int, int]:
        """``{UAV: its cell}`` of the assignment of the largest product of its UAVs' best scores: a UAV's score of a cell
        is the probability that it serves the UAV's users (``served[users]``) times the discount of its path to it."""
        discounts = [np.where(discount < 0, 0.0, discount) for discount, _, _ in paths]
        best_cell = {}  # (users, UAV) -> (its best cell for those users, the cell's value)
        for mine, p in served.items():
            for uav, discount in enumerate(discounts):
                value = p * discount
                c = int(np.argmax(value))
                best_cell[mine, uav] = c, float(value[c])
        best, plan = -1.0, {}
        for groups in assignments(users, len(paths)):
            score = np.prod([best_cell[mine, uav][1] for uav, mine in groups])
            if score > best:
                best, plan = score, {uav: best_cell[mine, uav][0] for uav, mine in groups}
        return plan

    def _reach(self, paths: list[tuple[np.ndarray, ...]]) -> tuple[np.ndarray, np.ndarray, list]:
        """(the path lengths ``D`` from 0 to the most moves to any reachable cell of any UAV of ``paths``
        ((discount, predecessors, moves) a UAV), the searcher's discount of each, each UAV's ``_nearest_first``)."""
        lengths = np.arange(int(max(np.max(moves[np.isfinite(moves)]) for _, _, moves in paths)) + 1)
        discount = self.searcher.discount(lengths.astype(np.float32))
        return lengths, discount, [_nearest_first(moves, lengths) for _, _, moves in paths]

    @staticmethod
    def _makespan_plan(served: dict, users: int, reach: tuple[np.ndarray, np.ndarray, list]) -> dict[int, int]:
        """``{UAV: its cell}`` of the assignment and the cells of the largest product of the UAVs' probabilities of
        serving their users times the discount of the longest of their paths (``reach``: ``_reach``): for every length
        ``D``, each UAV takes its most likely cell within ``D`` moves (the nearest of equals)."""
        _, discount, ranked = reach
        within = {}  # (users, UAV) -> (the best probability within D moves [D], its cell [D])
        for uav, nearest in enumerate(ranked):
            for mine, p in served.items():
                within[mine, uav] = _best_within(p, nearest)
        best, plan = -1.0, {}
        for groups in assignments(users, len(ranked)):
            score = discount * np.prod([within[mine, uav][0] for uav, mine in groups], axis=0)
            d = int(np.argmax(score))
            if score[d] > best:
                best, plan = float(score[d]), {uav: int(within[mine, uav][1][d]) for uav, mine in groups}
        return plan

    @staticmethod
    def _union_plan(
        cover: np.ndarray, paths: list[tuple[np.ndarray, ...]], reach: tuple[np.ndarray, np.ndarray, list], start: dict[int, int]
    ) -> dict[int, int]:
        """``{UAV: its cell}`` for every UAV, from the cells ``start`` (the makespan plan's; a UAV without users at
        its own), by coordinate ascent on the probability that every user is served by some UAV, ``prod_n (1 -
        prod_k (1 - P_n(c_k)))`` (the cells' covers taken as independent), times the discount of the longest path:
        each UAV in turn takes the cell (the nearest of equals) that raises it most with the others' cells held,
        round the fleet until a round moves no UAV (at most ``UNION_ROUNDS``). ``reach``: ``_reach`` of ``paths``."""
        lengths, discount, ranked = reach
        moves = [m for _, _, m in paths]
        cells = dict(start)
        miss = np.prod([1.0 - cover[:, c] for c in cells.values()], axis=0)  # [N] no UAV serves the user
        best = float(discount[int(max(moves[u][c] for u, c in cells.items()))] * np.prod(1.0 - miss))
        for _ in range(UNION_ROUNDS):
            before = dict(cells)
            for u in cells:
                others = [c for j, c in cells.items() if j != u]
                miss = np.prod([1.0 - cover[:, c] for c in others], axis=0)  # [N] without UAV u
                value, at = _best_within(np.prod(1.0 - (1.0 - cover) * miss[:, None], axis=0), ranked[u])
                far = int(max((moves[j][c] for j, c in cells.items() if j != u), default=0))
                total = value * discount[np.maximum(lengths, far)]
                d = int(np.argmax(total))
                if total[d] > best * (1 + 1e-9):  # a UAV moves only for a gain beyond rounding
                    best, cells[u] = float(total[d]), int(at[d])
            if cells == before:
                break
        return cells

    @staticmethod
    def _step(cm, here: int, target: int, pred: np.ndarray, mask: np.ndarray) -> int:  # noqa: ANN001
        """The move that starts a shortest legal path from legal cell ``here`` to ``target`` (stay at it)."""
        if target == here:
            return STAY
        step = target
        while pred[step] != here and pred[step] >= 0:
            step = int(pred[step])
        dy, dx = cm.legal[step] - cm.legal[here]
        move = np.flatnonzero((FLEET_MOVES[:STAY, 0] == dy) & (FLEET_MOVES[:STAY, 1] == dx))
        return int(move[0]) if len(move) and mask[move[0]] else STAY

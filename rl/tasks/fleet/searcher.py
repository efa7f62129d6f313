"""The map searcher run for the fleet (``FleetSearcher``)."""

from __future__ import annotations

import numpy as np

from uavplace.rl.tasks.fleet.config import FLEET_MOVES, STAY
from uavplace.rl.tasks.fleet.env import FleetView
from uavplace.rl.tasks.fleet.maps import FleetMaps, assignments, user_subsets


class FleetSearcher:
    """The map searcher run for the fleet (``rl.tasks.placement.searcher``): one belief per user over its candidate
    cells, updated by every UAV's first measurement of each cell (a cell measured again tells nothing new), and one plan for the fleet.

    Per user ``n`` the posterior probability ``P_n(c)`` that each legal cell ``c`` serves it (1 or 0 at a visited
    cell: its SINR is known). A set of users ``S`` is served at ``c`` with probability ``prod_{n in S} P_n(c)``. Over
    the K^N assignments of users to UAVs and the cells of the UAVs that have users, the plan takes the largest score
    (``SearchConfig.fleet_plan``): with ``makespan``, the product of the UAVs' probabilities times the searcher's
    distance discount of the longest of their paths, since the fleet succeeds when its last UAV arrives; with
    ``product``, the product over UAVs of each one's probability times the discount of its own path. Each UAV moves
    one cell along a shortest legal path to its cell (staying when it stands on it; a UAV without users stays).
    Needs the bundles' public maps (``FleetMaps.of``)."""

    name = "map searcher"

    def __init__(self, predictor, config=None, cache=None) -> None:  # noqa: ANN001 - rl.tasks.placement.searcher's types
        from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

        self.searcher = MapSearchPolicy(predictor, config, cache)
        self.public = None
        self.log_b: list[list[np.ndarray]] = []

    def bind(self, maps: FleetMaps) -> FleetSearcher:
        """Read ``maps``' public maps (its bundles' heights, grid and settings; never a user's map)."""
        from uavplace.rl.tasks.placement.config import EnvConfig
        from uavplace.rl.tasks.placement.maps import MapSet
        from uavplace.rl.view import PublicMaps

        if maps.bundles is None:
            raise ValueError("the fleet searcher predicts from bundles: FleetMaps.of(bundles, config)")
        env = EnvConfig(window=maps.config.window, p_t_db=maps.config.p_t_db, rotate=False)
        self.public, self.symmetries = PublicMaps.of(MapSet(maps.bundles, env)), env.symmetries
        return self

    def reset(self, rows: np.ndarray, num_envs: int, uavs: int) -> None:
        if len(self.log_b) != num_envs:
            self.log_b = [[] for _ in range(num_envs)]
        for r in rows:
            self.log_b[int(r)] = []

    def act(self, mask: np.ndarray, view: FleetView) -> np.ndarray:
        from uavplace.rl.belief import shared_posterior_cover

        if self.public is None:
            raise ValueError("FleetSearcher.bind(maps) first: it predicts from the bundles' public maps")
        public, cfg, p = self.public, view.config, view.config.window // 2
        e, k = mask.shape[:2]
        out = np.full((e, k), STAY, np.int64)
        by_canvas: dict[int, list[int]] = {}
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
        for canvas, rows in by_canvas.items():  # the plans: a city's rows' users in one matrix product
            cm = self.searcher.canvas_maps(public, canvas)
            covers = shared_posterior_cover(np.concatenate([np.stack(self.log_b[r]) for r in rows]), cm.cover)
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
        served = {mine: np.prod(cover[list(mine)], axis=0) for mine in user_subsets(cfg.users)}  # [M] a set of users
        plan = (
            self._makespan_plan(served, cfg.users, paths)
            if self.searcher.config.fleet_plan == "makespan"
            else self._product_plan(served, cfg.users, paths)
        )
        return np.array([self._step(cm, int(cols[u]), plan.get(u, int(cols[u])), paths[u][1], mask[u]) for u in range(k)])

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

    def _makespan_plan(self, served: dict, users: int, paths: list[tuple[np.ndarray, ...]]) -> dict[int, int]:
        """``{UAV: its cell}`` of the assignment and the cells of the largest product of the UAVs' probabilities of
        serving their users times the discount of the longest of their paths: for every length ``D``, each UAV takes
        its most likely cell within ``D`` moves (the nearest of equals)."""
        horizon = int(max(np.max(moves[np.isfinite(moves)]) for _, _, moves in paths))
        lengths = np.arange(horizon + 1)
        within = {}  # (users, UAV) -> (the best probability within D moves [D], its cell [D])
        for uav, (_, _, moves) in enumerate(paths):
            order = np.argsort(moves, kind="stable")  # nearest first, unreachable (inf) last
            last = np.searchsorted(moves[order], lengths, side="right") - 1  # the farthest cell within D moves
            for mine, p in served.items():
                p = p[order]
                best = np.maximum.accumulate(p)
                rises = np.flatnonzero(np.r_[True, p[1:] > best[:-1]])  # where the running best rises: its nearest cell
                at = rises[np.searchsorted(rises, last, side="right") - 1]
                within[mine, uav] = np.where(last >= 0, best[last], 0.0), order[at]  # none within D moves: 0
        discount = self.searcher.discount(lengths.astype(np.float32))
        best, plan = -1.0, {}
        for groups in assignments(users, len(paths)):
            score = discount * np.prod([within[mine, uav][0] for uav, mine in groups], axis=0)
            d = int(np.argmax(score))
            if score[d] > best:
                best, plan = float(score[d]), {uav: int(within[mine, uav][1][d]) for uav, mine in groups}
        return plan

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

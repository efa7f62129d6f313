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
    the K^N assignments of users to UAVs, each UAV's best cell for its users scores that probability times the
    searcher's distance discount from the UAV; the assignment of the largest product of its UAVs' scores is
    followed, each UAV one cell along a shortest legal path to its cell (staying when it stands on it). Needs the
    bundles' public maps (``FleetMaps.of``)."""

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
        from uavplace.rl.belief import posterior_cover

        if self.public is None:
            raise ValueError("FleetSearcher.bind(maps) first: it predicts from the bundles' public maps")
        public, cfg, p = self.public, view.config, view.config.window // 2
        e, k = mask.shape[:2]
        out = np.full((e, k), STAY, np.int64)
        by_canvas: dict[int, list[int]] = {}
        for r in range(e):  # the beliefs, row by row
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
            covers = posterior_cover(np.concatenate([np.stack(self.log_b[r]) for r in rows]), cm.cover)
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
        paths = [self.searcher.paths_from(self.public, canvas, cm, int(c)) for c in cols]  # (discount, predecessors)
        discounts = [np.where(d < 0, 0.0, d) for d, _ in paths]
        best_cell = {}  # (users, UAV) -> (its best cell for those users, the cell's value)
        for mine in user_subsets(cfg.users):
            served = np.prod(cover[list(mine)], axis=0)
            for uav in range(k):
                value = served * discounts[uav]
                c = int(np.argmax(value))
                best_cell[mine, uav] = c, float(value[c])
        best, plan = -1.0, [int(c) for c in cols]
        for groups in assignments(cfg.users, k):
            score, targets = 1.0, [int(c) for c in cols]  # a UAV without users stays where it is
            for uav, mine in groups:
                targets[uav], value = best_cell[mine, uav]
                score *= value
            if score > best:
                best, plan = score, targets
        return np.array([self._step(cm, int(cols[u]), plan[u], paths[u][1], mask[u]) for u in range(k)])

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

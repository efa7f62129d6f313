"""A searcher that uses the map: the belief of ``rl.belief`` over where the user is, and a planner.

Each row keeps a belief over the candidate user cells of the canvas it flies over, from the predicted radio map of a
user at each (``rl.belief``: uniform at the start, updated by every measurement). The planner then scores each
unvisited legal cell ``x'`` by the posterior probability that it reaches P_T, ``P(x') = sum_c b_c (1 - p_dead)
Phi((mu_c(x') - P_T) / sigma)``, discounted by its fewest legal moves ``d`` from the UAV (``SearchConfig.discount``),
and moves one cell along a shortest path to the best; it plans again at every step. Two planners that localise
(``SearchConfig.planner``): ``info`` adds the information a measurement gives, ``lookahead`` weighs the outcomes of
the next measurement. With ``SearchConfig.error_share`` > 0 the cover planner krigs the predictor's errors: each
candidate's chance near the cells measured moved by what they say of its map there (``BeliefModel.kriged_cover``).

It reads only what the UAV knows (an ``rl.world.view.AgentView``): its position, its own measurements and the public
maps. ``rl.tasks.fleet`` runs the searcher for a fleet of UAVs, ``rl.tasks.tracking.searcher`` for a user who walks.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from scipy import sparse
from scipy.ndimage import maximum_filter
from scipy.sparse.csgraph import shortest_path

from uavplace.rl.belief import BeliefModel, CandidateMaps, PredictionCache, posterior_cover, rows_of
from uavplace.rl.config import SearchConfig
from uavplace.rl.predictor import PhysicsConstants, Predictor
from uavplace.rl.world.maps import MOVES
from uavplace.rl.world.view import AgentView, PublicMaps
from uavplace.schemas.constants import reaches_target

#: The searcher's name in tables (its ablation's: SEARCHER + ", no buildings").
SEARCHER = "map searcher"


class MapSearchPolicy(BeliefModel):
    """The searcher of the module's docstring as an ``rl.tasks.placement.policies.Policy``: the belief of
    ``rl.belief.BeliefModel`` and a planner."""

    name = SEARCHER  # an instance's: SEARCHER, its ablation's, or the name given
    #: The ``SearchConfig`` fields it does not read (the fleet's plan).
    unread_settings = frozenset({"fleet_plan"})

    def __init__(
        self,
        predictor: Predictor | PhysicsConstants,
        config: SearchConfig | None = None,
        cache: PredictionCache | None = None,
        name: str | None = None,
        device: str = "cpu",
    ) -> None:
        super().__init__(predictor, config, cache, device)
        self.name = name or (SEARCHER if self.config.buildings else SEARCHER + ", no buildings")
        self._graphs: dict[tuple, sparse.csr_matrix] = {}
        self._paths: OrderedDict[tuple, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self.belief: list[np.ndarray | None] = []
        self.seen: list[np.ndarray | None] = []  # per row, the legal cells visited so far (with its belief)
        self.measured: list[dict[int, float]] = []  # per row, each legal cell measured so far: its value, in order
        # per row where the errors are kriged: the [C] latents of its last error_memory measured cells, in the order
        # measured ([C, error_memory], the first latent_count[row] columns filled): appended in place, never stacked
        self.latents: list[np.ndarray | None] = []
        self.latent_count = np.zeros(0, np.int64)
        self.belief_canvas = np.zeros(0, np.int64)
        self.started = np.zeros(0, bool)

    def __getstate__(self) -> dict:
        """``BeliefModel``'s, and not the paths held in memory either."""
        state = super().__getstate__()
        state.update(_graphs={}, _paths=OrderedDict())
        return state

    def _graph(self, public: PublicMaps, canvas: int, maps: CandidateMaps) -> sparse.csr_matrix:
        key = (public.settings[public.bundle_of(canvas)]["version"], public.symmetry_of(canvas))
        if key not in self._graphs:
            idx, legal = maps.index, maps.legal
            rows, cols = [], []
            for dy, dx in MOVES:
                ny, nx = legal[:, 0] + dy, legal[:, 1] + dx
                ok = (ny >= 0) & (ny < idx.shape[0]) & (nx >= 0) & (nx < idx.shape[1])
                j = np.full(len(legal), -1)
                j[ok] = idx[ny[ok], nx[ok]]
                keep = j >= 0
                rows.append(np.flatnonzero(keep))
                cols.append(j[keep])
            r, c = np.concatenate(rows), np.concatenate(cols)
            self._graphs[key] = sparse.csr_matrix((np.ones(len(r), np.float32), (r, c)), shape=(len(legal), len(legal)))
        return self._graphs[key]

    def discount(self, moves: np.ndarray) -> np.ndarray:
        """The discount of a cell ``moves`` moves away (``SearchConfig.discount``, ``reach_cells``)."""
        scale = moves / self.config.reach_cells
        return np.exp(-scale) if self.config.discount == "exp" else 1.0 / (1.0 + scale)

    def paths_from(self, public: PublicMaps, canvas: int, maps: CandidateMaps, cell: int) -> tuple[np.ndarray, ...]:
        """(discount [M], predecessors [M], fewest moves [M]) of the shortest legal paths from legal cell ``cell``: each
        cell's discount by its fewest moves (``SearchConfig.discount``; -1 where unreachable, where the moves are inf);
        kept for the most recent 4096 cells."""
        key = (canvas, cell, public.settings[public.bundle_of(canvas)]["version"])
        if key not in self._paths:
            self.prefetch_paths(public, canvas, maps, np.array([cell]))
        self._paths.move_to_end(key)
        return self._paths[key]

    def prefetch_paths(self, public: PublicMaps, canvas: int, maps: CandidateMaps, cells: np.ndarray) -> None:
        """``paths_from`` of each legal cell of ``cells`` not held yet, in one call of the shortest-path search (the
        same paths as one cell a call, the graph checked once)."""
        version = public.settings[public.bundle_of(canvas)]["version"]
        missing = [c for c in dict.fromkeys(int(c) for c in cells) if (canvas, c, version) not in self._paths]
        if not missing:
            return
        graph = self._graph(public, canvas, maps)
        moves, preds = shortest_path(graph, unweighted=True, indices=missing, return_predecessors=True)
        for cell, d, pred in zip(missing, moves.astype(np.float32), preds, strict=True):
            d = d.copy()  # a row of its own: an entry keeps no other cell's arrays alive
            self._paths[canvas, cell, version] = (
                np.where(np.isfinite(d), self.discount(d), np.float32(-1.0)),
                pred.astype(np.int32),
                d,
            )
        while len(self._paths) > 4096:
            self._paths.popitem(last=False)

    # -- the policy --------------------------------------------------------------------------------
    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        if len(self.belief) != num_envs:
            self.belief, self.seen = [None] * num_envs, [None] * num_envs
            self.measured = [{} for _ in range(num_envs)]
            self.latents, self.latent_count = [None] * num_envs, np.zeros(num_envs, np.int64)
            self.belief_canvas = np.full(num_envs, -1, np.int64)
        for r in np.asarray(rows, np.int64):
            self.belief[r] = self.seen[r] = None
            self.measured[r], self.latents[r], self.latent_count[r] = {}, None, 0

    def prior(self, maps: CandidateMaps, row: int) -> np.ndarray:
        """``[C]`` the log-belief of row ``row`` before its first measurement: uniform over the candidates (an oracle
        that is told more overrides it)."""
        return np.zeros(len(maps.cells), np.float32)

    def act(self, obs: np.ndarray, mask: np.ndarray, env: AgentView) -> np.ndarray:
        n = len(mask)
        if len(self.belief) != n:
            self.reset(np.arange(n), n)
        public = env.public
        pos, t, canvas = env.pos, env.t, env.canvas
        measured, visits = env.measured(), env.visits
        actions = np.zeros(n, np.int64)
        p = public.pad
        here = np.full(n, -1, np.int64)
        by_canvas: dict[int, list[int]] = {}
        going_on: dict[int, list[int]] = {}  # rows whose belief takes their last measurement: a canvas's at once
        again: set[int] = set()  # rows of going_on that measured their cell before
        for r in range(n):  # the beliefs, row by row
            if env.exhausted[r] or not mask[r].any():
                continue
            c = int(canvas[r])
            maps = self.canvas_maps(public, c)
            here[r] = maps.index[pos[r, 0] - p, pos[r, 1] - p]
            by_canvas.setdefault(c, []).append(r)
            if self.belief[r] is not None and t[r] > 0 and self.belief_canvas[r] == c:
                going_on.setdefault(c, []).append(r)
                self.seen[r][here[r]] = True  # a step visits one cell: the one it stands in
                if int(here[r]) in self.measured[r]:
                    again.add(r)
                continue
            floor_db = float(public.settings[public.bundle_of(c)]["floor_db"])
            log_b = self.prior(maps, r)
            self.measured[r], self.latents[r], self.latent_count[r] = {}, None, 0
            for y, x in np.argwhere(visits[r] > 0):  # every cell measured so far (at t = 0 the start), as memory holds it
                column, value = int(maps.index[y - p, x - p]), float(env.memory[r, y, x])
                log_b = self.update(maps, log_b, column, value, floor_db, self.measured[r], self.latents_of(r))
                self.remember(maps, r, column, value, floor_db)
            self.belief_canvas[r], self.belief[r] = c, log_b
            self.seen[r] = visits[r, maps.legal[:, 0] + p, maps.legal[:, 1] + p] > 0
        for c, rows in going_on.items():  # the same numbers as row by row (``update_rows``)
            floor_db = float(public.settings[public.bundle_of(c)]["floor_db"])
            maps = self.canvas_maps(public, c)
            if self.config.kriged_belief:  # each row given its own measurements before
                for r in rows:  # a cell measured again tells nothing new under the correlation (1 at the same cell)
                    if r not in again:
                        value, before = float(measured[r]), self.measured[r]
                        self.belief[r] = self.update(
                            maps, self.belief[r], int(here[r]), value, floor_db, before, self.latents_of(r)
                        )
            else:
                log_b = np.stack([self.belief[r] for r in rows])
                at, values = here[rows], np.asarray(measured, np.float64)[rows]
                for r, row in zip(rows, self.update_rows(maps, log_b, at, values, floor_db), strict=True):
                    self.belief[r] = row
            for r in rows:
                if r not in again:
                    self.remember(maps, r, int(here[r]), float(measured[r]), floor_db)
        for c, rows in by_canvas.items():  # the plans, a canvas's rows in one product
            maps = self.canvas_maps(public, c)
            self.prefetch_paths(public, c, maps, here[rows])
            scores = posterior_cover(np.stack([self.belief[r] for r in rows]), maps, self.on_device, self.config.precision)
            floor_db = float(public.settings[public.bundle_of(c)]["floor_db"])
            p_t = public.config.p_t_db
            for i, r in enumerate(rows):
                seen = self.seen[r]
                score = scores[i]
                if self.config.kriged_planner:
                    score = self.with_kriging(maps, score, self.belief[r], r, seen, floor_db)
                if self.config.planner == "info":
                    score = self.with_information(public, c, maps, int(here[r]), score, self.belief[r], seen, floor_db, p_t)
                actions[r] = self.first_move(public, c, maps, int(here[r]), score, seen, mask[r])
                if self.config.planner == "lookahead":
                    actions[r] = self.lookahead_move(
                        public, c, maps, int(here[r]), self.belief[r], seen, mask[r], floor_db, p_t, int(actions[r])
                    )
        return actions

    def lookahead_move(
        self,
        public: PublicMaps,
        canvas: int,
        maps: CandidateMaps,
        here: int,
        log_b: np.ndarray,
        seen: np.ndarray,
        mask: np.ndarray,
        floor_db: float,
        p_t_db: float,
        default: int,
    ) -> int:
        """The ``lookahead`` planner's move from legal cell ``here``: for each legal move, the expectation over the
        outcome of the measurement at the cell it leads to (``outcome_probabilities``; the belief updated as
        ``update`` would, on the outcome's bin) of the best discounted posterior probability of reaching P_T among
        the ``lookahead_targets`` unvisited cells the cover planner scores best, counting 1 for an outcome at or
        above P_T (the episode ends there). ``default`` (the cover planner's move) unless another is better."""
        b = np.exp(log_b - log_b.max())
        keep = b > 1e-6
        b = (b[keep] / b[keep].sum()).astype(np.float64)
        cover = maps.cover[keep].astype(np.float64)  # the kept rows only: a float32 belief's maps have no cover64
        discount, _, _ = self.paths_from(public, canvas, maps, here)
        score = np.where(seen | (discount < 0), -1.0, (b @ cover) * discount)
        k = min(self.config.lookahead_targets, len(score))
        targets = np.argpartition(-score, k - 1)[:k]
        targets = targets[score[targets] >= 0]
        if not len(targets):
            return default
        lower = np.concatenate([[floor_db], self.bin_edges(floor_db, p_t_db)])  # the live bins' lower edges
        success = np.concatenate([[False], reaches_target(lower, p_t_db)])  # the bins above P_T: the episode ends
        kept = rows_of(maps, keep)
        values = np.full(len(MOVES), -np.inf)
        for a, (dy, dx) in enumerate(MOVES):
            y, x = maps.legal[here, 0] + dy, maps.legal[here, 1] + dx
            if not mask[a] or not (0 <= y < maps.index.shape[0] and 0 <= x < maps.index.shape[1]) or maps.index[y, x] < 0:
                continue
            n = int(maps.index[y, x])
            disc_n, _, _ = self.paths_from(public, canvas, maps, n)
            t = targets[(targets != n) & (disc_n[targets] >= 0)]
            if not len(t):
                continue
            if seen[n]:  # measured before: nothing new to learn there
                values[a] = float(((b @ cover[:, t]) * disc_n[t]).max())
                continue
            probs = self.outcome_probabilities(kept, np.array([n]), floor_db, p_t_db)[:, 0, :]  # [C', J]
            q = b @ probs
            post = b[None, :] * probs.T**self.config.temper
            post /= np.maximum(post.sum(axis=1, keepdims=True), 1e-300)
            best = ((post @ cover[:, t]) * disc_n[t][None, :]).max(axis=1)
            values[a] = float(q @ np.where(success, 1.0, best))
        if not np.isfinite(values).any() or values[default] >= values.max() - 1e-12:
            return default
        return int(np.argmax(values))

    def remember(self, maps: CandidateMaps, row: int, column: int, value: float, floor_db: float) -> None:
        """Row ``row`` measured ``value`` at legal cell ``column`` for the first time: kept in order, with its error
        latents where the errors are kriged (computed once: they do not change; the last ``error_memory`` kept)."""
        self.measured[row][column] = value
        if self.config.error_share > 0:
            latent = self.error_latent(maps, np.array([column]), np.array([value]), floor_db)[:, 0]
            if self.latents[row] is None:
                self.latents[row] = np.empty((len(latent), self.config.error_memory))
            n = int(self.latent_count[row])
            if n == self.config.error_memory:  # full: the oldest goes
                self.latents[row][:, :-1] = self.latents[row][:, 1:]
                n -= 1
            self.latents[row][:, n] = latent
            self.latent_count[row] = n + 1

    def latents_of(self, row: int) -> np.ndarray | None:
        """``[C, V]`` the error latents of row ``row``'s ``error_memory`` cells measured last (a view, no copy), or None
        where not kriged or before its first measurement."""
        return None if self.latents[row] is None else self.latents[row][:, : self.latent_count[row]]

    def with_kriging(
        self, maps: CandidateMaps, score: np.ndarray, log_b: np.ndarray, row: int, seen: np.ndarray, floor_db: float
    ) -> np.ndarray:
        """``score`` [M] with the unvisited cells within ``error_reach`` cells (Chebyshev) of the ``error_memory`` cells
        row ``row`` measured last scored by ``kriged_cover``: their chance of reaching P_T moved by what the
        measurements say of each candidate's map errors nearby."""
        cfg, measured = self.config, self.measured[row]
        columns = np.fromiter(measured, np.int64)[-cfg.error_memory :]
        values = np.fromiter(measured.values(), np.float64)[-cfg.error_memory :]
        near = np.zeros(maps.index.shape, np.uint8)
        near[maps.legal[columns, 0], maps.legal[columns, 1]] = 1
        near = maximum_filter(near, size=2 * cfg.error_reach + 1)[maps.legal[:, 0], maps.legal[:, 1]] > 0
        targets = np.flatnonzero(near & ~seen)
        if not len(targets):
            return score
        out = score.astype(np.float64)
        out[targets] = self.kriged_cover(maps, log_b, columns, values, floor_db, targets, self.latents_of(row))
        return out

    def with_information(
        self,
        public: PublicMaps,
        canvas: int,
        maps: CandidateMaps,
        here: int,
        score: np.ndarray,
        log_b: np.ndarray,
        seen: np.ndarray,
        floor_db: float,
        p_t_db: float,
    ) -> np.ndarray:
        """``score`` [M] plus ``info_weight`` times the information of a measurement at each unvisited cell within
        ``info_radius`` moves of legal cell ``here`` (the ``info`` planner)."""
        _, _, d = self.paths_from(public, canvas, maps, here)
        near = np.flatnonzero((d <= self.config.info_radius) & ~seen)
        if not len(near):
            return score
        out = score.astype(np.float64)
        out[near] += self.config.info_weight * self.information(maps, log_b, near, floor_db, p_t_db)
        return out

    def first_move(
        self,
        public: PublicMaps,
        canvas: int,
        maps: CandidateMaps,
        here: int,
        score: np.ndarray,
        seen: np.ndarray,
        mask: np.ndarray,
    ) -> int:
        """The first move along a shortest legal path to the unvisited cell of best discounted ``score``."""
        discount, pred, _ = self.paths_from(public, canvas, maps, here)
        score = np.where(seen | (discount < 0), -1.0, score * discount)
        target = int(np.argmax(score))
        if target == here or score[target] < 0:
            return int(np.argmax(mask))
        step = target  # walk back from the target to the cell next to the UAV
        while pred[step] != here and pred[step] >= 0:
            step = int(pred[step])
        dy, dx = maps.legal[step] - maps.legal[here]
        move = np.flatnonzero((MOVES[:, 0] == dy) & (MOVES[:, 1] == dx))
        return int(move[0]) if len(move) and mask[move[0]] else int(np.argmax(mask))

"""The fleet's policies without a map: the steered random walk, greedy hill-climbing, and independent placement
agents (``FleetPlacement``)."""

from __future__ import annotations

import numpy as np

from uavplace.rl.randomness import combine, stream_key, uniforms
from uavplace.rl.tasks.fleet.config import FLEET_MOVES, STAY
from uavplace.rl.tasks.fleet.env import FleetView
from uavplace.rl.tasks.fleet.maps import FleetMaps
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.world.view import view_for


class FleetRandomWalk:
    """The steered random walk per UAV: repeat its last move w.p. ``p_repeat`` (if legal), else a random legal move;
    never stays. Draws per episode and step (``rl.randomness``)."""

    name = "steered random walk"

    def __init__(self, seed: int = 0, p_repeat: float = 0.4) -> None:
        self.stream = stream_key("fleet " + self.name, seed)
        self.p_repeat = p_repeat
        self.last = np.zeros((0, 0), np.int64)

    def reset(self, rows: np.ndarray, num_envs: int, uavs: int) -> None:
        if self.last.shape != (num_envs, uavs):
            self.last = np.full((num_envs, uavs), -1, np.int64)
        self.last[rows] = -1

    def act(self, mask: np.ndarray, view: FleetView) -> np.ndarray:
        e, k = mask.shape[:2]
        u = uniforms(self.stream, view.keys, view.t, 5 * k).reshape(e, k, 5)
        moves = mask[..., :STAY]
        a = np.argmax(u[..., :STAY] * moves, axis=2)
        last = np.maximum(self.last, 0)
        repeat = (self.last >= 0) & (u[..., STAY] < self.p_repeat) & np.take_along_axis(moves, last[..., None], 2)[..., 0]
        a = np.where(repeat, self.last, a)
        a = np.where(moves.any(axis=2), a, STAY)
        self.last = a
        return a


class FleetGreedy:
    """Hill-climbing per UAV on the users no other UAV serves now: each UAV scores a cell by the sum, over those
    users, of the SINR the fleet measured there counted up to P_T. It goes to a random unvisited legal neighbour
    while it has one (repeating its last move while that raised its score and leads to an unvisited cell), else to
    the visited neighbour of best score; it stays where its score already serves all of its users. Reads only the
    fleet's measurements (``FleetView``)."""

    name = "greedy hill-climbing"

    def __init__(self, seed: int = 0) -> None:
        self.stream = stream_key("fleet " + self.name, seed)
        self.last = np.zeros((0, 0), np.int64)
        self.prev = np.zeros((0, 0), np.float32)

    def reset(self, rows: np.ndarray, num_envs: int, uavs: int) -> None:
        if self.last.shape != (num_envs, uavs):
            self.last = np.full((num_envs, uavs), -1, np.int64)
            self.prev = np.full((num_envs, uavs), np.nan, np.float32)
        self.last[rows] = -1
        self.prev[rows] = np.nan

    def act(self, mask: np.ndarray, view: FleetView) -> np.ndarray:
        cfg = view.config
        e, k = mask.shape[:2]
        rows = np.arange(e)
        here = view.at_uavs()  # [E, K, N]
        served = cfg.reaches(here)
        to = view.pos[:, :, None, :] + FLEET_MOVES[None, None, :STAY]  # [E, K, 4, 2]
        seen = view.visits[rows[:, None, None], to[..., 0], to[..., 1]] > 0  # [E, K, 4]
        value = np.minimum(
            view.memory[rows[:, None, None, None], np.arange(cfg.users)[None, None, None], to[..., 0, None], to[..., 1, None]],
            cfg.p_t_db,
        )  # [E, K, 4, N]
        u = uniforms(self.stream, view.keys, view.t, 8 * k).reshape(e, k, 8)
        out = np.full((e, k), STAY, np.int64)
        for uav in range(k):
            others = np.delete(served, uav, axis=1).any(axis=1) if k > 1 else np.zeros((e, cfg.users), bool)
            mine = ~others  # the users this UAV works for
            score_here = np.where(mine, np.minimum(here[:, uav], cfg.p_t_db), 0).sum(axis=1)
            score = np.where(mine[:, None], value[:, uav], 0).sum(axis=2)  # [E, 4]
            legal = mask[:, uav, :STAY]
            unvisited = legal & ~seen[:, uav]
            last = np.maximum(self.last[:, uav], 0)
            keep = (self.last[:, uav] >= 0) & (score_here > self.prev[:, uav]) & unvisited[rows, last]
            explore = np.argmax(u[:, uav, :STAY] * unvisited, axis=1)
            best = np.argmax(np.where(legal & seen[:, uav], score, -np.inf) + u[:, uav, STAY:] * 1e-3, axis=1)
            a = np.where(keep, self.last[:, uav], np.where(unvisited.any(axis=1), explore, best))
            done = (served[:, uav] | ~mine).all(axis=1)  # every user it works for is served where it stands
            out[:, uav] = np.where(done | ~legal.any(axis=1), STAY, a)
            self.prev[:, uav] = score_here
        self.last = np.where(out == STAY, -1, out)
        return out


class _DealtEnv(BatchedEnv):
    """A placement env that keeps an agent's channels for ``FleetPlacement``: its rows' episodes are named (for the
    agent's random draws, ``rl.randomness``) by the fleet episode's key and the UAV (``keys``); ``others`` ``[N,
    K - 1, 2]`` holds the cells of each row's other UAVs, which its fleet channel marks (``EnvConfig.fleet_channel``)."""

    def __init__(self, maps, num_envs: int, uavs: int, autoreset: bool = False, compact: bool = False) -> None:  # noqa: ANN001
        super().__init__(maps, num_envs, autoreset=autoreset, compact=compact)
        self.keys = np.zeros(num_envs, np.uint64)
        self.others = np.zeros((num_envs, uavs - 1, 2), np.int64)

    def episode_keys(self) -> np.ndarray:
        return self.keys.copy()

    def fleet_plane(self, idx: np.ndarray, y0: np.ndarray, x0: np.ndarray, out: np.ndarray) -> None:
        super().fleet_plane(idx, y0, x0, out)
        w = self.config.window
        for j in range(self.others.shape[1]):
            oy, ox = self.others[idx, j, 0] - y0, self.others[idx, j, 1] - x0
            inside = np.flatnonzero((oy >= 0) & (oy < w) & (ox >= 0) & (ox < w))
            out[inside, oy[inside], ox[inside]] = np.float32(self.config.p_h_db)


class FleetPlacement:
    """Independent placement agents: every UAV runs one trained placement agent (``policy`` with its ``EnvConfig``,
    e.g. the shipped ``best``) unchanged on the users dealt to it, as ``rl.tasks.tracking.PlacementInTracking`` runs one in
    the tracking env.

    The deal, at every step and in the UAVs' order: each UAV keeps the users it serves where it stands (those no
    earlier UAV keeps); the users nobody serves are then dealt one at a time, each to the UAV that holds the fewest
    users (the first in order on a tie), which takes the one it measures strongest where it stands (the nearest by
    what it hears). A UAV's users are served at a cell when the weakest of them is, so its agent plays the placement
    task of that weakest SINR: its memory is, at every cell the fleet visited, the lowest of its users' shared
    measurements there (P_H unvisited, P_L blocked), its visits are the fleet's and its homing cone starts from the
    best of those. A UAV stays when it has no user or serves all of its users, and when every move is held by another
    UAV; otherwise it moves by its agent's rule. An agent trained with the fleet channel (``EnvConfig.fleet_channel``)
    also sees where the other UAVs stand. Reads only the fleet's measurements and positions (``FleetView``)."""

    prefix = "independent "

    def __init__(
        self,
        policy,
        env: EnvConfig,
        name: str | None = None,
        *,
        prefix: str | None = None,  # noqa: ANN001
        compact: bool = False,
    ) -> None:
        """``policy``: a ``rl.tasks.placement.policies.Policy`` (None: only ``dealt`` is used, as ``FleetTrainEnv``
        does); ``prefix`` before its name (default ``FleetPlacement.prefix``: a placement agent run as it is); ``compact``: the agent's
        observations as the learner stores them (``BatchedEnv``'s)."""
        name = name or policy.name
        if env.belief_channel or env.context_zoom:
            raise ValueError(
                f"{name}: an agent with a belief or context channel reads one user's measurements as they "
                "come; the fleet deals each UAV a changing set of users"
            )
        self.policy, self.name = policy, (self.prefix if prefix is None else prefix) + name
        self.env_config = env.model_copy(update={"rotate": False, "city_weights": {}, "split": None})
        self.compact = compact
        self.maps: FleetMaps | None = None
        self.mirror = None

    def bind(self, maps: FleetMaps) -> FleetPlacement:
        """Play on ``maps``' cities: a placement env (``BatchedEnv``) row per UAV and episode row keeps its agent's
        channels; that env's maps hold no user's map (SINR, dead cells and the genie's distances blanked)."""
        from uavplace.rl.world.maps import MapSet

        if maps.bundles is None:
            raise ValueError("independent placement agents read the bundles: FleetMaps.of(bundles, config)")
        # no user's map: what the agents see comes from the fleet's measurements alone
        self.maps, self.placement = maps, MapSet(maps.bundles, self.env_config).forget_users()
        self.mirror = None  # made anew on these maps at the next reset
        # per city, the view of its identity symmetry; the placement canvas's cell of the fleet canvas's cell 0
        self.views = np.array(
            [np.flatnonzero(self.placement.view_map == self.placement.symmetries * b)[0] for b in range(len(maps.cities))]
        )
        self.shift = self.placement.pad - maps.pad
        return self

    def reset(self, rows: np.ndarray, num_envs: int, uavs: int) -> None:
        self.reset_deal(rows, num_envs, uavs)
        self.policy.reset((np.asarray(rows)[:, None] * uavs + np.arange(uavs)).ravel(), num_envs * uavs)

    def reset_deal(self, rows: np.ndarray, num_envs: int, uavs: int) -> None:
        """Fleet rows ``rows`` begin new episodes: their UAVs' placement rows are read afresh at the next ``dealt``."""
        if self.maps is None:
            raise ValueError("FleetPlacement.bind(maps) first: its agents play on the bundles' maps")
        if self.mirror is None or self.mirror.num_envs != num_envs * uavs:
            self.mirror = _DealtEnv(self.placement, num_envs * uavs, uavs, autoreset=False, compact=self.compact)
            self.groups = np.zeros((num_envs, uavs, self.maps.config.users), bool)
            self.fresh = np.ones(num_envs, bool)
        self.groups[rows] = False
        self.fresh[rows] = True

    def deal(self, view: FleetView) -> tuple[np.ndarray, np.ndarray]:
        """(groups [E, K, N]: the users dealt to each UAV; served [E, K, N]: whom each UAV serves where it stands)."""
        cfg = view.config
        e, k, n = len(view.t), cfg.uavs, cfg.users
        here = view.at_uavs()
        served = cfg.reaches(here)
        groups = np.zeros((e, k, n), bool)
        kept = np.zeros((e, n), bool)
        for uav in range(k):
            groups[:, uav] = served[:, uav] & ~kept
            kept |= groups[:, uav]
        while not kept.all():
            left = np.flatnonzero(~kept.all(axis=1))
            uav = np.argmin(groups[left].sum(axis=2) * k + np.arange(k), axis=1)  # the fewest users, first on a tie
            pick = np.argmax(np.where(kept[left], -np.inf, here[left, uav]), axis=1)
            groups[left, uav, pick] = kept[left, pick] = True
        return groups, served

    def _rebuild(self, m: int, view: FleetView, r: int, mine: np.ndarray) -> None:
        """Placement row ``m`` (fleet row ``r``'s UAV) reads the fleet's measurements of users ``mine`` afresh."""
        mirror, fleet, s = self.mirror, self.maps, self.shift
        inner = slice(fleet.pad, fleet.side - fleet.pad)
        placed = slice(fleet.pad + s, fleet.side - fleet.pad + s)
        view_id = self.views[int(view.city[r])]
        visited = view.visits[r, inner, inner] > 0
        mirror.view[m], mirror.episode_id[m] = view_id, r
        mirror.memory[m] = self.placement.memory0[view_id]
        mirror.visits[m] = 0
        mirror.visits[m, placed, placed] = view.visits[r, inner, inner]
        mirror.best_sinr[m], mirror.best_pos[m] = self.env_config.p_l_db, mirror.pos[m]
        if len(mine):
            weakest = view.memory[r, mine, inner, inner].min(axis=0)
            mirror.memory[m, placed, placed] = np.where(visited, weakest, mirror.memory[m, placed, placed])
            at = np.unravel_index(np.argmax(np.where(visited, weakest, -np.inf)), weakest.shape)
            mirror.best_sinr[m], mirror.best_pos[m] = weakest[at], np.array(at) + fleet.pad + s

    def act(self, mask: np.ndarray, view: FleetView) -> np.ndarray:
        obs, moves, idle = self.dealt(mask, view)
        e, k = mask.shape[:2]
        actions = self.policy.act(obs, moves, view_for(self.policy, self.mirror)).reshape(e, k)
        return np.where(idle, STAY, actions)

    def dealt(self, mask: np.ndarray, view: FleetView) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Deal the users and bring every UAV's placement row up to date (its agent's env, ``mirror``); returns its
        observations ``[E * K, ...]``, their legal placement moves ``[E * K, 4]`` (all four for a UAV that cannot
        move: it stays) and ``idle`` ``[E, K]``, the UAVs that stay whatever their agent says (no user, all of
        their users served, or no free move). Calling it twice on one step changes nothing."""
        mirror, s = self.mirror, self.shift
        e, k = mask.shape[:2]
        rows = np.arange(e)
        groups, served = self.deal(view)
        y, x = view.pos[..., 0], view.pos[..., 1]
        for uav in range(k):  # the placement rows stand where their UAVs stand
            m = rows * k + uav
            mirror.pos[m, 0], mirror.pos[m, 1], mirror.t[m] = y[:, uav] + s, x[:, uav] + s, view.t
            mirror.keys[m] = combine(view.keys, np.uint64(uav))
            if self.env_config.fleet_channel:  # read only by that channel
                mirror.others[m] = np.delete(view.pos, uav, axis=1) + s
        changed = (groups != self.groups).any(axis=2) | self.fresh[:, None]
        for r, uav in zip(*np.nonzero(changed), strict=True):
            self._rebuild(r * k + uav, view, r, np.flatnonzero(groups[r, uav]))
        for uav in range(k):  # the others: what the fleet measured this step, at every UAV's cell
            keep = ~changed[:, uav]
            m, own = (rows * k + uav)[keep], groups[keep, uav]
            for j in range(k):
                cy, cx = y[keep, j], x[keep, j]
                weakest = np.where(own, view.memory[rows[keep], :, cy, cx], np.inf).min(axis=1)
                mirror.visits[m, cy + s, cx + s] = view.visits[rows[keep], cy, cx]
                has = own.any(axis=1)
                mirror.memory[m[has], cy[has] + s, cx[has] + s] = weakest[has]
                better = has & (weakest > mirror.best_sinr[m])
                mirror.best_sinr[m[better]] = weakest[better]
                mirror.best_pos[m[better]] = np.stack([cy[better], cx[better]], axis=1) + s
        self.groups, self.fresh = groups, np.zeros(e, bool)
        moves = mask[..., :STAY].reshape(e * k, STAY)
        free = moves.any(axis=1)
        idle = ~groups.any(axis=2) | (served | ~groups).all(axis=2) | ~free.reshape(e, k)
        return mirror.observe(), np.where(free[:, None], moves, True), idle

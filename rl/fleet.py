"""The fleet task: several UAVs serve several users of unknown position at once (the paper's second future work).

K UAVs (``FleetConfig.uavs``, 1-4) start on distinct legal cells of one city and move together, each one cell a
step or staying (actions 0-3 the placement moves, 4 stay). A UAV never enters a cell another UAV holds at the
start of the step, and of two UAVs that move into one free cell the first in order enters while the other stays:
no two ever share a cell, and none pass through each other. N users (``users``, 1-6) are drawn from the city's
traced users; nobody knows where they are. Every UAV measures every user's SINR at its cell at every step (the
users are told apart by their pilots) and the fleet shares what it measures. The episode succeeds when, at one
step, every user has a UAV at SINR >= P_T; it is truncated after ``t_max`` steps.

Episodes (``FleetMaps.episode_list``): episode ``i`` of a list is drawn from its own generator (the list's seed
and ``i`` hashed, ``rl.randomness``), so any prefix of a list is the shorter list: a city, N distinct users, K
distinct legal starts from which every user's target cells (SINR >= P_T) are reachable, not every user served at
the start. ``episode_keys`` names an episode by what the fleet knows of it (its city's public map and its UAVs'
starts, never its users) for the policies' random draws.

Observation ``[K, 2 + N, window, window]``, one window per UAV centred on it: the building height minus the
altitude [m] (clipped; ``edge_height_m`` beyond the edge), the fleet channel (P_H where another UAV stands, 0
elsewhere) and each user's shared SINR memory [dB] (the SINR measured at each visited cell, P_H unvisited, P_L
blocked or beyond the edge). Reward (for learners): the gain, summed over the users, of the best SINR any UAV
measures of each user, counted up to P_T, plus ``c_e`` per UAV that enters a cell the fleet never visited, plus
``success_bonus`` when every user is served.

The oracle (``oracle_steps``) knows every user's map: the fewest steps until every user is served is, over the
assignments of users to UAVs, the largest of each UAV's fewest moves to a cell that serves all of its users (the
intersection of their target cells), minimised. It never counts two UAVs that must pass each other in a corridor
one cell wide (a lower bound there; exact elsewhere: ``tests/test_fleet.py`` checks it against a search over the
fleet's joint positions).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np
import pandas as pd
from pydantic import ConfigDict, Field, field_validator

from uavplace.dataset.bundle import Bundle
from uavplace.dataset.difficulty import UNREACHABLE, steps_to_target
from uavplace.infra.files import array_digest
from uavplace.rl.config import EnvConfig
from uavplace.rl.maps import MOVES
from uavplace.rl.randomness import canvas_key, combine, stream_key, uniforms
from uavplace.rl.vec_env import BatchedEnv
from uavplace.schemas.base import Contract, InputError
from uavplace.schemas.constants import P_T_DB, reaches_target

#: The fleet's 5 actions per UAV in map coordinates (dy, dx): the 4 placement moves, then 4 = stay.
FLEET_MOVES = np.vstack([MOVES, [[0, 0]]])
STAY = 4


class FleetConfig(Contract):
    """Everything that defines the fleet task (saved with every run and report that uses it)."""

    model_config = ConfigDict(allow_inf_nan=False)

    uavs: int = Field(default=2, ge=1, le=4, description="UAVs K in the fleet")
    users: int = Field(default=3, ge=1, le=6, description="Users N served at once, drawn from a city's traced users")
    t_max: int = Field(default=500, ge=1, description="Step budget: truncated after t_max steps")
    p_t_db: float = Field(default=P_T_DB, description="SINR target P_T: a user is served by a UAV at or above it [dB]")
    window: int = Field(default=61, ge=3, le=1001, description="Observation side in cells (odd), centred on each UAV")
    p_h_db: float = Field(default=50.0, description="P_H: the memory value of unvisited cells [dB]")
    p_l_db: float = Field(default=-150.0, description="P_L: the memory value of blocked cells and beyond the edge [dB]")
    edge_height_m: float = Field(default=100.0, description="Height channel value beyond the map edge [m above the UAV]")
    height_clip_m: float = Field(default=100.0, gt=0, description="Height channel clipped to +/- this [m]")
    c_e: float = Field(default=1.2, description="Reward per UAV entering a cell the fleet never visited")
    success_bonus: float = Field(default=100.0, description="Reward when every user is served")

    @field_validator("window")
    @classmethod
    def _odd(cls, window: int) -> int:
        if window % 2 != 1:
            raise ValueError(f"window {window} must be odd")
        return window

    @property
    def num_channels(self) -> int:
        return 2 + self.users


@dataclass(frozen=True)
class FleetCity:
    """One city's maps for the fleet: ``legal`` [ny, nx] (the UAV may enter), ``height_m`` [ny, nx] (building height
    minus altitude), ``sinr_db`` [U, ny, nx] and ``target`` [U, ny, nx] (legal, live and at or above P_T) per traced
    user, ``version`` (what names its episodes)."""

    name: str
    version: str
    legal: np.ndarray
    height_m: np.ndarray
    sinr_db: np.ndarray
    target: np.ndarray

    @functools.cached_property
    def public_digest(self) -> str:
        """The sha256 of what the fleet knows of the city before it flies (where it may go, the buildings' heights),
        never a user's map: what its episodes' random draws are keyed by (``FleetMaps.episode_keys``)."""
        return array_digest(self.legal, self.height_m)

    @classmethod
    def of(cls, bundle: Bundle, p_t_db: float, users: np.ndarray | None = None) -> FleetCity:
        """``bundle``'s maps; ``users``: the bundle's users the fleet draws from (default: all)."""
        picked = np.arange(bundle.num_users) if users is None else np.asarray(users, np.int64)
        sinr, dead = bundle.sinr_db[picked], bundle.dead[picked]
        legal = ~bundle.blocked
        target = reaches_target(sinr, p_t_db, dead, legal)
        return cls(bundle.city, bundle.version, legal, bundle.height_rel_m, sinr, target)


class FleetMaps:
    """The cities of a fleet task on padded canvases (``pad`` = half a window on every side, ``side`` cells):
    ``height`` [B, L, L], ``blocked`` [B, L, L] (beyond the edge too), ``sinr`` [B, U_max, L, L] (P_L beyond the
    edge and past a city's users), ``target`` [B, U_max, L, L]."""

    def __init__(self, cities: list[FleetCity], config: FleetConfig) -> None:
        if not cities:
            raise ValueError("a fleet needs at least one city")
        short = [c.name for c in cities if len(c.sinr_db) < config.users]
        if short:
            raise InputError(", ".join(short), f"fewer traced users than the fleet's {config.users} (--users)", field="users")
        self.cities, self.config = cities, config
        self.bundles: list[Bundle] | None = None  # FleetMaps.of: the bundles whose public maps a searcher reads
        self.pad = p = config.window // 2
        self.side = L = max(max(c.legal.shape) for c in cities) + 2 * p
        users = max(len(c.sinr_db) for c in cities)
        self.height = np.full((len(cities), L, L), config.edge_height_m, np.float32)
        self.blocked = np.ones((len(cities), L, L), bool)
        self.sinr = np.full((len(cities), users, L, L), config.p_l_db, np.float32)
        self.target = np.zeros((len(cities), users, L, L), bool)
        for b, c in enumerate(cities):
            ny, nx = c.legal.shape
            inner = (b, slice(p, p + ny), slice(p, p + nx))
            self.height[inner] = np.clip(c.height_m, -config.height_clip_m, config.height_clip_m)
            self.blocked[inner] = ~c.legal
            self.sinr[b, : len(c.sinr_db), p : p + ny, p : p + nx] = c.sinr_db
            self.target[b, : len(c.sinr_db), p : p + ny, p : p + nx] = c.target
        self.memory0 = np.where(self.blocked, np.float32(config.p_l_db), np.float32(config.p_h_db))
        self._reach: dict[tuple[int, int], np.ndarray] = {}
        self._oracle: dict[tuple[int, ...], int] = {}  # episode -> oracle steps (drawing computes them)

    @classmethod
    def of(cls, bundles: list[Bundle], config: FleetConfig, users: list[np.ndarray] | None = None) -> FleetMaps:
        """The fleet task on ``bundles``; ``users``: per bundle, the users drawn from (default: all; a learner's
        training cities offer their training users only)."""
        picked = users if users is not None else [None] * len(bundles)
        out = cls([FleetCity.of(b, config.p_t_db, u) for b, u in zip(bundles, picked, strict=True)], config)
        out.bundles = list(bundles)
        return out

    def reach(self, city: int, user: int) -> np.ndarray:
        """``[ny, nx]`` the fewest moves from each cell of ``city`` to a target cell of ``user`` (``UNREACHABLE``
        where none can be reached)."""
        key = (city, user)
        if key not in self._reach:
            c = self.cities[city]
            self._reach[key] = steps_to_target(c.legal, c.target[user])
        return self._reach[key]

    def group_reach(self, city: int, users: tuple[int, ...]) -> np.ndarray:
        """``[ny, nx]`` the fewest moves from each cell of ``city`` to a cell that serves every user of ``users`` (the
        intersection of their target cells; ``UNREACHABLE`` where there is none to reach)."""
        key = (city, *users)
        if key not in self._reach:
            c = self.cities[city]
            self._reach[key] = steps_to_target(c.legal, np.logical_and.reduce(c.target[list(users)]))
        return self._reach[key]

    def episode_list(self, n: int, seed: int) -> np.ndarray:
        """``[n, 1 + N + 2K]`` int64 episodes ``(city, users..., y_1, x_1, ..., y_K, x_K)`` (map cells): episode ``i``
        drawn from its own generator (``seed`` and ``i`` hashed), so the first ``m`` of a list are the list of ``m``."""
        cfg = self.config
        out = np.zeros((n, 1 + cfg.users + 2 * cfg.uavs), np.int64)
        stream = stream_key("fleet episode list", seed, cfg.users, cfg.uavs, cfg.p_t_db)
        for i in range(n):
            rng = np.random.default_rng(int(combine(stream, i)))
            for _ in range(1000):
                episode = self.draw(rng)
                if episode is not None:
                    out[i] = episode
                    break
            else:
                names = ", ".join(c.name for c in self.cities)
                raise InputError(names, f"no fleet episode of {cfg.users} users and {cfg.uavs} UAVs found in 1000 draws at "
                                 f"P_T = {cfg.p_t_db:g} dB: every user needs a target cell reachable from the starts "
                                 "(fewer --users or another --p-t-db)", field="p_t_db")  # fmt: skip
        return out

    def draw(self, rng: np.random.Generator) -> np.ndarray | None:
        """One episode drawn with ``rng``, or None when the draw is not one (the module's docstring)."""
        cfg = self.config
        b = int(rng.integers(len(self.cities)))
        c = self.cities[b]
        users = rng.choice(len(c.sinr_db), cfg.users, replace=False)
        open_cells = np.flatnonzero(c.legal)
        starts = open_cells[rng.choice(len(open_cells), cfg.uavs, replace=False)]
        y, x = np.divmod(starts, c.legal.shape[1])
        reach = np.stack([self.reach(b, int(u))[y, x] for u in users])  # [N, K]
        served = np.stack([c.target[int(u)][y, x] for u in users]).any(axis=1)
        if (reach >= UNREACHABLE).any() or served.all():
            return None
        episode = np.concatenate([[b], users, np.stack([y, x], axis=1).ravel()])
        return episode if self.oracle(episode) < UNREACHABLE else None

    def oracle(self, episode: np.ndarray) -> int:
        """``fleet_oracle`` of one episode (a row of ``episode_list``), computed once per ``FleetMaps``."""
        key = tuple(int(v) for v in episode)
        if key not in self._oracle:
            city, users, starts = self.split(np.asarray(episode, np.int64)[None])
            self._oracle[key] = fleet_oracle(self.cities[int(city[0])], users[0], starts[0])
        return self._oracle[key]

    def split(self, episodes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Episodes as (city [E], users [E, N], starts [E, K, 2] map cells)."""
        episodes = np.asarray(episodes, np.int64)
        n = self.config.users
        return episodes[:, 0], episodes[:, 1 : 1 + n], episodes[:, 1 + n :].reshape(len(episodes), -1, 2)

    def episode_keys(self, episodes: np.ndarray) -> np.ndarray:
        """``[E]`` uint64: each episode named by what the fleet knows of it: its city's public map (``canvas_key``)
        and its UAVs' starts, never its users or the bundle's version."""
        city, _, starts = self.split(episodes)
        keys = np.array([canvas_key(self.cities[int(b)].public_digest) for b in city], np.uint64)
        for column in starts.reshape(len(starts), -1).T:
            keys = combine(keys, column.astype(np.uint64))
        return keys


@functools.cache
def user_subsets(n: int) -> tuple[tuple[int, ...], ...]:
    """The non-empty subsets of ``n`` users, smallest first."""
    return tuple(s for r in range(1, n + 1) for s in itertools.combinations(range(n), r))


@functools.cache
def assignments(n: int, k: int) -> tuple[tuple[tuple[int, tuple[int, ...]], ...], ...]:
    """Every assignment of ``n`` users to ``k`` UAVs (``itertools.product`` order), as the ``(uav, its users)`` of the
    UAVs that have users, in UAV order: what the oracle minimises over and the fleet searcher maximises over."""
    return tuple(
        tuple((uav, mine) for uav in range(k) if (mine := tuple(u for u in range(n) if owner[u] == uav)))
        for owner in itertools.product(range(k), repeat=n)
    )


def oracle_steps(maps: FleetMaps, episodes: np.ndarray) -> np.ndarray:
    """``[E]`` the fewest steps until every user is served (see the module's docstring): for every subset of the
    users, the fewest moves from each start to a cell that serves them all; then, over the K^N assignments of users to
    UAVs, the largest of the UAVs' times, minimised (``UNREACHABLE`` when no assignment serves everyone)."""
    return np.array([maps.oracle(e) for e in np.asarray(episodes, np.int64)], np.int64)


def fleet_oracle(city: FleetCity, users: np.ndarray, starts: np.ndarray) -> int:
    """``oracle_steps`` of one episode: ``users`` [N] of ``city``, ``starts`` [K, 2] map cells."""
    subsets = user_subsets(len(users))
    both = np.stack([np.logical_and.reduce(city.target[users[list(s)]]) for s in subsets])
    dist = steps_to_target(city.legal, both)[:, starts[:, 0], starts[:, 1]].astype(np.int64)  # [subsets, K]
    time = {s: dist[i] for i, s in enumerate(subsets)}
    worst = (max(int(time[mine][uav]) for uav, mine in groups) for groups in assignments(len(users), len(starts)))
    return min(worst, default=UNREACHABLE)


class BatchedFleet:
    """``num_envs`` fleet episodes stepped together in numpy: ``begin`` starts episodes (rows of
    ``FleetMaps.episode_list``) in given rows; ``step`` moves the running ones; a finished row stays as it ended
    (``done``) until ``begin`` starts another episode there (``run_fleet``)."""

    def __init__(self, maps: FleetMaps, num_envs: int) -> None:
        cfg = maps.config
        self.maps, self.config, self.num_envs = maps, cfg, num_envs
        n, L, K, N = num_envs, maps.side, cfg.uavs, cfg.users
        self.city = np.zeros(n, np.int64)
        self.users = np.zeros((n, N), np.int64)
        self.pos = np.zeros((n, K, 2), np.int64)  # canvas cells
        self.t = np.zeros(n, np.int64)
        self.memory = np.zeros((n, N, L, L), np.float32)
        self.visits = np.zeros((n, L, L), np.uint16)
        self.best = np.zeros((n, N), np.float32)  # the best SINR of each user measured now by any UAV
        self.served_at = np.full((n, N), -1, np.int64)  # the first step each user was served (-1: not yet)
        self.done = np.ones(n, bool)
        self.episode_id = np.full(n, -1, np.int64)
        self.keys = np.zeros(n, np.uint64)  # each row's episode key (FleetMaps.episode_keys)
        w = cfg.window
        self._windows = {
            "memory": np.lib.stride_tricks.sliding_window_view(self.memory, (w, w), axis=(2, 3)),
            "height": np.lib.stride_tricks.sliding_window_view(maps.height, (w, w), axis=(1, 2)),
        }

    def begin(self, rows: np.ndarray, episodes: np.ndarray, ids: np.ndarray) -> None:
        """Start ``episodes`` (ids ``ids``) in ``rows``."""
        city, users, starts = self.maps.split(episodes)
        p = self.maps.pad
        self.city[rows], self.users[rows], self.pos[rows] = city, users, starts + p
        self.t[rows] = 0
        self.memory[rows] = self.maps.memory0[city][:, None]
        self.visits[rows] = 0
        self.served_at[rows] = -1
        self.done[rows] = False
        self.episode_id[rows] = ids
        self.keys[rows] = self.maps.episode_keys(episodes)
        self._measure(rows)

    def sinr_here(self, rows: np.ndarray) -> np.ndarray:
        """``[len(rows), K, N]`` each user's SINR at each UAV's cell."""
        y, x = self.pos[rows, :, 0], self.pos[rows, :, 1]
        return self.maps.sinr[self.city[rows, None, None], self.users[rows, None, :], y[:, :, None], x[:, :, None]]

    def _measure(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows ``rows`` measure every user at every UAV: the shared memories, the visits, the best SINR and who is
        served. Returns how many of each row's UAVs stand on a cell never visited before, and whether every user of
        the row is served now."""
        values = self.sinr_here(rows)  # [R, K, N]
        y, x = self.pos[rows, :, 0], self.pos[rows, :, 1]
        fresh = self.visits[rows[:, None], y, x] == 0
        self.visits[rows[:, None], y, x] += 1
        for n in range(self.config.users):
            self.memory[rows[:, None], n, y, x] = values[:, :, n]
        self.best[rows] = values.max(axis=1)
        served = reaches_target(values, self.config.p_t_db)
        newly = served.any(axis=1) & (self.served_at[rows] < 0)
        self.served_at[rows] = np.where(newly, self.t[rows, None], self.served_at[rows])
        return fresh.sum(axis=1), served.any(axis=1).all(axis=1)

    def action_mask(self, rows: np.ndarray | None = None) -> np.ndarray:
        """``[len(rows), K, 5]`` bool: the moves into a legal cell no other UAV holds; staying is always legal."""
        rows = np.arange(self.num_envs) if rows is None else rows
        to = self.pos[rows, :, None, :] + FLEET_MOVES[None, None]  # [R, K, 5, 2]
        ok = ~self.maps.blocked[self.city[rows, None, None], to[..., 0], to[..., 1]]
        K = self.config.uavs
        for j in range(K):  # a cell another UAV holds
            held = (to == self.pos[rows, j][:, None, None, :]).all(axis=-1)  # [R, K, 5]
            held[:, j] = False
            ok &= ~held
        ok[..., STAY] = True
        return ok

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Move every running row's UAVs by ``actions`` [num_envs, K] (finished rows stay as they are); returns
        (reward [num_envs], terminated [num_envs], truncated [num_envs])."""
        cfg, K = self.config, self.config.uavs
        rows = np.flatnonzero(~self.done)
        actions = np.asarray(actions, np.int64)[rows]
        before = np.minimum(self.best[rows], cfg.p_t_db).sum(axis=1)
        start = self.pos[rows].copy()
        want = start + FLEET_MOVES[actions]  # [R, K, 2]
        free = ~self.maps.blocked[self.city[rows, None], want[..., 0], want[..., 1]]
        new = start.copy()
        for k in range(K):  # in order: not a cell held at the start of the step, nor one an earlier UAV entered
            ok = free[:, k].copy()
            for j in range(K):
                if j != k:
                    ok &= ~(want[:, k] == start[:, j]).all(axis=1)
                if j < k:
                    ok &= ~(want[:, k] == new[:, j]).all(axis=1)
            new[:, k] = np.where(ok[:, None], want[:, k], start[:, k])
        self.pos[rows] = new
        self.t[rows] += 1
        fresh, everyone = self._measure(rows)
        terminated = np.zeros(self.num_envs, bool)
        truncated = np.zeros(self.num_envs, bool)
        terminated[rows] = everyone
        truncated[rows] = (self.t[rows] >= cfg.t_max) & ~terminated[rows]
        reward = np.zeros(self.num_envs, np.float32)
        gain = np.minimum(self.best[rows], cfg.p_t_db).sum(axis=1) - before
        reward[rows] = gain + cfg.c_e * fresh + cfg.success_bonus * terminated[rows]
        self.done |= terminated | truncated
        return reward, terminated, truncated

    def observe(self, rows: np.ndarray | None = None) -> np.ndarray:
        """``[len(rows), K, 2 + N, w, w]`` the windows of each UAV (see the module's docstring)."""
        rows = np.arange(self.num_envs) if rows is None else rows
        cfg, K, N, w = self.config, self.config.uavs, self.config.users, self.config.window
        obs = np.zeros((len(rows), K, 2 + N, w, w), np.float32)
        h = w // 2
        for k in range(K):
            y0, x0 = self.pos[rows, k, 0] - h, self.pos[rows, k, 1] - h
            obs[:, k, 0] = self._windows["height"][self.city[rows], y0, x0]
            for j in range(K):
                if j == k:
                    continue
                dy, dx = self.pos[rows, j, 0] - y0, self.pos[rows, j, 1] - x0
                inside = (dy >= 0) & (dy < w) & (dx >= 0) & (dx < w)
                obs[np.flatnonzero(inside), k, 1, dy[inside], dx[inside]] = cfg.p_h_db
            obs[:, k, 2:] = self._windows["memory"][rows, :, y0, x0]  # [R, N, w, w]
        return obs


@dataclass(frozen=True)
class FleetView:
    """What a fleet policy other than the oracle may read: per row, the UAVs' canvas cells (``pos`` [E, K, 2]), the
    step (``t``), the fleet's shared measurements (``memory`` [E, N, L, L]: each user's SINR at the visited cells,
    P_H unvisited, P_L blocked) and visits (``visits`` [E, L, L]), the episode's key for random draws (``keys``), its
    city (``city``), the cities' public maps (``height`` and ``blocked`` [B, L, L]) and the task's settings. No
    user's map; every array read-only."""

    pos: np.ndarray
    t: np.ndarray
    memory: np.ndarray
    visits: np.ndarray
    keys: np.ndarray
    city: np.ndarray
    height: np.ndarray
    blocked: np.ndarray
    config: FleetConfig

    def at_uavs(self) -> np.ndarray:
        """``[E, K, N]`` each user's SINR measured at each UAV's cell (the shared memory there)."""
        rows, users = np.arange(len(self.t))[:, None, None], np.arange(self.config.users)
        return self.memory[rows, users, self.pos[..., 0, None], self.pos[..., 1, None]]

    @classmethod
    def of(cls, env: BatchedFleet) -> FleetView:
        arrays = (env.pos, env.t, env.memory, env.visits, env.keys, env.city, env.maps.height, env.maps.blocked)
        frozen = [a.view() for a in arrays]
        for a in frozen:
            a.flags.writeable = False
        return cls(*frozen, config=env.config)


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
        served = reaches_target(here, cfg.p_t_db)
        to = view.pos[:, :, None, :] + FLEET_MOVES[None, None, :STAY]  # [E, K, 4, 2]
        seen = view.visits[rows[:, None, None], to[..., 0], to[..., 1]] > 0  # [E, K, 4]
        value = np.minimum(view.memory[rows[:, None, None, None], np.arange(cfg.users)[None, None, None],
                                       to[..., 0, None], to[..., 1, None]], cfg.p_t_db)  # fmt: skip  # [E, K, 4, N]
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
    agent's random draws, ``rl.randomness``) by the fleet episode's key and the UAV (``keys``)."""

    def __init__(self, maps, num_envs: int, autoreset: bool = False, compact: bool = False) -> None:  # noqa: ANN001
        super().__init__(maps, num_envs, autoreset=autoreset, compact=compact)
        self.keys = np.zeros(num_envs, np.uint64)

    def episode_keys(self) -> np.ndarray:
        return self.keys.copy()


class FleetPlacement:
    """Independent placement agents: every UAV runs one trained placement agent (``policy`` with its ``EnvConfig``,
    e.g. the shipped ``best``) unchanged on the users dealt to it, as ``rl.tracking.PlacementInTracking`` runs one in
    the tracking env.

    The deal, at every step and in the UAVs' order: each UAV keeps the users it serves where it stands (those no
    earlier UAV keeps); the users nobody serves are then dealt one at a time, each to the UAV that holds the fewest
    users (the first in order on a tie), which takes the one it measures strongest where it stands (the nearest by
    what it hears). A UAV's users are served at a cell when the weakest of them is, so its agent plays the placement
    task of that weakest SINR: its memory is, at every cell the fleet visited, the lowest of its users' shared
    measurements there (P_H unvisited, P_L blocked), its visits are the fleet's and its homing cone starts from the
    best of those. A UAV stays when it has no user or serves all of its users, and when every move is held by another
    UAV; otherwise it moves by its agent's rule. Reads only the fleet's measurements (``FleetView``)."""

    prefix = "independent "

    def __init__(self, policy, env: EnvConfig, name: str | None = None, *, prefix: str | None = None,  # noqa: ANN001
                 compact: bool = False) -> None:  # fmt: skip
        """``policy``: a ``rl.policies.Policy`` (None: only ``dealt`` is used, as ``FleetTrainEnv`` does); ``prefix``
        before its name (default ``FleetPlacement.prefix``: a placement agent run as it is); ``compact``: the agent's
        observations as the learner stores them (``BatchedEnv``'s)."""
        name = name or policy.name
        if env.belief_channel or env.context_zoom:
            raise ValueError(f"{name}: an agent with a belief or context channel reads one user's measurements as they "
                             "come; the fleet deals each UAV a changing set of users")  # fmt: skip
        self.policy, self.name = policy, (self.prefix if prefix is None else prefix) + name
        self.env_config = env.model_copy(update={"rotate": False, "city_weights": {}, "split": None})
        self.compact = compact
        self.maps: FleetMaps | None = None
        self.mirror = None

    def bind(self, maps: FleetMaps) -> FleetPlacement:
        """Play on ``maps``' cities: a placement env (``BatchedEnv``) row per UAV and episode row keeps its agent's
        channels; that env's maps hold no user's map (SINR, dead cells and the genie's distances blanked)."""
        from uavplace.rl.maps import MapSet

        if maps.bundles is None:
            raise ValueError("independent placement agents read the bundles: FleetMaps.of(bundles, config)")
        self.maps, self.placement = maps, MapSet(maps.bundles, self.env_config)
        # no user's map: what the agents see comes from the fleet's measurements alone
        self.placement.sinr[...], self.placement.dead[...] = self.env_config.p_l_db, True
        self.placement.steps[...] = UNREACHABLE
        # per city, the view of its identity symmetry; the placement canvas's cell of the fleet canvas's cell 0
        self.views = np.array([np.flatnonzero(self.placement.view_map == self.placement.symmetries * b)[0]
                               for b in range(len(maps.cities))])  # fmt: skip
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
            self.mirror = _DealtEnv(self.placement, num_envs * uavs, autoreset=False, compact=self.compact)
            self.groups = np.zeros((num_envs, uavs, self.maps.config.users), bool)
            self.fresh = np.ones(num_envs, bool)
        self.groups[rows] = False
        self.fresh[rows] = True

    def deal(self, view: FleetView) -> tuple[np.ndarray, np.ndarray]:
        """(groups [E, K, N]: the users dealt to each UAV; served [E, K, N]: whom each UAV serves where it stands)."""
        cfg = view.config
        e, k, n = len(view.t), cfg.uavs, cfg.users
        here = view.at_uavs()
        served = reaches_target(here, cfg.p_t_db)
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
        actions = self.policy.act(obs, moves, self.mirror).reshape(e, k)
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


class FleetTrainEnv:
    """The fleet task as the learner's environment (``rl.agent.train.FleetTrainer``): a row per UAV of ``num_envs /
    K`` fleet episodes (row ``e * K + k``), each observing what ``FleetPlacement`` shows a UAV's agent (the placement
    observation of its dealt users' weakest SINR, from the fleet's shared measurements) and acting with the placement
    network's 4 moves: one network shared by every UAV, each acting from the shared memory and its own position.

    A UAV that ``FleetPlacement`` keeps still (no user, all of its users served, no free move) stays whatever its row
    chose. A row's reward is placement's, on the task its UAV was dealt when it moved: the change of its users'
    weakest SINR at its cell, plus ``c_e`` when it enters a cell the fleet never visited, plus ``success_bonus`` when
    it comes to serve all its users (times ``reward_scale``); a UAV that stays gets nothing. The rows of an episode end
    with it (every user served, or ``t_max``); a finished episode starts another, drawn with ``rng`` from the
    training cities (``FleetMaps.draw``). The genie's moves of a row (the auxiliary head's labels): those that start a
    shortest path to a cell serving every user dealt to its UAV (``FleetMaps.group_reach``; none where no cell
    does). The trainer's interface is ``rl.vec_env.EpisodeRows``'s, checkpoints included (``state_arrays``: the
    fleet's episode state; the dealt rows are read afresh from it)."""

    state_arrays = ("city", "users", "pos", "t", "memory", "visits", "best", "served_at", "done", "episode_id", "keys")

    def __init__(self, maps: FleetMaps, env: EnvConfig, num_envs: int) -> None:
        k = maps.config.uavs
        if num_envs % k:
            raise ValueError(f"num_envs {num_envs} is not a multiple of the fleet's {k} UAVs")
        self.maps, self.uavs, self.num_envs, self.env_config = maps, k, num_envs, env
        self.fleet = BatchedFleet(maps, num_envs // k)
        self.deal = FleetPlacement(None, env, "fleet", compact=True).bind(maps)
        self.rng = np.random.default_rng()
        self._episodes_started = 0
        self._idle = np.zeros((num_envs // k, k), bool)
        for name in self.state_arrays:  # the fleet's arrays themselves (changed in place), as a checkpoint saves them
            setattr(self, name, getattr(self.fleet, name))

    def _begin(self, rows: np.ndarray) -> None:
        episodes, tries = [], 0
        while len(episodes) < len(rows):
            drawn = self.maps.draw(self.rng)
            tries += 1
            if drawn is not None:
                episodes.append(drawn)
            elif tries > 1000 * len(rows):
                names = ", ".join(c.name for c in self.maps.cities)
                raise InputError(names, "no fleet episode found in 1000 draws a row: every user needs a target cell "
                                 "reachable from the starts (fewer fleet.users or another fleet.p_t_db)", field="fleet")  # fmt: skip
        ids = self._episodes_started + np.arange(len(rows))
        self._episodes_started += len(rows)
        self.fleet.begin(rows, np.array(episodes, np.int64), ids)
        self.deal.reset_deal(rows, self.fleet.num_envs, self.uavs)

    def _dealt(self) -> tuple[np.ndarray, np.ndarray]:
        obs, moves, self._idle = self.deal.dealt(self.fleet.action_mask(), FleetView.of(self.fleet))
        return obs, moves

    def reset(self, *, seed: int | None = None) -> tuple[np.ndarray, dict]:
        self.rng = np.random.default_rng(seed)
        self._begin(np.arange(self.fleet.num_envs))
        obs, moves = self._dealt()
        return obs, {"action_mask": moves}

    def observe(self) -> np.ndarray:
        return self._dealt()[0]

    def action_mask(self) -> np.ndarray:
        return self._dealt()[1]

    def check_state(self, source: object) -> None:
        """``InputError`` (naming ``source``) unless the restored episode state is one of these cities'; then every
        UAV's row is read afresh from it."""
        f, cfg = self.fleet, self.maps.config
        users = np.array([len(c.sinr_db) for c in self.maps.cities])
        ok = ((f.city >= 0) & (f.city < len(self.maps.cities))).all() and (f.t >= 0).all() and (f.t <= cfg.t_max).all()
        ok = ok and ((f.users >= 0) & (f.users < users[np.clip(f.city, 0, len(users) - 1), None])).all()
        ok = ok and ((f.pos >= self.maps.pad) & (f.pos < self.maps.side - self.maps.pad)).all()
        if not ok or self.maps.blocked[f.city[:, None], f.pos[..., 0], f.pos[..., 1]].any():
            raise InputError(source, "the fleet's episode state is not one of these cities' (city, users, cells)", field="pos")
        self.deal.reset_deal(np.arange(f.num_envs), f.num_envs, self.uavs)

    def sinr_here(self) -> np.ndarray:
        """``[num_envs]`` the weakest user's best SINR in each row's episode (what the training log's gain reads)."""
        return np.repeat(self.fleet.best.min(axis=1), self.uavs)

    def neighbour_visits(self) -> np.ndarray:
        """``[num_envs, 4]`` the fleet's visits of the cell each move leads to."""
        return self.deal.mirror.neighbour_visits()

    def genie_moves(self) -> np.ndarray:
        """``[num_envs, 4]`` bool: the moves of each UAV that start a shortest path to a cell serving all its users
        (privileged: a training aid only, never an observation)."""
        f, p, k = self.fleet, self.maps.pad, self.uavs
        out = np.zeros((self.num_envs, STAY), bool)
        for e, uav in zip(*np.nonzero(self.deal.groups.any(axis=2) & ~self._idle), strict=True):
            reach = self.maps.group_reach(int(f.city[e]), tuple(int(u) for u in np.flatnonzero(self.deal.groups[e, uav])))
            y, x = f.pos[e, uav] - p
            here = reach[y, x]
            if here >= UNREACHABLE:
                continue
            ny, nx = y + MOVES[:, 0], x + MOVES[:, 1]
            inside = (ny >= 0) & (ny < reach.shape[0]) & (nx >= 0) & (nx < reach.shape[1])
            out[e * k + uav, inside] = reach[ny[inside], nx[inside]] < here
        return out

    def _weakest(self, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``[E, K]`` each UAV's weakest SINR of the users in ``groups`` [E, K, N] where it stands (0 without users), and
        whether it serves them all."""
        here = FleetView.of(self.fleet).at_uavs()
        weakest = np.where(groups, here, np.inf).min(axis=2)
        has = groups.any(axis=2)
        return np.where(has, weakest, 0.0), has & reaches_target(weakest, self.maps.config.p_t_db)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        k, cfg, f = self.uavs, self.env_config, self.fleet
        chosen = np.asarray(actions, np.int64).reshape(-1, k)
        groups = self.deal.groups.copy()  # the task each UAV moves for
        before, served_before = self._weakest(groups)
        moving = ~self._idle & ~f.done[:, None]
        _, terminated, truncated = f.step(np.where(self._idle, STAY, chosen))
        after, served_after = self._weakest(groups)
        rows = np.arange(f.num_envs)[:, None]
        fresh = f.visits[rows, f.pos[..., 0], f.pos[..., 1]] == 1
        reward = after - before + cfg.c_e * fresh + cfg.success_bonus * (served_after & ~served_before)
        reward = np.where(moving, reward, 0.0) * cfg.reward_scale
        term, trunc = np.repeat(terminated, k), np.repeat(truncated, k)
        final = np.flatnonzero(trunc)
        info = {"final_index": final, "sinr": self.sinr_here(), "steps": np.repeat(self.fleet.t, k)}
        if len(final):  # the last observation of the rows cut short, before their next episodes begin
            obs, moves = self._dealt()
            info["final_obs"], info["final_mask"] = obs[final], moves[final]
        ended = np.flatnonzero(terminated | truncated)
        if len(ended):
            self._begin(ended)
        obs, moves = self._dealt()  # a second deal in one step (after a cut) changes nothing but the begun rows
        info["action_mask"] = moves
        return obs, reward.ravel().astype(np.float32), term, trunc, info


def run_fleet(maps: FleetMaps, policy, episodes: np.ndarray, num_envs: int = 64,  # noqa: ANN001
              record: np.ndarray | None = None) -> pd.DataFrame:  # fmt: skip
    """Play ``episodes`` with ``policy`` (``reset(rows, num_envs, uavs)``, ``act(mask, FleetView) -> [E, K]``); one
    row per episode: ``success`` (every user served at one step within ``t_max``), ``steps`` (to that step; ``t_max
    + 1`` when it failed), ``users_served`` (the share of users served at some step), ``oracle_steps`` and ``spl``
    (success x oracle steps / max(steps, oracle steps)); and, for ``eval.metrics``, the oracle's steps as
    ``genie_steps``, the user set as ``user``, the city, and the first UAV's start. ``record``: episode numbers whose
    paths are kept, ``attrs["paths"][i]`` [T + 1, K, 2] map cells of every UAV at every step."""
    episodes = np.asarray(episodes, np.int64)
    cfg = maps.config
    n = min(num_envs, len(episodes))
    env = BatchedFleet(maps, n)
    steps = np.full(len(episodes), cfg.t_max + 1, np.int64)
    success = np.zeros(len(episodes), bool)
    share = np.zeros(len(episodes))
    nxt = min(n, len(episodes))
    kept = set() if record is None else {int(i) for i in record}
    paths: dict[int, list[np.ndarray]] = {}

    def remember(rows: np.ndarray) -> None:
        for r in rows:
            if int(env.episode_id[r]) in kept:
                paths.setdefault(int(env.episode_id[r]), []).append(env.pos[r] - maps.pad)

    env.begin(np.arange(n), episodes[:n], np.arange(n))
    policy.reset(np.arange(n), n, cfg.uavs)
    remember(np.arange(n))
    while not env.done.all():
        running = np.flatnonzero(~env.done)
        _, terminated, truncated = env.step(policy.act(env.action_mask(), FleetView.of(env)))
        remember(running)
        ended = np.flatnonzero(terminated | truncated)
        for row in ended:
            i = env.episode_id[row]
            success[i], share[i] = terminated[row], (env.served_at[row] >= 0).mean()
            steps[i] = env.t[row] if terminated[row] else cfg.t_max + 1
        refill = ended[: max(0, len(episodes) - nxt)]
        if len(refill):
            env.begin(refill, episodes[nxt : nxt + len(refill)], np.arange(nxt, nxt + len(refill)))
            policy.reset(refill, n, cfg.uavs)
            remember(refill)
            nxt += len(refill)
    oracle = oracle_steps(maps, episodes)
    spl = success * oracle / np.maximum(np.maximum(steps, oracle), 1)
    city, users, starts = maps.split(episodes)
    frame = pd.DataFrame({
        "episode": np.arange(len(episodes)), "success": success, "steps": steps, "users_served": share,
        "oracle_steps": oracle, "spl": spl,
        # what the placement report's statistics read: the oracle in the genie's place, the user set as the user
        "genie_steps": oracle, "city": [maps.cities[int(c)].name for c in city],
        "user": ["-".join(map(str, sorted(u))) for u in users.tolist()], "view": city,
        "start_y": starts[:, 0, 0], "start_x": starts[:, 0, 1],
    })  # fmt: skip
    frame.attrs["paths"] = {i: np.stack(p) for i, p in paths.items()}
    return frame


class FleetSearcher:
    """The map searcher run for the fleet (``rl.searcher``): one belief per user over its candidate cells, updated by
    every UAV's first measurement of each cell (a cell measured again tells nothing new), and one plan for the fleet.

    Per user ``n`` the posterior probability ``P_n(c)`` that each legal cell ``c`` serves it (1 or 0 at a visited
    cell: its SINR is known). A set of users ``S`` is served at ``c`` with probability ``prod_{n in S} P_n(c)``. Over
    the K^N assignments of users to UAVs, each UAV's best cell for its users scores that probability times the
    searcher's distance discount from the UAV; the assignment of the largest product of its UAVs' scores is
    followed, each UAV one cell along a shortest legal path to its cell (staying when it stands on it). Needs the
    bundles' public maps (``FleetMaps.of``)."""

    name = "map searcher"

    def __init__(self, predictor, config=None, cache=None) -> None:  # noqa: ANN001 - rl.searcher's types
        from uavplace.rl.searcher import MapSearchPolicy

        self.searcher = MapSearchPolicy(predictor, config, cache)
        self.public = None
        self.log_b: list[list[np.ndarray]] = []

    def bind(self, maps: FleetMaps) -> FleetSearcher:
        """Read ``maps``' public maps (its bundles' heights, grid and settings; never a user's map)."""
        from uavplace.rl.config import EnvConfig
        from uavplace.rl.maps import MapSet
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
        known = reaches_target(view.memory[r][:, cm.legal[:, 0] + p, cm.legal[:, 1] + p], cfg.p_t_db)  # [N, M]
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

"""The fleet task's cities on padded canvases and its episodes (``FleetMaps.episode_list``)."""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np

from uavplace.dataset.bundle import Bundle
from uavplace.dataset.difficulty import UNREACHABLE, steps_to_target
from uavplace.infra.files import array_digest
from uavplace.rl.randomness import canvas_key, combine, stream_key
from uavplace.rl.tasks.fleet.config import FleetConfig
from uavplace.schemas.base import InputError
from uavplace.schemas.constants import reaches_target


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
                raise InputError(
                    names,
                    f"no fleet episode of {cfg.users} users and {cfg.uavs} UAVs found in 1000 draws at "
                    f"P_T = {cfg.p_t_db:g} dB: every user needs a target cell reachable from the starts "
                    "(fewer --users or another --p-t-db)",
                    field="p_t_db",
                )
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

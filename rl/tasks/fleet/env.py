"""The fleet task stepped in numpy (``BatchedFleet``) and what a policy may read of it (``FleetView``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavplace.rl.tasks.fleet.config import FLEET_MOVES, STAY, FleetConfig
from uavplace.rl.tasks.fleet.maps import FleetMaps
from uavplace.rl.world.view import frozen, sealed


class BatchedFleet:
    """``num_envs`` fleet episodes stepped together in numpy: ``begin`` starts episodes (rows of
    ``FleetMaps.episode_list``) in given rows; ``step`` moves the running ones; a finished row stays as it ended
    (``done``) until ``begin`` starts another episode there (``run_fleet``)."""

    def __init__(self, maps: FleetMaps, num_envs: int) -> None:
        cfg = maps.config
        if not cfg.measurement.exact or not cfg.map_error.exact:
            raise ValueError(
                "the fleet task reads every user's SINR exactly on the traced city's map: measurement and map errors "
                "are played in the placement and tracking tasks"
            )
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
        served = self.config.reaches(values)
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
    city (``city``), the cities' public maps (``height`` and ``blocked`` [B, L, L]), the task's settings and which
    rows have ended (``done`` [E]: their moves are not played). No user's map; every array read-only."""

    pos: np.ndarray
    t: np.ndarray
    memory: np.ndarray
    visits: np.ndarray
    keys: np.ndarray
    city: np.ndarray
    height: np.ndarray
    blocked: np.ndarray
    config: FleetConfig
    done: np.ndarray

    def at_uavs(self) -> np.ndarray:
        """``[E, K, N]`` each user's SINR measured at each UAV's cell (the shared memory there)."""
        rows, users = np.arange(len(self.t))[:, None, None], np.arange(self.config.users)
        return self.memory[rows, users, self.pos[..., 0, None], self.pos[..., 1, None]]

    @classmethod
    def of(cls, env: BatchedFleet) -> FleetView:
        """The view of ``env`` now: read-only copies of where its UAVs are and when (a policy that writes them moves
        no UAV), read-only views of the fleet's measurements, and the public maps as read-only copies made once per
        ``FleetMaps`` (a policy that makes them writable again changes nothing the env reads)."""
        kept = getattr(env, "_public", None)
        if kept is None or kept[0] is not env.maps:
            env._public = kept = (env.maps, sealed(env.maps.height), sealed(env.maps.blocked))
        pos, t, keys, city, done = (sealed(a) for a in (env.pos, env.t, env.keys, env.city, env.done))
        return cls(pos, t, frozen(env.memory), frozen(env.visits), keys, city, *kept[1:], config=env.config, done=done)

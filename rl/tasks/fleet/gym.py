"""The fleet task's Gymnasium face, ``uavplace/UavFleet-v0`` (``rl/__init__.py`` registers it; ``zoo.py`` wraps it
for PettingZoo)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from uavplace.rl.tasks.fleet.config import FleetConfig
from uavplace.rl.tasks.fleet.env import BatchedFleet
from uavplace.rl.tasks.fleet.maps import FleetMaps
from uavplace.rl.world.gym import observation_bounds, task_bundles


class UavFleetEnv(gym.Env):
    """``uavplace/UavFleet-v0``: one episode of the fleet task (``rl.tasks.fleet``: K UAVs serve N users of unknown
    position at once). Observation ``[K, 2 + N, window, window]``, one window per UAV; action ``MultiDiscrete([5] *
    K)`` (each UAV's 4 moves and stay); ``terminated`` when every user is served at one step, ``truncated`` after
    ``t_max`` steps. ``info``: ``action_mask`` [K, 5], ``positions`` [K, 2] (map cells), ``sinr_db`` [K, N] (what
    each UAV measures of each user) and ``served`` [N] (each user served at this step). ``dataset``: a city name or
    list (or a loaded ``FleetMaps``); ``config``: a ``FleetConfig`` or a dict of its fields; ``**overrides``: its
    fields."""

    metadata = {"render_modes": []}

    def __init__(self, dataset, config=None, root: str = "data/processed", **overrides: object) -> None:  # noqa: ANN001
        maps = (
            dataset
            if isinstance(dataset, FleetMaps)
            else FleetMaps.of(*task_bundles(dataset, config, FleetConfig, root, overrides))
        )
        self.config = cfg = maps.config
        self._env = BatchedFleet(maps, 1)
        low, high = observation_bounds(cfg)
        self.observation_space = gym.spaces.Box(low, high, (cfg.uavs, cfg.num_channels, cfg.window, cfg.window), np.float32)
        self.action_space = gym.spaces.MultiDiscrete([5] * cfg.uavs)

    def _info(self) -> dict:
        e, rows = self._env, np.array([0])
        values = e.sinr_here(rows)[0]
        return {
            "action_mask": e.action_mask(rows)[0].astype(np.int8),
            "positions": e.pos[0] - e.maps.pad,
            "sinr_db": values,
            "served": self.config.reaches(values).any(axis=0),
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        maps = self._env.maps
        episode = None
        while episode is None:  # all randomness from Gymnasium's seeded generator
            episode = maps.draw(self.np_random)
        self._env.begin(np.array([0]), episode[None], np.array([0]))
        self._playing = True
        return self._env.observe()[0], self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """One step of every UAV; ``ValueError`` for a step before ``reset`` or after the episode ended, and for an
        action that is not in the action space (K integers from 0 to 4: no float, string or out-of-range value)."""
        if not getattr(self, "_playing", False):
            raise ValueError("step() before reset(), or after the episode ended: call reset()")
        moves = np.asarray(action)
        if moves.shape != (self.config.uavs,) or moves.dtype.kind not in "iu" or ((moves < 0) | (moves > 4)).any():
            raise ValueError(f"action {action!r}: expected {self.config.uavs} integers from 0 to 4 (the action space)")
        reward, terminated, truncated = self._env.step(moves.astype(np.int64).reshape(1, -1))
        self._playing = not (terminated[0] or truncated[0])
        return self._env.observe()[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), self._info()

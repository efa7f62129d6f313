"""The tracking task's Gymnasium face, ``uavplace/UavTracking-v0`` (``rl/__init__.py`` registers it)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from uavplace.rl.tasks.tracking.config import TrackingConfig
from uavplace.rl.tasks.tracking.env import TrackingEnv
from uavplace.rl.tasks.tracking.maps import RouteSet
from uavplace.rl.world.gym import observation_bounds, task_bundles


class UavTrackingEnv(gym.Env):
    """``uavplace/UavTracking-v0``: one episode of the tracking task (``rl.tasks.tracking``: a user who moves along a
    ray-traced route; 5 actions, the 4 moves and stay; a fixed horizon, ``truncated`` at its end, never
    ``terminated``). ``info``: ``action_mask`` (5), ``sinr_db``, ``position``, after a step ``covered`` and
    ``illegal``. ``dataset``: cities whose bundles have routes (or a loaded ``RouteSet``); ``config``: a
    ``TrackingConfig`` or a dict of its fields; ``**overrides``: its fields."""

    metadata = {"render_modes": []}

    def __init__(self, dataset, config=None, root: str = "data/processed", **overrides: object) -> None:  # noqa: ANN001
        routes = (
            dataset
            if isinstance(dataset, RouteSet)
            else RouteSet(*task_bundles(dataset, config, TrackingConfig, root, overrides))
        )
        self.config = routes.config
        self._env = TrackingEnv(routes, 1, autoreset=False)
        c, w = self.config.num_channels, self.config.window
        low, high = observation_bounds(self.config, self.config.age_clip_s)
        self.observation_space = gym.spaces.Box(low, high, (c, w, w), np.float32)
        self.action_space = gym.spaces.Discrete(5)

    def _info(self, extra: dict | None = None) -> dict:
        e = self._env
        mask = e.action_mask()[0].astype(np.int8)
        return {"action_mask": mask, "sinr_db": float(e.sinr_here()[0]), "position": e.pos[0].copy()} | (extra or {})

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self._env.rng = self.np_random  # all randomness from Gymnasium's seeded generator
        self._env._start(np.array([0]))
        return self._env.observe()[0], self._info()

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, reward, _, truncated, info = self._env.step(np.array([int(action)]))
        extra = {"covered": bool(info["covered"][0]), "illegal": bool(info["illegal"][0])}
        return obs[0], float(reward[0]), False, bool(truncated[0]), self._info(extra)

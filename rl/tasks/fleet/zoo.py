"""The fleet task (``rl.tasks.fleet``) as a PettingZoo parallel environment: one agent per UAV.

``parallel_env(dataset, ...)`` (PettingZoo's convention) wraps ``uavplace/UavFleet-v0`` (``rl.tasks.fleet.gym.UavFleetEnv``):
agents ``uav_0`` ... ``uav_{K-1}``, each observing its own window ``[2 + N, window, window]`` (the building
heights, the other UAVs, every user's shared SINR memory) and choosing one of 5 actions (the 4 moves, 4 = stay).
The fleet shares one reward (every agent gets it) and ends together: every agent is terminated when every user is
served at one step, truncated after ``t_max`` steps. An agent given no action stays. ``infos[agent]``: its
``action_mask`` [5], its cell (``position``) and what it measures of each user (``sinr_db`` [N]). Seeded by
``reset(seed=...)`` as the Gymnasium env is. Needs ``pip install -e '.[zoo]'`` (PettingZoo); tested with its
``parallel_api_test`` (``tests/test_fleet.py``).
"""

from __future__ import annotations

import numpy as np
from pettingzoo import ParallelEnv

from uavplace.rl.tasks.fleet import STAY
from uavplace.rl.tasks.fleet.gym import UavFleetEnv


class UavFleetParallelEnv(ParallelEnv):
    """See the module's docstring; ``dataset``, ``config``, ``root`` and ``**overrides`` as ``UavFleetEnv``'s."""

    metadata = {"name": "uavplace_fleet_v0", "render_modes": []}

    def __init__(self, dataset, config=None, root: str = "data/processed", **overrides: object) -> None:  # noqa: ANN001
        import gymnasium as gym

        self.fleet = UavFleetEnv(dataset, config, root, **overrides)
        k = self.fleet.config.uavs
        self.possible_agents = [f"uav_{i}" for i in range(k)]
        self.agents: list[str] = []
        box = self.fleet.observation_space
        self._observation = gym.spaces.Box(box.low[0], box.high[0], box.shape[1:], box.dtype)
        self._action = gym.spaces.Discrete(STAY + 1)

    def observation_space(self, agent: str):  # noqa: ANN201 - a gymnasium Box
        return self._observation  # the same object every call, as PettingZoo asks

    def action_space(self, agent: str):  # noqa: ANN201 - a gymnasium Discrete
        return self._action

    def _split(self, obs: np.ndarray, info: dict) -> tuple[dict, dict]:
        observations = {a: obs[i] for i, a in enumerate(self.possible_agents)}
        infos = {
            a: {"action_mask": info["action_mask"][i], "position": info["positions"][i], "sinr_db": info["sinr_db"][i]}
            for i, a in enumerate(self.possible_agents)
        }
        return observations, infos

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        obs, info = self.fleet.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        return self._split(obs, info)

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        """One step of every UAV (an agent given no action stays); ``ValueError`` for a step before ``reset`` or after
        the episode ended, an agent that is not live, and an action that is not in its space (an integer from 0 to
        4: no float, string or out-of-range value, which a cast would have turned into a move)."""
        if not self.agents:
            raise ValueError("step() before reset(), or after the episode ended: call reset()")
        unknown = sorted(set(actions) - set(self.agents), key=str)
        if unknown:
            raise ValueError(f"actions for {unknown}: not live agents ({', '.join(self.agents)})")
        for agent, a in actions.items():
            if isinstance(a, bool) or not isinstance(a, int | np.integer) or not 0 <= int(a) <= STAY:
                raise ValueError(f"{agent}: action {a!r} is not in the action space (an integer from 0 to {STAY})")
        chosen = np.array([int(actions.get(a, STAY)) for a in self.possible_agents], np.int64)
        obs, reward, terminated, truncated, info = self.fleet.step(chosen)
        observations, infos = self._split(obs, info)
        everyone = self.possible_agents
        rewards = dict.fromkeys(everyone, reward)
        terminations, truncations = dict.fromkeys(everyone, terminated), dict.fromkeys(everyone, truncated)
        if terminated or truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos


def parallel_env(dataset, config=None, root: str = "data/processed", **overrides: object) -> UavFleetParallelEnv:  # noqa: ANN001
    """The fleet task as a PettingZoo parallel environment (``UavFleetParallelEnv``)."""
    return UavFleetParallelEnv(dataset, config, root, **overrides)

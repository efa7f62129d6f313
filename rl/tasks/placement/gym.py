"""``uavplace/UavPlacement-v0``, placement's Gymnasium face: one episode of the UAV placement problem over map bundles.

## Description
A UAV at a fixed altitude moves on the bundle's grid to find a cell where the
SINR of a ground user, at an unknown position, reaches P_T (docs/method.md).

## Observation space
``Box(-150, 100, (C, window, window), float32)`` centred on the UAV: channel 0
the building height minus the altitude [m] (clipped to +/- 100; beyond the map
edge ``edge_height_m``), channel 1 the SINR memory [dB] (measured SINR at
visited cells, P_H = +50 at unvisited ones, P_L = -150 at blocked cells and
beyond the edge). Blind variant: only the SINR memory, with blocked map cells
shown as P_H. With ``visited_channel`` a channel of the visited cells (P_H where
visited, 0 elsewhere) comes before the SINR memory, which stays last; with
``homing_channel`` the homing cone (the best SINR measured so far less
``homing_slope_db`` per cell of distance from where it was measured, clipped at
P_L) comes between them, and with ``belief_channel`` the map searcher's posterior
probability [%] that each cell reaches P_T, from its belief over the user's position
given the episode's measurements (``rl.belief.BeliefTracker``), just before the SINR
memory. With
``context_zoom`` z, context channels follow the height channel: the window again
in blocks of z x z cells (z times the span), their mean height and the best SINR
measured in each (P_H where none is visited, P_L where all blocked or beyond the
edge); blind: the SINR one only.

## Action space
``Discrete(4)``: 0 north (+y), 1 east (+x), 2 south (-y), 3 west (-x).
``info["action_mask"]`` (and ``action_mask()``) marks the legal moves; an
illegal action leaves the UAV in place.

## Rewards
``SINR_{t+1} - SINR_t + c_E * [the new cell was never visited]`` (the paper's), and the
training levers of ``EnvConfig`` when set: less ``step_cost``, plus potential-based
shaping from the genie's distance, times ``reward_scale``.

## Episode end
``terminated`` when SINR >= P_T; ``truncated`` after ``t_max`` moves.

## Info
``action_mask``, ``sinr_db`` (the SINR measured at the UAV's cell) and ``position``
(the UAV's cell), and ``illegal`` after a step: what a UAV knows. With
``evaluation_info=True`` also ``genie_steps`` (the fewest moves to a target) and
``view`` (which user and symmetry the episode plays): both are read off the
user's map, which a searching agent must not see. They are for an evaluator
scoring episodes; a learner given them could home in on a user nobody located.

## Arguments
``dataset`` (a city name or list, or loaded ``MapSet``), ``config`` (``EnvConfig``
or a dict of its fields), ``root`` (processed-data root), ``evaluation_info``
(see Info), ``obs_scale`` (observations and their bounds divided by it: 50 puts
them in about [-3, 2], what uavplace's own networks divide by and what libraries
whose networks expect inputs of order 1, such as Stable-Baselines3, need; see
docs/peer.md), ``**overrides`` (``EnvConfig`` fields, e.g. ``blind=True``).

## Version history
- v0: first version.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.world.gym import observation_bounds, with_overrides
from uavplace.rl.world.maps import MapSet


class UavPlacementEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(
        self,
        dataset: str | list[str] | MapSet,
        config: EnvConfig | dict | None = None,
        root: str = "data/processed",
        evaluation_info: bool = False,
        obs_scale: float = 1.0,
        **overrides: object,
    ) -> None:
        if not (np.isfinite(obs_scale) and obs_scale > 0):
            raise ValueError(f"obs_scale must be positive and finite, not {obs_scale}")
        if isinstance(dataset, MapSet):
            maps = dataset
            if config is not None or overrides:
                raise ValueError("a MapSet carries its config; pass config/overrides when loading it")
        else:
            maps = MapSet.load(dataset, with_overrides(EnvConfig, config, overrides), root=root)
        self.config = maps.config
        self.evaluation_info = evaluation_info
        self._env = BatchedEnv(maps, 1, autoreset=False)
        c, w = self.config.num_channels, self.config.window
        low, high = observation_bounds(self.config)
        self.obs_scale = float(obs_scale)
        self.observation_space = gym.spaces.Box(low / self.obs_scale, high / self.obs_scale, (c, w, w), np.float32)
        self.action_space = gym.spaces.Discrete(4)

    @property
    def maps(self) -> MapSet:
        return self._env.maps

    def action_mask(self) -> np.ndarray:
        """``[4]`` int8: 1 where the move is legal."""
        return self._env.action_mask()[0].astype(np.int8)

    def _info(self, extra: dict | None = None) -> dict:
        e = self._env
        info = {"action_mask": self.action_mask(), "sinr_db": float(e.sinr_here()[0]), "position": e.pos[0].copy()}
        if self.evaluation_info:  # read off the user's map: never for the agent (see Info)
            info |= {"genie_steps": int(e.genie_steps()[0]), "view": int(e.view[0])}
        return info | (extra or {})

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        e = self._env
        e.rng = self.np_random  # all randomness from Gymnasium's seeded generator
        e._start(np.array([0]))
        return self._observe(), self._info()

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        e = self._env
        _, reward, terminated, truncated, info = e.step(np.array([int(action)]))
        extra = {"illegal": bool(info["illegal"][0])}
        return self._observe(), float(reward[0]), bool(terminated[0]), bool(truncated[0]), self._info(extra)

    def _observe(self) -> np.ndarray:
        obs = self._env.observe()[0]
        return obs if self.obs_scale == 1.0 else obs / np.float32(self.obs_scale)

"""The Gymnasium environment: one episode of the UAV placement problem over map bundles.

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
from uavplace.rl.tasks.placement.maps import MapSet


def with_overrides(kind: type, config: object, overrides: dict) -> object:
    """The settings ``config`` (a ``kind``, a dict of its fields or None) with ``overrides``, validated as the command
    line's are: an unknown field, or a value out of its range, is a ``ValueError`` of one line naming the field
    (``model_copy(update=...)`` would take anything)."""
    from pydantic import ValidationError

    from uavplace.schemas.base import validation_message

    try:
        base = config if isinstance(config, kind) else kind(**(config or {}))
        return kind.model_validate({**base.model_dump(), **overrides})
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise ValueError(f"{kind.__name__}.{field}: {message}") from None


def task_bundles(dataset: str | list[str], config: object, kind: type, root: str, overrides: dict) -> tuple[list, object]:
    """(the bundles of ``dataset``, a city name or list; the task's ``kind`` config from ``config``, a ``kind``, a
    dict of its fields or None, with ``overrides``): what the tracking and fleet environments are made from."""
    from uavplace.dataset.bundle import load_bundle

    merged = with_overrides(kind, config, overrides)
    names = [dataset] if isinstance(dataset, str) else list(dataset)
    return [load_bundle(n, root=root) for n in names], merged


def observation_bounds(config: object, *more_high: float) -> tuple[float, float]:
    """(low, high) of an observation: P_L and the clipped depth below, P_H, the clipped height, the edge's height
    (and ``more_high``) above."""
    low = min(config.p_l_db, -config.height_clip_m)
    return low, max(config.p_h_db, config.height_clip_m, config.edge_height_m, *more_high)


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


class UavTrackingEnv(gym.Env):
    """``uavplace/UavTracking-v0``: one episode of the tracking task (``rl.tasks.tracking``: a user who moves along a
    ray-traced route; 5 actions, the 4 moves and stay; a fixed horizon, ``truncated`` at its end, never
    ``terminated``). ``info``: ``action_mask`` (5), ``sinr_db``, ``position``, after a step ``covered`` and
    ``illegal``. ``dataset``: cities whose bundles have routes (or a loaded ``RouteSet``); ``config``: a
    ``TrackingConfig`` or a dict of its fields; ``**overrides``: its fields."""

    metadata = {"render_modes": []}

    def __init__(self, dataset, config=None, root: str = "data/processed", **overrides: object) -> None:  # noqa: ANN001
        from uavplace.rl.tasks.tracking import RouteSet, TrackingConfig, TrackingEnv

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
        from uavplace.rl.tasks.fleet import BatchedFleet, FleetConfig, FleetMaps

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

"""The tracking task's policies: placement policies in it, holding, its agent, the re-planning genie and the oracle.

The re-planning genie and the oracle (``privileged``) receive the ``TrackingEnv`` itself; every other policy receives a
``TrackingView`` (``rl.world.view.view_for``): its UAVs' positions, steps and measurements, and the public maps."""

from __future__ import annotations

import numpy as np

from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.tracking.config import ACTION_OF, STAY, TrackingConfig
from uavplace.rl.tasks.tracking.env import TrackingEnv, TrackingView
from uavplace.rl.tasks.tracking.maps import RouteSet, oracle_path
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.view import view_for


class MovesOnly:
    """A placement policy (``rl.tasks.placement.policies``: 4 moves, never stays) acting in the tracking env: it is
    shown the moves' legal mask only, and keeps acting by its own rule after it first reaches P_T."""

    def __init__(self, policy) -> None:  # noqa: ANN001 - a rl.tasks.placement.policies.Policy
        self.policy, self.name = policy, policy.name

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        self.policy.reset(rows, num_envs)

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingView) -> np.ndarray:
        return self.policy.act(obs, mask[:, :4], env)


class Holding:
    """A method without a stay action (a placement agent run unchanged, a placement baseline) with one rule on top:
    stay while its own measurement now (the SINR memory's centre, the cell it stands in) is at or above P_T, else
    act as ``policy`` does. ``policy`` still sees every observation, so a recurrent agent's state and a placement
    agent's mirror follow the episode while it holds; it reads nothing the UAV did not measure."""

    def __init__(self, policy) -> None:  # noqa: ANN001 - a tracking method (MovesOnly, PlacementInTracking)
        self.policy, self.name = policy, f"{policy.name} + hold"

    def bind(self, routes: RouteSet) -> Holding:
        """Lay ``policy`` on ``routes``' cities where it is laid (``PlacementInTracking.bind``): played alone (a copy
        in a Ray task), the held method is bound as it would be when played first."""
        if hasattr(self.policy, "bind"):
            self.policy.bind(routes)
        return self

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        self.policy.reset(rows, num_envs)

    @property
    def reads_observation(self) -> bool:
        return getattr(self.policy, "reads_observation", True)

    def act(self, obs: np.ndarray | None, mask: np.ndarray, env: TrackingView) -> np.ndarray:
        action = self.policy.act(obs, mask, env)
        return np.where(env.config.reaches(env.measured()), STAY, action)  # the SINR memory's centre


class PlacementInTracking:
    """A placement policy that reads placement observations (a trained placement agent, run unchanged) acting in the
    tracking env. A placement env over the same cities (``BatchedEnv``, built for the agent's own ``EnvConfig``, its
    users' maps blanked: ``MapSet.forget_users``) keeps the agent's channels (SINR memory, visited cells, homing cone,
    context) from the UAVs' positions and measurements (``TrackingView``), as if the user's map were the placement
    episode's; the agent sees its observations and that env's ``AgentView``, moves by its own rule (never stays) and
    keeps acting after it first reaches P_T. ``bind`` (``run_tracking`` calls it) lays it on the routes' cities."""

    reads_observation = False  # its agent reads the mirror's

    def __init__(self, policy, env: EnvConfig, name: str | None = None) -> None:  # noqa: ANN001 - a placement Policy
        self.policy, self.name = policy, name or policy.name
        self.env_config = env.model_copy(update={"rotate": False, "city_weights": {}, "split": None})
        self.mirror = None
        self.placement: MapSet | None = None
        self.bound: tuple = ()

    def bind(self, routes: RouteSet) -> PlacementInTracking:
        """Play on ``routes``' cities (as they are: a placement agent is not rotated): a placement canvas per city,
        with no user's map."""
        if routes.turns != 1:
            raise ValueError("a placement agent plays the routes as they are: a RouteSet without rotate")
        if self.bound != (id(routes),):
            seen = self.env_config.model_copy(update={"map_error": routes.config.map_error})  # the world's map, as it errs
            self.placement, self.bound, self.mirror = MapSet(routes.bundles, seen).forget_users(), (id(routes),), None
            maps = self.placement
            # per city, the view of its identity symmetry: its height and blocked canvases
            self.views = np.array([np.flatnonzero(maps.view_map == maps.symmetries * b)[0] for b in range(len(routes.bundles))])
            self.shift = maps.pad - routes.maps.pad
        return self

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        self.policy.reset(rows, num_envs)

    def _mirror(self, num_envs: int):  # noqa: ANN202 - a BatchedEnv
        from uavplace.rl.tasks.placement.env import BatchedEnv

        if self.placement is None:
            raise ValueError(f"{self.name}: bind(routes) first, as run_tracking does")
        if self.mirror is None or self.mirror.num_envs != num_envs:
            self.mirror = BatchedEnv(self.placement, num_envs, autoreset=False)
            self.begun = np.zeros(num_envs, bool)
        return self.mirror

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingView) -> np.ndarray:
        mirror = self._mirror(env.num_envs)
        rows = np.arange(env.num_envs)
        pos, sinr = env.pos + self.shift, env.measured()
        new = (env.t == 0) | ~self.begun
        if new.any():
            idx = rows[new]
            views = self.views[env.canvas[idx] // env.public.symmetries]  # each row's city (``PublicMaps.bundle_of``)
            ids = np.where(env.exhausted[idx], -1, 0)  # an episode, or a played-out queue's placeholder
            mirror.begin(idx, views, pos[idx, 0], pos[idx, 1], sinr[idx], ids)
            self.begun[idx] = True
        if (~new).any():
            idx = rows[~new]
            mirror.pos[idx], mirror.t[idx] = pos[idx], env.t[idx]
            mirror.measure(idx, sinr[idx])
        return self.policy.act(mirror.observe(), mask[:, :4], view_for(self.policy, mirror))


class TrackingAgent:
    """An agent trained on the tracking task (``uavrl train --task tracking``), acting on the observations it was
    trained with (``observation``: its ``TrackingConfig``); ``run_tracking`` plays it on a ``RouteSet`` of those."""

    def __init__(self, policy, observation: TrackingConfig, name: str) -> None:  # noqa: ANN001 - a DQNPolicy
        self.policy, self.observation, self.name = policy, observation, name

    @property
    def privileged(self) -> bool:
        """As privileged as the policy it plays (a genie laid on another observation still reads the env)."""
        return getattr(self.policy, "privileged", False)

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        self.policy.reset(rows, num_envs)

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingView) -> np.ndarray:
        return self.policy.act(obs, mask, env)


class ReplanningGenie:
    """The placement genie re-planned every step: knows the user's map now (not the future); stays while covered,
    else takes a shortest legal path toward the current P_T region."""

    name = "re-planning genie"
    privileged = True  # reads the user's map now: receives the env itself
    reads_observation = False

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        pass

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingEnv) -> np.ndarray:
        point = env.point()
        ny, nx = env.neighbours()
        steps = env.routes.steps[point[:, None], ny, nx].astype(np.int64)
        steps[~mask[:, :4]] = np.iinfo(np.int64).max
        here = env.routes.steps[point, env.pos[:, 0], env.pos[:, 1]]
        return np.where(here == 0, STAY, np.argmin(steps, axis=1))


class OraclePolicy:
    """The upper bound: knows the whole route and every map; follows ``oracle_path`` of its episode (computed when the
    episode starts), the most covered steps possible."""

    name = "oracle"
    privileged = True  # reads the whole route and every map: receives the env itself
    reads_observation = False

    def __init__(self) -> None:
        self.plans = np.zeros((0, 0, 2), np.int64)  # [num_envs, horizon + 1, 2]: each row's planned canvas cells
        self.planned = np.zeros(0, np.int64)  # the episode each row's plan is for

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        pass

    def plan(self, env: TrackingEnv, row: int) -> np.ndarray:
        r, p = int(env.route[row]), env.maps.pad
        canvas = env.routes.canvas[r]
        ny, nx = env.maps.shapes[canvas]
        t = np.arange(1, env.config.horizon + 1)
        points = env.routes.point(np.full(len(t), r), np.full(len(t), env.start_s[row]), t)
        sinr = env.routes.sinr[points, p : p + ny, p : p + nx]
        covered = env.config.reaches(sinr, env.routes.dead[points, p : p + ny, p : p + nx])
        legal = ~env.maps.blocked[canvas, p : p + ny, p : p + nx]
        path, _ = oracle_path(legal, covered, (int(env.pos[row, 0]) - p, int(env.pos[row, 1]) - p))
        return path + p

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingEnv) -> np.ndarray:
        n = env.num_envs
        if self.plans.shape[:2] != (n, env.config.horizon + 1):
            self.plans = np.zeros((n, env.config.horizon + 1, 2), np.int64)
            self.planned = np.full(n, -2, np.int64)
        for row in np.flatnonzero((env.t == 0) | (self.planned != env.episode_id)):  # episodes that just began
            self.plans[row], self.planned[row] = self.plan(env, row), env.episode_id[row]
        dy, dx = (self.plans[np.arange(n), env.t + 1] - env.pos).T
        return ACTION_OF[dy + 1, dx + 1]

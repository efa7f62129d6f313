"""Playing the tracking task's episodes with a policy (``run_tracking``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from uavplace.rl.tasks.tracking.env import TrackingEnv
from uavplace.rl.tasks.tracking.maps import RouteSet, episode_metrics
from uavplace.rl.world.view import view_for


@dataclass
class TrackingEpisodes:
    """What ``run_tracking`` returns: one row per episode, and each episode's covered steps ``[K, H]``; with
    ``record``, also the UAV's canvas cells ``path`` ``[K, H + 1, 2]`` (the start first) and the user's route point
    ``points`` ``[K, H + 1]`` (rows of ``RouteSet.sinr``) at each step."""

    table: pd.DataFrame
    covered: np.ndarray
    path: np.ndarray | None = None
    points: np.ndarray | None = None


def run_tracking(
    routes: RouteSet,
    policy,
    episodes: np.ndarray,
    *,
    num_envs: int = 256,
    record: bool = False,  # noqa: ANN001
) -> TrackingEpisodes:
    """Play ``episodes`` (``[K, 4]`` specs) to the horizon with ``policy`` (``rl.tasks.placement.policies`` interface: ``reset``,
    ``act(obs, mask, view)``, the view ``view_for`` gives: a ``TrackingView``, the env itself to a privileged policy;
    a policy with ``bind`` is bound to ``routes`` first); one row per episode with the metrics of ``episode_metrics`` (and with ``record``, the
    UAV's path and the user's route points, for drawing). A ``TrackingAgent`` whose observation differs from
    ``routes.config``'s plays the same episodes on routes laid out for its own (cells and paths shifted between
    the two canvases' paddings)."""
    own = getattr(policy, "observation", None)
    if own is not None and routes.config.observed_as(own) != routes.config:
        mine = RouteSet(routes.bundles, routes.config.observed_as(own))
        shift = mine.maps.pad - routes.maps.pad
        played = run_tracking(mine, policy, np.asarray(episodes, float) + [0, 0, shift, shift], num_envs=num_envs, record=record)
        if played.path is not None:
            played.path -= shift
        return played
    k, h = len(episodes), routes.config.horizon
    if hasattr(policy, "bind"):
        policy.bind(routes)
    env = TrackingEnv(routes, min(num_envs, k), queue=np.asarray(episodes, float))
    obs, info = env.reset()
    policy.reset(np.arange(env.num_envs), env.num_envs)
    covered = np.zeros((k, h), bool)
    path = np.zeros((k, h + 1, 2), np.int64) if record else None
    points = np.zeros((k, h + 1), np.int64) if record else None
    done = 0
    while done < k:
        live = ~env.exhausted
        ids, t = env.episode_id.copy(), env.t.copy()
        if record:
            path[ids[live], t[live]], points[ids[live], t[live]] = env.pos[live], env.point()[live]
        obs, _, _, truncated, info = env.step(policy.act(obs, info["action_mask"], view_for(policy, env)))
        covered[ids[live], t[live]] = info["covered"][live]
        finished = truncated & live
        if record and finished.any():  # the last step's cell and point, from before the env restarted these rows
            final = np.searchsorted(info["final_index"], np.flatnonzero(finished))
            path[ids[finished], h], points[ids[finished], h] = info["final_pos"][final], info["final_point"][final]
        done += int(finished.sum())
        if finished.any():
            policy.reset(np.flatnonzero(finished), env.num_envs)
    metrics = episode_metrics(covered)
    table = pd.DataFrame({"episode": np.arange(k), "route": episodes[:, 0].astype(int), "start_s": episodes[:, 1]} | metrics)
    table["city"] = [routes.names[int(r)][0] for r in table["route"]]
    table["kind"] = [routes.names[int(r)][2] for r in table["route"]]
    return TrackingEpisodes(table, covered, path, points)

"""Playing the tracking task's episodes with a policy (``run_tracking``)."""

from __future__ import annotations

from collections.abc import Callable
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

    @classmethod
    def joined(cls, parts: list[TrackingEpisodes]) -> TrackingEpisodes:
        """Contiguous pieces of one list of episodes (``run_tracking``'s ``first``), in order, as one."""
        recorded = all(p.path is not None for p in parts)
        return cls(
            pd.concat([p.table for p in parts], ignore_index=True),
            np.concatenate([p.covered for p in parts]),
            np.concatenate([p.path for p in parts]) if recorded else None,
            np.concatenate([p.points for p in parts]) if recorded else None,
        )


def run_tracking(
    routes: RouteSet,
    policy,
    episodes: np.ndarray,
    *,
    num_envs: int = 256,
    record: bool = False,  # noqa: ANN001
    first: int = 0,
    on_step: Callable[[int, int], None] | None = None,
) -> TrackingEpisodes:
    """Play ``episodes`` (``[K, 4]`` specs) to the horizon with ``policy`` (``rl.tasks.placement.policies`` interface: ``reset``,
    ``act(obs, mask, view)``, the view ``view_for`` gives: a ``TrackingView``, the env itself to a privileged policy;
    a policy with ``bind`` is bound to ``routes`` first); one row per episode with the metrics of ``episode_metrics`` (and with ``record``, the
    UAV's path and the user's route points, for drawing). A ``TrackingAgent`` whose observation differs from
    ``routes.config``'s plays the same episodes on routes laid out for its own (cells and paths shifted between
    the two canvases' paddings). ``first``: the episodes' place in a longer list (``eval.parallel`` plays one in
    contiguous pieces): their numbers, and so their random draws, as there. ``on_step(done, total)`` reports progress."""
    own = getattr(policy, "observation", None)
    if own is not None and routes.config.observed_as(own) != routes.config:
        mine = RouteSet(routes.bundles, routes.config.observed_as(own))
        shift = mine.maps.pad - routes.maps.pad
        moved = np.asarray(episodes, float) + [0, 0, shift, shift]
        played = run_tracking(mine, policy, moved, num_envs=num_envs, record=record, first=first, on_step=on_step)
        if played.path is not None:
            played.path -= shift
        return played
    k, h = len(episodes), routes.config.horizon
    if hasattr(policy, "bind"):
        policy.bind(routes)
    env = TrackingEnv(routes, min(num_envs, k), queue=np.asarray(episodes, float), first=first)
    env.observing = getattr(policy, "reads_observation", True)  # the oracle, the searcher, ... are handed None
    obs, info = env.reset()
    policy.reset(np.arange(env.num_envs), env.num_envs)
    covered = np.zeros((k, h), bool)
    path = np.zeros((k, h + 1, 2), np.int64) if record else None
    points = np.zeros((k, h + 1), np.int64) if record else None
    done = 0
    while done < k:
        live = ~env.exhausted
        ids, t = env.episode_id - first, env.t.copy()
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
            if on_step is not None:
                on_step(done, k)
    metrics = episode_metrics(covered)
    table = pd.DataFrame(
        {"episode": first + np.arange(k), "route": episodes[:, 0].astype(int), "start_s": episodes[:, 1]} | metrics
    )
    table["city"] = [routes.names[int(r)][0] for r in table["route"]]
    table["kind"] = [routes.names[int(r)][2] for r in table["route"]]
    return TrackingEpisodes(table, covered, path, points)

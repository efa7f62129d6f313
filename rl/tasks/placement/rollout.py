"""Play a fixed list of episodes with any policy, batched: the same episodes for every method."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.tasks.placement.policies import Policy
from uavplace.rl.world.maps import MOVES, MapSet
from uavplace.rl.world.view import view_for


def run_episodes(
    maps: MapSet,
    policy: Policy,
    episodes: np.ndarray,
    *,
    num_envs: int = 256,
    on_step: Callable[[int, int], None] | None = None,
    record: np.ndarray | None = None,
    first: int = 0,
) -> pd.DataFrame:
    """Play ``episodes`` (``[K, 3]`` specs from ``MapSet.sample_episodes``) to their end with ``policy``.

    Returns one row per episode: ``episode, view, city, user, rotation`` (the view's symmetry, 0-7), ``start_y, start_x``
    (the start's cell of the bundle's map, the view's symmetry undone, whatever the window), ``genie_steps`` (shortest possible), ``steps`` (moves played), ``success`` (P_T reached
    within ``t_max``) and ``return_`` (sum of rewards). ``on_step(done, total)`` reports progress.
    ``record``: episode numbers whose cells, start included, go to ``df.attrs["paths"]``
    (``{episode: [T + 1, 2] (iy, ix)}``, cells of the bundle's map, the view's rotation undone). ``first``: the
    episodes' place in a longer list (``eval.parallel`` plays one in contiguous pieces), which numbers them in the
    frame and the paths (``record`` counts from the first given; an episode's random draws are keyed by its start).
    """
    k = len(episodes)
    env = BatchedEnv(maps, min(num_envs, k), queue=episodes)
    obs, info = env.reset()
    policy.reset(np.arange(env.num_envs), env.num_envs)
    genie = np.zeros(k, np.int64)
    genie[env.episode_id[~env.exhausted]] = env.genie_steps()[~env.exhausted]
    steps = np.zeros(k, np.int64)
    success = np.zeros(k, bool)
    ret = np.zeros(k, np.float64)
    acc = np.zeros(env.num_envs, np.float64)
    wanted = np.zeros(k, bool)
    if record is not None:
        wanted[np.asarray(record, np.int64)] = True
    trail: dict[int, list[np.ndarray]] = {}
    paths: dict[int, np.ndarray] = {}

    def follow(rows: np.ndarray) -> None:
        for r in rows[wanted[env.episode_id[rows]] & ~env.exhausted[rows]]:
            trail[int(env.episode_id[r])] = [env.pos[r].copy()]

    follow(np.arange(env.num_envs))
    finished = 0
    while finished < k:
        actions = policy.act(obs, info["action_mask"], view_for(policy, env))
        live = ~env.exhausted
        ids = env.episode_id.copy()
        moved = env.pos.copy()
        obs, reward, terminated, truncated, info = env.step(actions)
        for r in np.flatnonzero(live & wanted[ids]):
            # After an episode ends the row restarts; its last cell is the move's target, not env.pos.
            here = env.pos[r] if not info["started"][r] else _landed(moved[r], actions[r], info["illegal"][r])
            trail[int(ids[r])].append(here.copy())
        acc += reward
        done = (terminated | truncated) & live
        if done.any():
            rows = np.flatnonzero(done)
            steps[ids[rows]] = info["steps"][rows]
            success[ids[rows]] = terminated[rows]
            ret[ids[rows]] = acc[rows]
            acc[rows] = 0.0
            finished += len(rows)
            for r in rows[wanted[ids[rows]]]:
                canvas = np.array(trail.pop(int(ids[r])), np.int64)  # [T + 1, 2] (y, x) in the view
                iy, ix = maps.unrotate(np.full(len(canvas), episodes[ids[r], 0]), canvas[:, 0], canvas[:, 1])
                paths[int(ids[r])] = np.stack([iy, ix], axis=1)
            follow(rows)
            policy.reset(rows, env.num_envs)
            fresh = rows[~env.exhausted[rows]]
            genie[env.episode_id[fresh]] = env.genie_steps()[fresh]
            if on_step is not None:
                on_step(finished, k)
    view = episodes[:, 0]
    scen = [maps.scenarios[v] for v in maps.scenario_of(view)]
    start_y, start_x = maps.unrotate(view, episodes[:, 1], episodes[:, 2])
    df = pd.DataFrame(
        {
            "episode": first + np.arange(k),
            "view": view,
            "city": [s.city for s in scen],
            "user": [s.user for s in scen],
            "rotation": maps.symmetry_of(view),
            "start_y": start_y,
            "start_x": start_x,
            "genie_steps": genie,
            "steps": steps,
            "success": success,
            "return_": ret,
        }
    )
    df.attrs["paths"] = {first + e: p for e, p in paths.items()}
    return df


def _landed(pos: np.ndarray, action: int, illegal: bool) -> np.ndarray:
    return pos if illegal else pos + MOVES[action]

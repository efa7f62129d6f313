"""Play a fixed list of episodes with any policy, batched: the same episodes for every method."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from rl.maps import MapSet
from rl.policies import Policy
from rl.vec_env import BatchedEnv


def run_episodes(
    maps: MapSet,
    policy: Policy,
    episodes: np.ndarray,
    *,
    num_envs: int = 256,
    on_step: Callable[[int, int], None] | None = None,
) -> pd.DataFrame:
    """Play ``episodes`` (``[K, 3]`` specs from ``MapSet.sample_episodes``) to their end with ``policy``.

    Returns one row per episode: ``episode, view, city, user, rotation, start_y, start_x,
    genie_steps`` (shortest possible), ``steps`` (moves played), ``success`` (P_T reached
    within ``t_max``) and ``return_`` (sum of rewards). ``on_step(done, total)`` reports progress.
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
    finished = 0
    while finished < k:
        actions = policy.act(obs, info["action_mask"], env)
        live = ~env.exhausted
        ids = env.episode_id.copy()
        obs, reward, terminated, truncated, info = env.step(actions)
        acc += reward
        done = (terminated | truncated) & live
        if done.any():
            rows = np.flatnonzero(done)
            steps[ids[rows]] = info["steps"][rows]
            success[ids[rows]] = terminated[rows]
            ret[ids[rows]] = acc[rows]
            acc[rows] = 0.0
            finished += len(rows)
            policy.reset(rows, env.num_envs)
            fresh = rows[~env.exhausted[rows]]
            genie[env.episode_id[fresh]] = env.genie_steps()[fresh]
            if on_step is not None:
                on_step(finished, k)
    view = episodes[:, 0]
    scen = [maps.scenarios[v // 4] for v in view]
    return pd.DataFrame(
        {
            "episode": np.arange(k),
            "view": view,
            "city": [s.city for s in scen],
            "user": [s.user for s in scen],
            "rotation": view % 4,
            "start_y": episodes[:, 1],
            "start_x": episodes[:, 2],
            "genie_steps": genie,
            "steps": steps,
            "success": success,
            "return_": ret,
        }
    )


def summarise(df: pd.DataFrame) -> dict[str, float]:
    """Success rate, and steps to P_T over all episodes with failures counted as infinite (> t_max).

    Quantiles are order statistics (``inverted_cdf``), so a quantile that falls on a failure is inf.
    """
    ok = df["success"].to_numpy()
    steps = np.where(ok, df["steps"], np.inf)
    ratio = np.where(ok, df["steps"] / np.maximum(df["genie_steps"], 1), np.inf)
    return {
        "success": float(ok.mean()),
        "median_steps": float(np.quantile(steps, 0.5, method="inverted_cdf")),
        "mean_steps_success": float(df.loc[ok, "steps"].mean()) if ok.any() else float("nan"),
        "p90_steps": float(np.quantile(steps, 0.9, method="inverted_cdf")),
        "steps_over_genie": float(np.quantile(ratio, 0.5, method="inverted_cdf")),
    }

"""Playing the fleet's episodes with a policy (``run_fleet``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from uavplace.rl.tasks.fleet.env import BatchedFleet, FleetView
from uavplace.rl.tasks.fleet.maps import FleetMaps, oracle_steps


def run_fleet(
    maps: FleetMaps,
    policy,
    episodes: np.ndarray,
    num_envs: int = 64,  # noqa: ANN001
    record: np.ndarray | None = None,
    first: int = 0,
    on_step: Callable[[int, int], None] | None = None,
) -> pd.DataFrame:
    """Play ``episodes`` with ``policy`` (``reset(rows, num_envs, uavs)``, ``act(mask, FleetView) -> [E, K]``); one
    row per episode: ``success`` (every user served at one step within ``t_max``), ``steps`` (to that step; ``t_max
    + 1`` when it failed), ``users_served`` (the share of users served at some step), ``oracle_steps`` and ``spl``
    (success x oracle steps / max(steps, oracle steps)); and, for ``eval.metrics``, the oracle's steps as
    ``genie_steps``, the user set as ``user``, the city, and the first UAV's start. ``record``: episode numbers whose
    paths are kept, ``attrs["paths"][i]`` [T + 1, K, 2] map cells of every UAV at every step. ``first``: the episodes'
    place in a longer list (``eval.parallel`` plays one in contiguous pieces), which numbers them (an episode's random
    draws are keyed by the episode itself, ``FleetMaps.episode_keys``). ``on_step(done, total)`` reports progress."""
    episodes = np.asarray(episodes, np.int64)
    cfg = maps.config
    n = min(num_envs, len(episodes))
    env = BatchedFleet(maps, n)
    steps = np.full(len(episodes), cfg.t_max + 1, np.int64)
    success = np.zeros(len(episodes), bool)
    share = np.zeros(len(episodes))
    nxt = min(n, len(episodes))
    kept = set() if record is None else {int(i) for i in record}
    paths: dict[int, list[np.ndarray]] = {}

    def remember(rows: np.ndarray) -> None:
        for r in rows:
            if int(env.episode_id[r]) in kept:
                paths.setdefault(int(env.episode_id[r]), []).append(env.pos[r] - maps.pad)

    env.begin(np.arange(n), episodes[:n], np.arange(n))
    policy.reset(np.arange(n), n, cfg.uavs)
    remember(np.arange(n))
    finished = 0
    while not env.done.all():
        running = np.flatnonzero(~env.done)
        _, terminated, truncated = env.step(policy.act(env.action_mask(), FleetView.of(env)))
        remember(running)
        ended = np.flatnonzero(terminated | truncated)
        for row in ended:
            i = env.episode_id[row]
            success[i], share[i] = terminated[row], (env.served_at[row] >= 0).mean()
            steps[i] = env.t[row] if terminated[row] else cfg.t_max + 1
        refill = ended[: max(0, len(episodes) - nxt)]
        if len(refill):
            env.begin(refill, episodes[nxt : nxt + len(refill)], np.arange(nxt, nxt + len(refill)))
            policy.reset(refill, n, cfg.uavs)
            remember(refill)
            nxt += len(refill)
        finished += len(ended)
        if len(ended) and on_step is not None:
            on_step(finished, len(episodes))
    oracle = oracle_steps(maps, episodes)
    spl = success * oracle / np.maximum(np.maximum(steps, oracle), 1)
    city, users, starts = maps.split(episodes)
    frame = pd.DataFrame(
        {
            "episode": first + np.arange(len(episodes)),
            "success": success,
            "steps": steps,
            "users_served": share,
            "oracle_steps": oracle,
            "spl": spl,
            # what the placement report's statistics read: the oracle in the genie's place, the user set as the user
            "genie_steps": oracle,
            "city": [maps.cities[int(c)].name for c in city],
            "user": ["-".join(map(str, sorted(u))) for u in users.tolist()],
            "view": city,
            "start_y": starts[:, 0, 0],
            "start_x": starts[:, 0, 1],
        }
    )
    frame.attrs["paths"] = {first + i: np.stack(p) for i, p in paths.items()}
    return frame

"""Policies that act on the batched environment: the genie and the simple baselines.

Every policy, learned or not, has the same interface (the evaluator scores any of them
the same way): ``reset(rows)`` when episodes (re)start in those rows, and
``act(obs, mask, env) -> [N] actions``. Only a privileged policy (``privileged = True``: the genie)
receives the environment itself; every other policy receives an ``rl.world.view.AgentView`` (``rl.tasks.placement.rollout``
hands it over): the observation, the legal-move mask, the UAV's own measurements and the building
map, never a user's map. Their random choices are drawn per episode and step from a stream of
their own name and seed (``episode_draws``), never from a generator shared across episodes.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from uavplace.rl.randomness import stream_key, uniforms
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.world.maps import MOVES
from uavplace.rl.world.rows import decode_obs


class Policy(Protocol):
    name: str

    def reset(self, rows: np.ndarray, num_envs: int) -> None: ...

    def act(self, obs: np.ndarray, mask: np.ndarray, env: BatchedEnv) -> np.ndarray: ...


def random_legal(mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A uniformly random legal action per row of ``mask`` [N, A] (a row with none gets 0)."""
    return pick_legal(mask, rng.random(mask.shape))


def pick_legal(mask: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The legal action of largest uniform ``u`` [N, A] per row of ``mask`` [N, A]: uniformly random (a row with none
    gets 0)."""
    return np.argmax(u * mask, axis=1)


def episode_draws(env: BatchedEnv, stream: np.uint64, count: int) -> np.ndarray:
    """[N, count] uniforms for each row's current episode and step (``rl.randomness``): the same in whatever order or
    batch the episodes are played."""
    return uniforms(stream, env.episode_keys(), env.t, count)


class GeniePolicy:
    """Knows the SINR everywhere: moves along a shortest legal path to the nearest target cell (BFS)."""

    name = "genie"
    privileged = True  # reads every user's map: receives the env itself

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        pass

    def act(self, obs: np.ndarray, mask: np.ndarray, env: BatchedEnv) -> np.ndarray:
        ny, nx = env.neighbours()
        steps = env.maps.steps[env.view[:, None], ny, nx].astype(np.int64)  # [N, 4]
        steps[~mask] = np.iinfo(np.int64).max
        return np.argmin(steps, axis=1)


class RandomWalkPolicy:
    """The paper's steered random walk: repeat the last move w.p. ``p_repeat`` (if legal), else a random legal move."""

    name = "steered random walk"

    def __init__(self, seed: int = 0, p_repeat: float = 0.4) -> None:
        self.stream = stream_key(self.name, seed)
        self.p_repeat = p_repeat
        self.last = np.zeros(0, np.int64)

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        if len(self.last) != num_envs:
            self.last = np.full(num_envs, -1, np.int64)
        self.last[rows] = -1

    def act(self, obs: np.ndarray, mask: np.ndarray, env: BatchedEnv) -> np.ndarray:
        n = len(mask)
        if len(self.last) != n:
            self.reset(np.arange(n), n)
        u = episode_draws(env, self.stream, 5)
        a = pick_legal(mask, u[:, :4])
        repeat = (self.last >= 0) & (u[:, 4] < self.p_repeat)
        repeat &= mask[np.arange(n), np.maximum(self.last, 0)]
        a = np.where(repeat, self.last, a)
        self.last = a
        return a


class GreedyPolicy:
    """Hill-climbing on measured SINR, from the observation only.

    If the last move raised the SINR and repeating it reaches an unvisited legal cell, repeat it;
    else go to a random unvisited legal neighbour; if every legal neighbour was visited, go to the
    one with the highest measured SINR (ties at random). Unvisited cells are those the SINR
    memory shows as P_H.
    """

    name = "greedy hill-climbing"

    def __init__(self, p_h_db: float, seed: int = 0) -> None:
        self.stream = stream_key(self.name, seed)
        self.p_h_db = p_h_db
        self.last = np.zeros(0, np.int64)
        self.prev = np.zeros(0, np.float32)

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        if len(self.last) != num_envs:
            self.last = np.full(num_envs, -1, np.int64)
            self.prev = np.full(num_envs, np.nan, np.float32)
        self.last[rows] = -1
        self.prev[rows] = np.nan

    def act(self, obs: np.ndarray, mask: np.ndarray, env: BatchedEnv) -> np.ndarray:
        n = len(mask)
        if len(self.last) != n:
            self.reset(np.arange(n), n)
        mem = obs[:, -1] if obs.dtype != np.uint8 else decode_obs(obs[:, -1])
        c = mem.shape[-1] // 2
        here = mem[:, c, c]
        neigh = mem[:, c + MOVES[:, 0], c + MOVES[:, 1]]  # [N, 4]
        unvisited = mask & (neigh >= self.p_h_db - 0.5)
        rows = np.arange(n)
        improved = (self.last >= 0) & (here > self.prev)
        keep = improved & unvisited[rows, np.maximum(self.last, 0)]
        u = episode_draws(env, self.stream, 8)
        explore = pick_legal(unvisited, u[:, :4])
        score = np.where(mask & ~unvisited, neigh, -np.inf) + u[:, 4:] * 1e-3
        best = np.argmax(score, axis=1)
        a = np.where(keep, self.last, np.where(unvisited.any(axis=1), explore, best))
        a = np.where(mask.any(axis=1), a, 0)
        self.last, self.prev = a, here
        return a

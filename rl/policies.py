"""Policies that act on the batched environment: the genie and the simple baselines.

Every policy, learned or not, has the same interface (the evaluator scores any of them
the same way): ``reset(rows)`` when episodes (re)start in those rows, and
``act(obs, mask, env) -> [N] actions``. Only the genie reads ``env``'s hidden state;
the others use what an agent may know (the observation, the legal-move mask, their
own past moves).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from uavplace.rl.maps import MOVES
from uavplace.rl.vec_env import BatchedEnv, decode_obs


class Policy(Protocol):
    name: str

    def reset(self, rows: np.ndarray, num_envs: int) -> None: ...

    def act(self, obs: np.ndarray, mask: np.ndarray, env: BatchedEnv) -> np.ndarray: ...


def random_legal(mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A uniformly random legal action per row of ``mask`` [N, 4] (a row with none gets 0)."""
    u = rng.random(mask.shape) * mask
    return np.argmax(u, axis=1)


class GeniePolicy:
    """Knows the SINR everywhere: moves along a shortest legal path to the nearest target cell (BFS)."""

    name = "genie"

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
        self.rng = np.random.default_rng(seed)
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
        a = random_legal(mask, self.rng)
        repeat = (self.last >= 0) & (self.rng.random(n) < self.p_repeat)
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
        self.rng = np.random.default_rng(seed)
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
        explore = random_legal(unvisited, self.rng)
        score = np.where(mask & ~unvisited, neigh, -np.inf) + self.rng.random((n, 4)) * 1e-3
        best = np.argmax(score, axis=1)
        a = np.where(keep, self.last, np.where(unvisited.any(axis=1), explore, best))
        a = np.where(mask.any(axis=1), a, 0)
        self.last, self.prev = a, here
        return a

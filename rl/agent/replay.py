"""FIFO replay of compact (uint8) observations, each stored once, with n-step returns.

The batched environment writes ``num_envs`` transitions per step into consecutive slots, so
the next observation of slot ``i`` is the observation stored at slot ``i + num_envs`` (the same
episode's next step), unless the episode ended at ``i``: a terminated transition needs no next
observation, and a truncated one keeps its final observation in a small side store (at most
one truncation per ``t_max`` transitions of an env, so ``capacity // t_max + 2 * num_envs``
side slots suffice). Memory: ``capacity * C * w * w`` bytes for the observations (5e5 x 2 x
61 x 61 = 3.5 GiB) plus 2 A + 11 bytes per slot (A actions: 19 bytes with placement's 4 moves).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from uavplace.infra.limits import check_limit


class Batch(NamedTuple):
    obs: np.ndarray  # [B, C, w, w] uint8
    action: np.ndarray  # [B] int64
    reward: np.ndarray  # [B] float32, the n-step discounted return
    discount: np.ndarray  # [B] float32, gamma**m, 0 where the episode terminated within the n steps
    next_obs: np.ndarray  # [B, C, w, w] uint8
    next_mask: np.ndarray  # [B, A] bool, legal actions at next_obs (A: 4 moves, 5 in the tracking task)
    genie: np.ndarray | None = None  # [B, A] bool, the genie's moves at obs (the replay's: all False if it stores none)


class ReplayBuffer:
    def __init__(
        self,
        capacity: int,
        num_envs: int,
        obs_shape: tuple[int, ...],
        t_max: int,
        n_step: int = 1,
        gamma: float = 0.99,
        n_actions: int = 4,
    ):
        self.num_envs = num_envs
        self.capacity = max(num_envs * (n_step + 2), (capacity // num_envs) * num_envs)
        self.n_step, self.gamma = n_step, gamma
        c = self.capacity
        # observation bytes, masks, action, reward, flags, index
        slot = int(np.prod(obs_shape)) + 2 * n_actions + 1 + 4 + 1 + 1 + 4
        check_limit(
            "replay_bytes",
            c * slot * (1 + 1 / t_max),
            "buffer_size",
            f"replay memory of {c:,} transitions [bytes]",
            field="buffer_size",
        )
        self.obs = np.zeros((c, *obs_shape), np.uint8)
        self.mask = np.zeros((c, n_actions), bool)
        self.genie = np.zeros((c, n_actions), bool)
        self.action = np.zeros(c, np.int8)
        self.reward = np.zeros(c, np.float32)
        self.terminated = np.zeros(c, bool)
        self.truncated = np.zeros(c, bool)
        self.side_index = np.full(c, -1, np.int32)
        self.side_size = c // t_max + 2 * num_envs
        self.side_obs = np.zeros((self.side_size, *obs_shape), np.uint8)
        self.side_mask = np.zeros((self.side_size, n_actions), bool)
        self.pos = 0  # next slot to write (a multiple of num_envs)
        self.size = 0  # slots written so far, up to capacity
        self.side_pos = 0

    def __len__(self) -> int:
        return self.size

    def add(
        self,
        obs: np.ndarray,
        mask: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        final_obs: np.ndarray,
        final_mask: np.ndarray,
        genie: np.ndarray | None = None,
    ) -> None:
        """One vector step: ``[N, ...]`` arrays; ``final_obs``/``final_mask`` hold the truncated rows' last
        observation and mask (in row order of ``np.flatnonzero(truncated)``); ``genie`` the genie's moves at
        ``obs`` (``BatchedEnv.genie_moves``) for a run that learns them."""
        n = self.num_envs
        s = slice(self.pos, self.pos + n)
        self.obs[s], self.mask[s], self.action[s] = obs, mask, action
        self.genie[s] = False if genie is None else genie
        self.reward[s], self.terminated[s], self.truncated[s] = reward, terminated, truncated
        self.side_index[s] = -1
        rows = np.flatnonzero(truncated)
        if len(rows):
            side = (self.side_pos + np.arange(len(rows))) % self.side_size
            self.side_obs[side], self.side_mask[side] = final_obs, final_mask
            self.side_index[self.pos + rows] = side
            self.side_pos = int((self.side_pos + len(rows)) % self.side_size)
        self.pos = (self.pos + n) % self.capacity
        self.size = min(self.size + n, self.capacity)

    def can_sample(self) -> bool:
        return self.size > self.num_envs * (self.n_step + 1)

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """Uniform over slots whose n-step successors are written (the newest n * num_envs are left out)."""
        n, c = self.num_envs, self.capacity
        usable = self.size - n * self.n_step
        oldest = (self.pos - self.size) % c
        idx = (oldest + rng.integers(0, usable, batch_size)) % c
        ret = np.zeros(batch_size, np.float32)
        disc = np.ones(batch_size, np.float32)
        alive = np.ones(batch_size, bool)
        last = idx.copy()
        for k in range(self.n_step):
            j = (idx + k * n) % c
            ret += np.where(alive, disc * self.reward[j], 0.0)
            disc = np.where(alive, disc * self.gamma, disc)
            last = np.where(alive, j, last)
            ended = alive & (self.terminated[j] | self.truncated[j])
            alive &= ~ended
        nxt = (last + n) % c
        term = self.terminated[last]
        trunc = self.truncated[last]
        next_obs = self.obs[nxt]
        next_mask = self.mask[nxt]
        if trunc.any():
            side = self.side_index[last[trunc]]
            next_obs[trunc] = self.side_obs[side]
            next_mask[trunc] = self.side_mask[side]
        return Batch(
            obs=self.obs[idx],
            action=self.action[idx].astype(np.int64),
            reward=ret,
            discount=np.where(term, 0.0, disc).astype(np.float32),
            next_obs=next_obs,
            next_mask=next_mask,
            genie=self.genie[idx],
        )

    # -- persistence (resume) -----------------------------------------------------------------------
    _ARRAYS = ("obs", "mask", "genie", "action", "reward", "terminated", "truncated", "side_index", "side_obs", "side_mask")

    _SLOTS = ("obs", "mask", "genie", "action", "reward", "terminated", "truncated", "side_index")

    def save(self, path: str | Path) -> None:
        """The written slots only: until the buffer is full they are the first ``size`` (a paper-preset
        replay is 3.7 GB full, a fraction of that early in a run)."""
        n = self.size
        arrays = {k: getattr(self, k)[:n] if k in self._SLOTS else getattr(self, k) for k in self._ARRAYS}
        np.savez(path, **arrays, counters=np.array([self.pos, self.size, self.side_pos]))

    def load(self, path: str | Path) -> None:
        with np.load(path, allow_pickle=False) as z:
            pos, size, side_pos = (int(v) for v in z["counters"])
            for k in self._ARRAYS:
                mine = getattr(self, k)
                if k == "genie" and k not in z.files:  # a replay saved before runs could store the genie's moves
                    mine[:] = False
                    continue
                want = (size, *mine.shape[1:]) if k in self._SLOTS else mine.shape
                if z[k].shape != want or size > self.capacity:
                    raise ValueError(f"replay {path}: {k} has shape {z[k].shape}, this run's is {want}")
                mine[: len(z[k])] = z[k]
            self.pos, self.size, self.side_pos = pos, size, side_pos

"""The episode rows every batched environment stands on (``EpisodeRows``: rows of episodes drawn from a seed or taken
from a queue), the observation's byte encoding (``encode_obs`` / ``decode_obs``) and the check of a restored state
(``refuse_bad_rows``)."""

from __future__ import annotations

import numpy as np

from uavplace.rl.world.maps import MOVES

#: ``encode_obs``: uint8 = round(value) + OBS_OFFSET, clipped to [0, 255]: values -150 .. +105 (dB or m).
OBS_OFFSET = 150


def refuse_bad_rows(source: object, problems: dict[str, np.ndarray], on_blocked: np.ndarray) -> None:
    """A restored env state's check (``check_state``): ``InputError`` naming ``source``, the field and the first env
    row where ``problems[field]`` ``[N]`` holds, or where ``on_blocked`` ``[N]`` (a UAV on a blocked cell) does."""
    from uavplace.schemas import InputError

    for name, bad in problems.items():
        if bad.any():
            raise InputError(source, f"env row {int(np.argmax(bad))}: {name} out of range or not finite", field=name)
    if on_blocked.any():
        raise InputError(source, "a UAV stands in a blocked cell", field="pos")


def encode_obs(obs: np.ndarray) -> np.ndarray:
    """float observation -> uint8 (1 dB / 1 m resolution, values -150 .. 105)."""
    return np.clip(np.rint(obs) + OBS_OFFSET, 0, 255).astype(np.uint8)


def decode_obs(obs: np.ndarray) -> np.ndarray:
    """uint8 observation -> float32."""
    return obs.astype(np.float32) - OBS_OFFSET


class EpisodeRows:
    """What the batched environments share: ``num_envs`` rows of episodes (placement's ``BatchedEnv``, the tracking
    task's ``rl.tasks.tracking.TrackingEnv``), drawn with the generator seeded by ``reset(seed)`` (``_sample``) or taken in
    order from ``queue`` (episode specs, one row each) when one is given: evaluation then plays exactly those, and
    ``exhausted`` tells which rows have no episode left (a queue's episode ids count from ``first``: the queue's
    place in a longer list, whose per-episode random draws it keeps, ``eval.parallel``). A subclass starts the
    episodes (``_start``) and observes them.

    The trainer (``rl.agent.train``) reads every environment through one interface: ``reset(seed)``, ``step(actions)``
    (``info["final_index"]``, ``final_obs`` and ``final_mask`` of the rows whose episodes were cut short, then
    ``action_mask`` for the next move), ``observe``, ``action_mask``, ``sinr_here``, ``genie_moves`` (a training aid),
    ``neighbour_visits`` where the revisit penalty is trained, and ``state_arrays``, ``check_state``,
    ``_episodes_started`` and ``rng``, what a checkpoint keeps (``rl.tasks.fleet.FleetTrainEnv`` offers the same)."""

    def _init_rows(self, num_envs: int, queue: np.ndarray | None, dtype: type = np.int64, first: int = 0) -> None:
        self.num_envs = num_envs
        self.queue = None if queue is None else np.asarray(queue, dtype)
        self.queue_pos = 0
        self.queue_first = first
        self.exhausted = np.zeros(num_envs, bool)
        self.rng = np.random.default_rng()
        self._episodes_started = 0
        self._rows = np.arange(num_envs)

    def _sample(self, k: int) -> np.ndarray:
        """``k`` episode specs drawn with ``rng``."""
        raise NotImplementedError

    def _start(self, idx: np.ndarray) -> None:
        """Begin the next episodes in rows ``idx`` (``_next_specs``)."""
        raise NotImplementedError

    def _next_specs(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``k`` episode specs and their episode ids (-1 where a queue has run out: those rows replay the queue's first
        episode as a placeholder and are ``exhausted``)."""
        if self.queue is None:
            ids = self._episodes_started + np.arange(k)
            self._episodes_started += k
            return self._sample(k), ids
        take = min(k, len(self.queue) - self.queue_pos)
        specs = np.zeros((k, self.queue.shape[1]), self.queue.dtype)
        specs[:] = self.queue[0] if len(self.queue) else 0
        specs[:take] = self.queue[self.queue_pos : self.queue_pos + take]
        ids = np.where(np.arange(k) < take, self.queue_first + self.queue_pos + np.arange(k), -1)
        self.queue_pos += take
        return specs, ids

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self._episodes_started = 0
        self.queue_pos = 0
        self._start(self._rows)
        return self.observe(), self.info()

    def neighbours(self, idx: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Canvas ``(y, x)`` of the 4 cells the moves lead to, each ``[len(idx), 4]``."""
        idx = self._rows if idx is None else idx
        return self.pos[idx, None, 0] + MOVES[None, :, 0], self.pos[idx, None, 1] + MOVES[None, :, 1]

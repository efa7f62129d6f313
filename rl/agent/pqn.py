"""PQN (Gallici et al., 2024, "Simplifying deep temporal difference learning"): Q-learning on the batched
env's rollouts, without replay or target network (``DQNConfig.learner = "pqn"``).

Each round acts ``rollout_steps`` moves in every env (the same epsilon-greedy rule as DQN), then fits the
Q-network to Q(lambda) returns computed backward over the rollout, with the network as it acted::

    G_t = r_t                                                            terminated at t
    G_t = r_t + gamma * max_a Q(final_t, a)                              truncated at t (its final observation)
    G_t = r_t + gamma * max_a Q(s_T, a)                                  the rollout's last move (s_T: where it stands)
    G_t = r_t + gamma * (lambda * G_{t+1} + (1 - lambda) * max_a Q(s_{t+1}, a))   otherwise

(max over the legal moves), in ``epochs`` passes of shuffled minibatches of ``batch_size`` (the Huber loss,
the genie-move head's loss added when ``aux_genie`` > 0). ``layer_norm`` keeps the bootstrap stable
without a target network.

A recurrent network (``DQNConfig.recurrent``) learns on whole env rollouts instead of shuffled moves: each
rollout keeps the state its env began it with (``Rollout.h0``), and the network is unrolled from it (the state
restarting at each episode's start), ``batch_size // rollout_steps`` envs a minibatch.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from uavplace.rl.agent.dqn import DQN, masked_argmax, to_tensor


class Rollout:
    """``steps`` vector steps of ``num_envs`` envs: compact observations, masks, moves, rewards, ends, and the
    final observation of each truncated row (``[steps, num_envs, ...]`` arrays; masks ``n_actions`` wide); ``h0``
    ``[num_envs, hidden]``, a recurrent network's state in each env when the rollout began (``hidden`` 0: none)."""

    def __init__(self, steps: int, num_envs: int, obs_shape: tuple[int, ...], hidden: int = 0, n_actions: int = 4) -> None:
        self.steps = steps
        self.h0 = np.zeros((num_envs, hidden), np.float32)
        self.obs = np.zeros((steps, num_envs, *obs_shape), np.uint8)
        self.mask = np.zeros((steps, num_envs, n_actions), bool)
        self.genie = np.zeros((steps, num_envs, n_actions), bool)
        self.action = np.zeros((steps, num_envs), np.int64)
        self.reward = np.zeros((steps, num_envs), np.float32)
        self.terminated = np.zeros((steps, num_envs), bool)
        self.truncated = np.zeros((steps, num_envs), bool)
        self.final_obs = np.zeros((steps, num_envs, *obs_shape), np.uint8)
        self.final_mask = np.zeros((steps, num_envs, n_actions), bool)
        self.t = 0  # vector steps stored so far

    @property
    def full(self) -> bool:
        return self.t == self.steps

    @property
    def first(self) -> np.ndarray:
        """``[steps, num_envs]``: the moves that start an episode after the rollout began (a recurrent state restarts)."""
        out = np.zeros_like(self.terminated)
        out[1:] = self.terminated[:-1] | self.truncated[:-1]
        return out

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
        """One vector step, as ``ReplayBuffer.add`` takes it (``final_*``: the truncated rows', in row order)."""
        t = self.t
        self.obs[t], self.mask[t], self.action[t], self.reward[t] = obs, mask, action, reward
        self.terminated[t], self.truncated[t] = terminated, truncated
        self.genie[t] = False if genie is None else genie
        rows = np.flatnonzero(truncated)
        if len(rows):
            self.final_obs[t, rows], self.final_mask[t, rows] = final_obs, final_mask
        self.t += 1

    _ARRAYS = ("obs", "mask", "genie", "action", "reward", "terminated", "truncated", "final_obs", "final_mask", "h0")

    def save(self, path: Path) -> None:
        np.savez(path, t=np.int64(self.t), **{k: getattr(self, k) for k in self._ARRAYS})

    def load(self, path: Path) -> None:
        with np.load(path, allow_pickle=False) as z:
            for k in self._ARRAYS:
                if k == "h0" and k not in z and not self.h0.size:
                    continue  # a feedforward rollout saved before recurrent networks: it has no state
                getattr(self, k)[...] = z[k]
            self.t = int(z["t"])


def q_lambda_returns(
    reward: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    q_next: np.ndarray,
    q_final: np.ndarray,
    gamma: float,
    lam: float,
) -> np.ndarray:
    """The Q(lambda) targets ``[T, N]`` of a rollout (module docstring). ``q_next[t]``: max legal Q at the
    observation after move ``t`` in the same slot (``q_next[T-1]``: where the envs stand now); ``q_final[t]``:
    at the final observation of a row truncated at ``t`` (read there only)."""
    out = np.zeros_like(reward, dtype=np.float32)
    ahead = q_next[-1]  # beyond the rollout the return is its bootstrap, so the last move's target is one-step
    for t in reversed(range(len(reward))):
        boot = np.where(truncated[t], q_final[t], q_next[t])
        carry = np.where(truncated[t], boot, lam * ahead + (1.0 - lam) * boot)
        ahead = reward[t] + gamma * np.where(terminated[t], 0.0, carry)
        out[t] = ahead
    return out


def legal_max(q: torch.Tensor, mask: np.ndarray) -> np.ndarray:
    """Max over the legal moves of Q ``[..., A]`` (``mask`` the same shape): ``[...]``."""
    legal = torch.from_numpy(mask).to(q.device)
    flat = q.reshape(-1, q.shape[-1])
    best = flat.gather(1, masked_argmax(flat, legal.reshape(flat.shape))[:, None])
    return best.reshape(q.shape[:-1]).cpu().numpy()


def max_q(agent: DQN, obs: np.ndarray, mask: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Max over the legal moves of the online network's Q ``[B]`` (evaluation mode, no gradient)."""
    out = np.zeros(len(obs), np.float32)
    agent.online.eval()
    with torch.no_grad():
        for i in range(0, len(obs), chunk):
            out[i : i + chunk] = legal_max(agent.online(to_tensor(obs[i : i + chunk], agent.device)), mask[i : i + chunk])
    return out


def minibatches(n: int, size: int, epochs: int, rng: np.random.Generator) -> Iterator[np.ndarray]:
    """``epochs`` passes over ``range(n)`` in a fresh shuffled order each, as sorted index arrays of ``size`` (a
    remainder short of ``size`` is left out of that pass)."""
    for _ in range(epochs):
        order = rng.permutation(n)
        for i in range(0, n - size + 1, size):
            yield np.sort(order[i : i + size])


def pqn_round(
    agent: DQN, rollout: Rollout, obs: np.ndarray, mask: np.ndarray, lr: float, rng: np.random.Generator
) -> list[float]:
    """Fit ``agent.online`` to the full ``rollout``'s Q(lambda) targets (``obs``/``mask``: where the envs stand
    now); returns the TD loss of each minibatch."""
    if agent.hidden is not None:
        return recurrent_round(agent, rollout, obs, mask, lr, rng)
    cfg = agent.config
    steps, n = rollout.action.shape
    flat, actions = steps * n, rollout.mask.shape[-1]
    following = np.concatenate([rollout.obs[1:], obs[None]])  # s_{t+1} of every slot
    following_mask = np.concatenate([rollout.mask[1:], mask[None]])
    q_next = max_q(agent, following.reshape(flat, *obs.shape[1:]), following_mask.reshape(flat, actions)).reshape(steps, n)
    q_final = np.zeros((steps, n), np.float32)
    cut = rollout.truncated
    if cut.any():
        q_final[cut] = max_q(agent, rollout.final_obs[cut], rollout.final_mask[cut])
    target = q_lambda_returns(rollout.reward, rollout.terminated, cut, q_next, q_final, cfg.gamma, cfg.q_lambda).reshape(flat)
    obs_flat = rollout.obs.reshape(flat, *obs.shape[1:])
    action, genie = rollout.action.reshape(flat), rollout.genie.reshape(flat, actions)
    return [
        agent.fit(obs_flat[idx], action[idx], torch.from_numpy(target[idx]), genie[idx], lr)
        for idx in minibatches(flat, cfg.batch_size, cfg.epochs, rng)
    ]


def recurrent_round(
    agent: DQN, rollout: Rollout, obs: np.ndarray, mask: np.ndarray, lr: float, rng: np.random.Generator
) -> list[float]:
    """``pqn_round`` for a recurrent network: the targets from the network unrolled over the rollout from
    ``rollout.h0`` (where the envs stand now and each truncated row's final observation: one step more from the
    state before it), then ``epochs`` passes over shuffled groups of whole env rollouts."""
    cfg, net, device = agent.config, agent.online, agent.device
    steps, n = rollout.action.shape
    first = rollout.first
    net.eval()
    with torch.no_grad():
        states = net.unroll(
            to_tensor(rollout.obs, device), torch.from_numpy(rollout.h0).to(device), torch.from_numpy(first).to(device)
        )  # [T, N, hidden]: the state after each move's observation
        q_acted = legal_max(net.head(states), rollout.mask)  # [T, N]
        q_now = legal_max(net.step(to_tensor(obs, device), states[-1])[0], mask)  # [N]
        q_final = np.zeros((steps, n), np.float32)
        cut = rollout.truncated
        if cut.any():
            t, row = np.nonzero(cut)
            q_cut, _ = net.step(to_tensor(rollout.final_obs[t, row], device), states[t, row])
            q_final[t, row] = legal_max(q_cut, rollout.final_mask[t, row])
    q_next = np.concatenate([q_acted[1:], q_now[None]])
    target = q_lambda_returns(rollout.reward, rollout.terminated, cut, q_next, q_final, cfg.gamma, cfg.q_lambda)
    return [
        agent.fit(
            rollout.obs[:, envs],
            rollout.action[:, envs],
            torch.from_numpy(target[:, envs]),
            rollout.genie[:, envs],
            lr,
            h0=rollout.h0[envs],
            first=first[:, envs],
        )
        for envs in minibatches(n, cfg.sequences_per_batch, cfg.epochs, rng)
    ]

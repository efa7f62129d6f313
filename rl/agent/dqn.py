"""Double DQN with a dueling head, legal-move masking and the paper's steered exploration.

The update, in one screen (``DQN.update``)::

    q      = online(obs)[a]                                   # [B]
    a*     = argmax over legal moves of online(next_obs)      # double Q: the online net picks
    target = R_n + discount * target_net(next_obs)[a*]        # ... the target net evaluates
    loss   = huber(q, target); clip grad norm; Adam step

``R_n``/``discount`` are the n-step return and ``gamma**n`` (0 past a terminal state), from
the replay; a truncated episode bootstraps from its final observation (no single done flag).
PQN (``rl/agent/pqn.py``) takes the same gradient step (``DQN.fit``) towards its own targets.
"""

from __future__ import annotations

import contextlib
import copy

import numpy as np
import torch
from torch import nn

from uavplace.infra.device import NETWORK_PRECISIONS, torch_device
from uavplace.infra.limits import check_limit
from uavplace.rl.agent.config import DQNConfig
from uavplace.rl.agent.network import FoveaQNetwork, MeanQ, QNetwork
from uavplace.rl.agent.replay import Batch
from uavplace.rl.randomness import stream_key
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.tasks.placement.policies import episode_draws, pick_legal, random_legal
from uavplace.rl.world.rows import OBS_OFFSET


def revisit_penalty(visits: np.ndarray, weight: float, device: torch.device) -> torch.Tensor:
    """``[N, 4]`` ``weight`` times ``visits``, the earlier visits of the cell each move leads to
    (``BatchedEnv.neighbour_visits``): what the revisit rule takes off each move's Q."""
    return torch.from_numpy(visits.astype(np.float32) * np.float32(weight)).to(device)


def make_network(config: DQNConfig, in_channels: int, window: int) -> nn.Module:
    """The Q-network ``config.network`` names, with the config's sizes; ``config.ensemble`` of them as one agent
    (``MeanQ``) when it is above 1. Its size is counted on torch's meta device first (no memory) and refused past
    the limit ``network_params``: the sizes come from a run.json or ``--set`` and could ask for any amount."""
    with torch.device("meta"):
        count = sum(p.numel() for p in _network(config, in_channels, window).parameters())
    check_limit(
        "network_params",
        count,
        "hidden, conv_channels, fovea, ensemble, env.window",
        f"parameters of a {config.network} network of {config.ensemble} member(s)",
        field="config",
    )
    return _network(config, in_channels, window)


def _network(config: DQNConfig, in_channels: int, window: int) -> nn.Module:
    if config.ensemble > 1:
        member = config.model_copy(update={"ensemble": 1})
        return MeanQ([_network(member, in_channels, window) for _ in range(config.ensemble)])
    sizes = {
        "hidden": config.hidden,
        "dropout": config.dropout,
        "aux": config.aux_genie > 0,
        "layer_norm": config.layer_norm,
        "recurrent": config.recurrent,
        "n_actions": config.n_actions,
    }
    if config.network == "fovea":
        return FoveaQNetwork(
            in_channels, window, fovea=config.fovea, extremes=config.pool_extremes, middle=config.pool_middle, **sizes
        )
    return QNetwork(in_channels, window, channels=config.conv_channels, **sizes)


def to_tensor(obs: np.ndarray, device: torch.device | None = None) -> torch.Tensor:
    """uint8 (compact) or float observations -> float32 tensor in dB / m, on ``device``."""
    if obs.dtype == np.uint8:  # decode_obs, in torch (faster; on a GPU the uint8 bytes travel, not floats)
        return torch.from_numpy(obs).to(device).to(torch.float32).sub_(OBS_OFFSET)
    return torch.from_numpy(obs.astype(np.float32, copy=False)).to(device)


def masked_argmax(q: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """argmax over legal actions: ``q`` [B, A], ``mask`` [B, A] bool -> [B]."""
    return q.masked_fill(~mask, float("-inf")).argmax(dim=1)


def genie_move_loss(logits: torch.Tensor, genie: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of ``logits`` ``[B, A]`` against the set of the genie's moves ``genie`` ``[B, A]`` bool
    (``-log`` of the probability given to the set), averaged over the rows with a genie move."""
    has = genie.any(dim=1)
    if not has.any():
        return logits.sum() * 0.0
    log_p = torch.log_softmax(logits[has], dim=1)
    return -torch.logsumexp(log_p.masked_fill(~genie[has], float("-inf")), dim=1).mean()


class DQN:
    """The online and target networks, the optimiser and the action rule (with a recurrent network, its state in
    each of the ``num_envs`` training envs, ``hidden``)."""

    def __init__(self, config: DQNConfig, in_channels: int, window: int, fast: bool = True) -> None:
        self.config = config
        self.device = torch_device(config.device)
        self.online = make_network(config, in_channels, window).to(self.device)
        # ``fast``: the same computation, arranged for speed (benchmarks/bench_train.py --paper-speed measures it
        # against fast=False): a convolutional network's weights and inputs in channels-last order, its eval-mode
        # values (acting, the double-Q target) with the batch norms folded (``QNetwork.forward_eval``), and Adam and
        # the gradient clipping each in one fused pass over the parameters.
        self.fast = fast
        if fast and isinstance(self.online, QNetwork):
            self.online = self.online.to(memory_format=torch.channels_last)
        self.target = copy.deepcopy(self.online)
        self.target.eval()
        self.optimizer = torch.optim.Adam(self.online.parameters(), lr=config.lr_start, fused=fast or None)
        self.updates = 0
        self.hidden = self.online.initial_state(config.num_envs) if config.recurrent else None

    def reset_state(self, rows: np.ndarray) -> None:
        """A new episode in these training envs: their recurrent state restarts from zeros (none to reset without one)."""
        if self.hidden is not None:
            self.hidden[torch.from_numpy(np.asarray(rows, np.int64)).to(self.device)] = 0.0

    def state(self) -> np.ndarray:
        """The training envs' recurrent state ``[num_envs, hidden]`` (``[num_envs, 0]`` without one)."""
        if self.hidden is None:
            return np.zeros((self.config.num_envs, 0), np.float32)
        return self.hidden.cpu().numpy()

    def q_values(self, obs: np.ndarray) -> torch.Tensor:
        """Q ``[N, A]`` of the training envs' observations (a recurrent network's state moves on with them)."""
        self.online.eval()
        with torch.no_grad():
            x = self.input(obs)
            if self.hidden is None:
                return self.evaluate(self.online, x)
            q, self.hidden = self.online.step(x, self.hidden)
            return q

    def act(
        self,
        obs: np.ndarray,
        mask: np.ndarray,
        eps: float,
        last: np.ndarray,
        rng: np.random.Generator,
        visits: np.ndarray | None = None,
    ) -> np.ndarray:
        """The paper's rule: w.p. ``p_repeat * eps`` repeat ``last`` (if legal), w.p. ``(1 - p_repeat) * eps``
        a random legal move, else the legal move of highest Q (less ``train_revisit_penalty`` times ``visits``
        ``[N, 4]``, the earlier visits of the cell each move leads to, when both are given)."""
        n = len(mask)
        q = self.q_values(obs)
        if visits is not None and self.config.train_revisit_penalty > 0:
            q = q - revisit_penalty(visits, self.config.train_revisit_penalty, self.device)
        greedy = masked_argmax(q, torch.from_numpy(mask).to(self.device)).cpu().numpy()
        u = rng.random(n)
        explore_move = random_legal(mask, rng)
        can_repeat = (last >= 0) & mask[np.arange(n), np.maximum(last, 0)]
        repeat = (u < self.config.p_repeat * eps) & can_repeat
        explore = (u < eps) & ~repeat
        return np.where(repeat, last, np.where(explore, explore_move, greedy))

    def td_target(self, batch: Batch) -> torch.Tensor:
        """Double-Q n-step target ``[B]``, legal moves only."""
        next_obs = self.input(batch.next_obs)
        next_mask = torch.from_numpy(batch.next_mask).to(self.device)
        with torch.no_grad():
            self.online.eval()
            best = masked_argmax(self.evaluate(self.online, next_obs), next_mask)  # [B]
            q_next = self.evaluate(self.target, next_obs).gather(1, best[:, None]).squeeze(1)  # [B]
        reward, discount = (torch.from_numpy(a).to(self.device) for a in (batch.reward, batch.discount))
        return reward + discount * q_next

    def update(self, batch: Batch, lr: float) -> float:
        """One gradient step towards the double-Q target; returns the TD loss."""
        return self.fit(batch.obs, batch.action, self.td_target(batch), batch.genie, lr)

    def fit(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        target: torch.Tensor,
        genie: np.ndarray | None,
        lr: float,
        h0: np.ndarray | None = None,
        first: np.ndarray | None = None,
    ) -> float:
        """One gradient step of ``Q(obs, action)`` towards ``target`` ``[B]`` (Huber); returns that TD loss. With
        ``aux_genie`` > 0 the genie-move head's loss on ``genie`` ``[B, A]`` is added to what is minimised.

        A recurrent network learns on sequences: ``obs`` ``[T, B, ...]`` unrolled from the states ``h0``
        ``[B, hidden]``, restarting where ``first`` ``[T, B]`` marks an episode's start; ``action``, ``target`` and
        ``genie`` are then ``[T, B]`` (``[T, B, 4]``), and every step of every sequence counts alike."""
        self.online.train()
        x = self.input(obs)
        if h0 is None:
            z = self.online.embed(x)
        else:
            first_t = torch.from_numpy(np.asarray(first, bool)).to(self.device)
            z = self.online.unroll(x, torch.from_numpy(h0).to(self.device), first_t).flatten(0, 1)
        action_t = torch.from_numpy(np.asarray(action, np.int64).reshape(-1)).to(self.device)
        q = self.online.head(z).gather(1, action_t[:, None]).squeeze(1)  # [B] (or [T * B])
        td_loss = torch.nn.functional.smooth_l1_loss(q, target.reshape(-1).to(self.device))
        loss = td_loss
        if self.config.aux_genie > 0:
            genie_t = torch.from_numpy(genie.reshape(-1, genie.shape[-1])).to(self.device)
            loss = loss + self.config.aux_genie * genie_move_loss(self.online.aux(z), genie_t)
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.online.parameters(), self.config.grad_clip, foreach=self.fast or None)
        self.optimizer.step()
        self.updates += 1
        return td_loss.item()

    def sync_target(self) -> None:
        self.target.load_state_dict(self.online.state_dict())

    def input(self, obs: np.ndarray) -> torch.Tensor:
        """``obs`` as the online network reads it: ``to_tensor``, channels-last for a fast convolutional network."""
        if self.fast and isinstance(self.online, QNetwork):
            return to_tensor(np.ascontiguousarray(np.moveaxis(obs, -3, -1)), self.device).movedim(-1, -3)  # [..., C, w, w]
        return to_tensor(obs, self.device)

    def evaluate(self, net: nn.Module, x: torch.Tensor) -> torch.Tensor:
        """Eval-mode Q values of ``net`` (the online or the target network) at ``x``; call it under ``torch.no_grad``."""
        if self.fast and isinstance(net, QNetwork):
            return net.forward_eval(x)
        return net.eval()(x)

    def load_optimizer(self, state: dict) -> None:
        """The optimiser's state from a checkpoint, keeping this agent's choice of the fused step (a checkpoint's
        parameter groups carry the flag they were saved with)."""
        self.optimizer.load_state_dict(state)
        for group in self.optimizer.param_groups:
            group["fused"] = self.fast or None


class DQNPolicy:
    """A trained network as a ``Policy``: the legal move of highest Q, a random legal move w.p. ``epsilon``.

    ``revisit_penalty`` > 0: the greedy move maximises ``Q - revisit_penalty * visits``, ``visits`` the times this
    episode has already been in the cell the move leads to (the agent's own route, nothing it could not know), so that
    an agent circling a few cells is pushed out of the loop; 0 is the paper's plain argmax. ``aux_weight`` > 0 adds
    ``aux_weight * log p(move)``, ``p`` the genie-move head's softmax over the legal moves (a network with that head).
    A recurrent network keeps its state per row, from zeros at each episode's start (``reset``).

    ``precision`` ``bfloat16``: the features (the layers before the heads, and a recurrent network's cell) run under
    torch's bfloat16 autocast, the heads in float32 on them (``NETWORK_PRECISIONS``); a row's moves do not depend on
    the batch it is in.
    """

    def __init__(
        self,
        net: nn.Module,
        epsilon: float = 0.096,
        seed: int = 0,
        name: str = "dqn",
        revisit_penalty: float = 0.0,
        aux_weight: float = 0.0,
        precision: str = "float32",
    ) -> None:
        if aux_weight > 0 and getattr(net, "aux", None) is None:
            raise ValueError("aux_weight needs a network with a genie-move head (trained with aux_genie > 0)")
        if precision not in NETWORK_PRECISIONS:
            raise ValueError(f"unknown network precision {precision!r}: {', '.join(NETWORK_PRECISIONS)}")
        self.precision = precision
        self.net = net.fused() if isinstance(net, (QNetwork, MeanQ)) else net.eval()
        self.device = next(net.parameters()).device
        self.epsilon = epsilon
        self.revisit_penalty = revisit_penalty
        self.aux_weight = aux_weight
        self.stream = stream_key(name, seed)  # the test-epsilon moves: drawn per episode and step (rl.randomness)
        self.name = name
        self.recurrent = getattr(net, "recurrent", False)
        self.hidden: torch.Tensor | None = None  # [num_envs, hidden]: a recurrent network's state in each row

    @classmethod
    def from_config(
        cls,
        net: nn.Module,
        config: DQNConfig,
        epsilon: float | None = None,
        seed: int | None = None,
        precision: str = "float32",
    ) -> DQNPolicy:
        """``net`` acting by ``config``'s test rule (its epsilon, revisit penalty and head weight, unless given), its
        features in ``precision``."""
        return cls(
            net,
            config.test_epsilon if epsilon is None else epsilon,
            config.seed if seed is None else seed,
            config.agent,
            config.test_revisit_penalty,
            config.test_aux_weight,
            precision,
        )

    def _features_autocast(self) -> contextlib.AbstractContextManager:
        """The autocast the features run under: bfloat16 where ``precision`` says so, else none."""
        if self.precision == "float32":
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=torch.bfloat16)

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        if self.recurrent:
            if self.hidden is None or len(self.hidden) != num_envs:
                self.hidden = self.net.initial_state(num_envs)
            self.hidden[torch.from_numpy(np.asarray(rows, np.int64)).to(self.device)] = 0.0

    def act(self, obs: np.ndarray, mask: np.ndarray, env: BatchedEnv) -> np.ndarray:
        """The network runs on the rows that still play (``env.exhausted``: slots of an evaluation whose episodes
        are all handed out); the random draws cover every row, so the moves do not depend on which rows played."""
        live = np.flatnonzero(~env.exhausted)
        greedy = np.zeros(len(mask), np.int64)
        penalty = revisit_penalty(env.neighbour_visits(), self.revisit_penalty, self.device) if self.revisit_penalty > 0 else None
        if len(live):
            rows = slice(None) if len(live) == len(mask) else live
            legal = torch.from_numpy(mask[rows]).to(self.device)
            if self.recurrent and (self.hidden is None or len(self.hidden) != len(mask)):
                self.reset(np.arange(len(mask)), len(mask))  # (outside inference mode: the state is updated in place)
            with torch.inference_mode():
                x = to_tensor(obs[rows], self.device)
                z = None  # the features the heads read, where the policy needs them
                with self._features_autocast():
                    if self.recurrent:
                        z = self.net.encode(x, self.hidden[rows]).float()
                    elif self.aux_weight > 0 or self.precision != "float32":
                        z = self.net.embed(x).float()
                if self.recurrent:
                    self.hidden[rows] = z
                q = self.net(x) if z is None else self.net.head(z)
                if self.aux_weight > 0:
                    q = q + self.aux_weight * torch.log_softmax(self.net.aux(z).masked_fill(~legal, float("-inf")), dim=1)
                if penalty is not None:
                    q = q - penalty[rows]
                greedy[rows] = masked_argmax(q, legal).cpu().numpy()
        u = episode_draws(env, self.stream, 1 + mask.shape[1])  # whether to explore, then one draw per action
        return np.where(u[:, 0] < self.epsilon, pick_legal(mask, u[:, 1:]), greedy)

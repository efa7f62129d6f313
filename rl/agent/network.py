"""Q-networks: the paper's (3 convolutions, 2 fully connected layers, batch norm, dropout, dueling head)
and a cheaper foveated one (a full-resolution centre and a pooled surround, fully connected)."""

from __future__ import annotations

import copy

import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval, fuse_conv_bn_weights

#: Observations (dB and m) are divided by this before the first layer.
INPUT_SCALE = 50.0


class DuelingQ(nn.Module):
    """Features (``embed``, the subclass's) then the dueling head ``Q = V + A - mean(A)`` (``value``, ``advantage``);
    ``aux``, when the subclass builds it, reads the same features.

    A recurrent network (``core``, a GRU cell) carries a state ``h`` ``[B, hidden]`` along an episode (zeros at its
    start): its features are ``h' = core(embed(obs), h)``, which both heads read. It acts by ``step(obs, h)`` and
    learns by ``unroll`` over a rollout; ``forward`` (one observation, no history) is for feedforward networks only.
    """

    value: nn.Linear
    advantage: nn.Linear
    aux: nn.Linear | None
    core: nn.GRUCell | None

    def _build_heads(self, hidden: int, n_actions: int, aux: bool, recurrent: bool = False) -> None:
        """The dueling head's two layers and, with ``aux``, the genie-move head, all on ``hidden`` features; with
        ``recurrent``, the GRU cell before them (without it, the modules of older checkpoints)."""
        self.value = nn.Linear(hidden, 1)
        self.advantage = nn.Linear(hidden, n_actions)
        self.aux = nn.Linear(hidden, n_actions) if aux else None
        self.core = nn.GRUCell(hidden, hidden) if recurrent else None

    @property
    def recurrent(self) -> bool:
        return self.core is not None

    def initial_state(self, n: int) -> torch.Tensor:
        """The recurrent state of ``n`` episodes at their start: zeros ``[n, hidden]``."""
        return torch.zeros(n, self.value.in_features, device=self.value.weight.device)

    def embed(self, obs: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def encode(self, obs: torch.Tensor, h: torch.Tensor | None = None) -> torch.Tensor:
        """``[B, hidden]``, what both heads read: ``embed(obs)``, or for a recurrent network the next state from ``h``."""
        return self.recur(self.embed(obs), h)

    def recur(self, z: torch.Tensor, h: torch.Tensor | None = None) -> torch.Tensor:
        """``[B, hidden]`` from features ``z``: ``z`` itself, or for a recurrent network the next state from ``h``."""
        return z if self.core is None else self.core(z, h)

    def step(self, obs: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A recurrent network's move: Q values ``[B, n_actions]`` of ``obs`` and the state after it ``[B, hidden]``."""
        h = self.encode(obs, h)
        return self.head(h), h

    def unroll(self, obs: torch.Tensor, h0: torch.Tensor, first: torch.Tensor) -> torch.Tensor:
        """A recurrent network's states ``[T, B, hidden]`` along ``obs`` ``[T, B, C, w, w]`` from ``h0`` ``[B, hidden]``;
        the state restarts from zeros where ``first`` ``[T, B]`` (bool) marks an episode's first observation."""
        steps, n = obs.shape[:2]
        z = self.embed(obs.flatten(0, 1)).view(steps, n, -1)  # the feedforward part in one batch
        h, out = h0, []
        for t in range(steps):
            h = self.core(z[t], h.masked_fill(first[t, :, None], 0.0))
            out.append(h)
        return torch.stack(out)

    def head(self, z: torch.Tensor) -> torch.Tensor:
        """Q values ``[B, n_actions]`` of features ``z`` ``[B, hidden]``."""
        a = self.advantage(z)
        return self.value(z) + a - a.mean(dim=1, keepdim=True)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Q values ``[B, n_actions]`` of observations ``[B, C, w, w]`` (a feedforward network)."""
        if self.core is not None:
            raise TypeError("a recurrent network needs its state: step(obs, h) or unroll(obs, h0, first)")
        return self.head(self.embed(obs))


def dense(n_in: int, n_out: int, dropout: float, layer_norm: bool) -> list[nn.Module]:
    """A fully connected layer, [layer norm,] ReLU, dropout (without layer norm, the modules of older checkpoints)."""
    return [nn.Linear(n_in, n_out), *([nn.LayerNorm(n_out)] if layer_norm else []), nn.ReLU(), nn.Dropout(dropout)]


class QNetwork(DuelingQ):
    """``[B, C, w, w]`` observations (float, or uint8 decoded by the caller) -> ``[B, 4]`` Q values.

    conv 5x5/2 (c1) -> conv 3x3/2 (c2) -> conv 3x3/2 (c3), each with batch norm and ReLU;
    fc (hidden) with ReLU and dropout; dueling head Q = V + A - mean(A). ``channels`` = (c1, c2, c3),
    by default (32, 64, 64). ``aux``: a second head on the same features, logits of the genie's move
    (trained as an auxiliary task, ``DQNConfig.aux_genie``; it never acts). ``layer_norm``: after the fully
    connected layer. ``recurrent``: a GRU cell between the features and the heads (``DuelingQ``).
    """

    def __init__(
        self,
        in_channels: int,
        window: int = 61,
        hidden: int = 256,
        dropout: float = 0.4,
        n_actions: int = 4,
        channels: tuple[int, int, int] = (32, 64, 64),
        aux: bool = False,
        layer_norm: bool = False,
        recurrent: bool = False,
    ) -> None:
        super().__init__()
        c1, c2, c3 = channels
        self.features = nn.Sequential(
            nn.Conv2d(in_channels, c1, kernel_size=5, stride=2),
            nn.BatchNorm2d(c1),
            nn.ReLU(),
            nn.Conv2d(c1, c2, kernel_size=3, stride=2),
            nn.BatchNorm2d(c2),
            nn.ReLU(),
            nn.Conv2d(c2, c3, kernel_size=3, stride=2),
            nn.BatchNorm2d(c3),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            n_flat = self.features(torch.zeros(2, in_channels, window, window)).shape[1]
        self.fc = nn.Sequential(*dense(n_flat, hidden, dropout, layer_norm))
        self._build_heads(hidden, n_actions, aux, recurrent)

    def fused(self) -> QNetwork:
        """An evaluation-mode copy for acting, never for training: each batch norm folded into the convolution
        before it and the weights in channels-last order (the same Q values; together about half the time
        on a CPU, ``benchmarks/bench_report.py --legacy``)."""
        net = copy.deepcopy(self).eval()
        layers = list(net.features)
        folded: list[nn.Module] = []
        for layer in layers:
            if isinstance(layer, nn.BatchNorm2d) and folded and isinstance(folded[-1], nn.Conv2d):
                folded[-1] = fuse_conv_bn_eval(folded[-1], layer)
            else:
                folded.append(layer)
        net.features = nn.Sequential(*folded)
        return net.to(memory_format=torch.channels_last)

    def forward_eval(self, obs: torch.Tensor) -> torch.Tensor:
        """Q values ``[B, n_actions]`` as ``eval()`` gives them, whatever mode the network is in: each batch norm
        folded into the convolution before it from the weights and statistics of this moment (a few small tensor
        operations, so a network that changes at every update acts and bootstraps by it), dropout off. The same
        values up to rounding (``tests/test_agent.py``) at the cost of the convolutions alone; call it under
        ``torch.no_grad``. A feedforward network only."""
        if self.core is not None:
            raise TypeError("a recurrent network needs its state: step(obs, h) or unroll(obs, h0, first)")
        x = obs / INPUT_SCALE
        convs = [m for m in self.features if isinstance(m, nn.Conv2d)]
        norms = [m for m in self.features if isinstance(m, nn.BatchNorm2d)]
        for conv, bn in zip(convs, norms, strict=True):  # each followed by its batch norm and a ReLU
            weight, bias = fuse_conv_bn_weights(
                conv.weight, conv.bias, bn.running_mean, bn.running_var, bn.eps, bn.weight, bn.bias
            )
            x = F.relu(F.conv2d(x, weight, bias, conv.stride))
        z = x.flatten(1)
        for layer in self.fc:
            if not isinstance(layer, nn.Dropout):
                z = layer(z)
        return self.head(z)

    def embed(self, obs: torch.Tensor) -> torch.Tensor:
        """``[B, hidden]``: the features both heads read (a recurrent network's GRU input)."""
        return self.fc(self.features(obs / INPUT_SCALE))


class FoveaQNetwork(DuelingQ):
    """``[B, C, w, w]`` observations -> ``[B, 4]`` Q values, at a fraction of ``QNetwork``'s cost on a CPU.

    The window is seen twice at ``fovea x fovea``: its centre at full resolution (the cells next to
    the UAV, where the next move is decided) and the whole window average-pooled (where the
    explored area and the buildings lie; with ``extremes``, max- and min-pooled too, so that a lane of open
    cells or one unvisited cell in a block stays visible); with ``middle``, a third view between them, the
    centre ``2 * fovea + 1`` cells at half resolution (3 x 3 means, stride 2), so that the lanes one to two fovea
    radii away are not averaged over 5 x 5 blocks. All go through 2 fully connected layers with ReLU and
    dropout (``layer_norm``: layer norm after each), then the dueling head (and, with ``aux``, the genie-move
    head, and with ``recurrent`` the GRU cell before the heads, as in ``QNetwork``).
    """

    def __init__(
        self,
        in_channels: int,
        window: int = 61,
        hidden: int = 256,
        dropout: float = 0.0,
        n_actions: int = 4,
        fovea: int = 15,
        aux: bool = False,
        layer_norm: bool = False,
        recurrent: bool = False,
        extremes: bool = False,
        middle: bool = False,
    ) -> None:
        super().__init__()
        if fovea % 2 != 1 or not 3 <= fovea <= window:
            raise ValueError(f"fovea {fovea} must be odd and between 3 and the window {window}")
        if middle and 2 * fovea + 1 > window:
            raise ValueError(f"the middle view needs a window of at least 2 * fovea + 1 = {2 * fovea + 1} cells, not {window}")
        self.fovea = fovea
        self.stride = max(1, (window - 1) // (fovea - 1))
        self.kernel = window - self.stride * (fovea - 1)  # pooled output is fovea x fovea, centred
        self.extremes = extremes
        self.middle = middle
        views = 2 + 2 * extremes + middle  # the centre, the mean surround [, its max and its min] [, the middle]
        self.fc = nn.Sequential(
            nn.Flatten(),
            *dense(views * in_channels * fovea * fovea, hidden, dropout, layer_norm),
            *dense(hidden, hidden, dropout, layer_norm),
        )
        self._build_heads(hidden, n_actions, aux, recurrent)

    @property
    def view_geometry(self) -> tuple[int, int, int, bool, bool]:
        """What ``views`` computes from an observation: networks of one geometry read the same views."""
        return self.fovea, self.stride, self.kernel, self.extremes, self.middle

    def embed(self, obs: torch.Tensor) -> torch.Tensor:
        """``[B, hidden]``: the features both heads read (a recurrent network's GRU input)."""
        return self.fc(self.views(obs))

    def views(self, obs: torch.Tensor) -> torch.Tensor:
        """``[B, views * C, f, f]``: the centre and the pooled surround (and the other views it was built with) that
        the fully connected layers read."""
        x = obs / INPUT_SCALE
        c, h = x.shape[-1] // 2, self.fovea // 2
        centre = x[..., c - h : c + h + 1, c - h : c + h + 1]  # [B, C, f, f]
        views = [centre, F.avg_pool2d(x, self.kernel, self.stride)]  # [B, C, f, f] each
        if self.extremes:
            views += [F.max_pool2d(x, self.kernel, self.stride), -F.max_pool2d(-x, self.kernel, self.stride)]
        if self.middle:
            m = self.fovea
            views.append(F.avg_pool2d(x[..., c - m : c + m + 1, c - m : c + m + 1], 3, 2))  # [B, C, f, f]
        return torch.cat(views, dim=1)


def add_input_channel(state: dict[str, torch.Tensor], net: DuelingQ, index: int) -> dict[str, torch.Tensor]:
    """``state``, the weights of ``net``'s architecture with one input channel fewer, with input channel ``index``
    added at zero weight: ``net`` loaded with them computes what the narrower network did, whatever the new channel
    holds, until training moves those weights (a fleet agent with the fleet channel started from a placement
    agent's weights, ``EnvConfig.fleet_channel``)."""
    if isinstance(net, QNetwork):  # the first convolution's [c1, C, k, k]
        key, views, cell = "features.0.weight", 1, state["features.0.weight"].shape[2:]
    elif isinstance(net, FoveaQNetwork):  # the first dense layer's [hidden, views * C * f * f]
        key, views, cell = "fc.1.weight", 2 + 2 * net.extremes + net.middle, (net.fovea**2,)
    else:
        raise TypeError(f"no input channel can be added to a {type(net).__name__}")
    w = state[key]
    grouped = w.reshape(w.shape[0], views, -1, *cell)  # [out, views, C, the weights of one channel]
    if not 0 <= index <= grouped.shape[2]:
        raise ValueError(f"input channel {index} is beyond the {grouped.shape[2]} channels of {key}")
    wider = torch.cat([grouped[:, :, :index], torch.zeros_like(grouped[:, :, :1]), grouped[:, :, index:]], dim=2)
    return {**state, key: wider.reshape(w.shape[0], -1, *w.shape[2:])}


class MeanQ(nn.Module):
    """Networks of one architecture acting as one agent (``DQNConfig.ensemble``, built by ``uavrl ensemble``): the
    Q values are the mean of theirs, each network reading the same observation with its own features and, when
    recurrent, its own state. The features ``z`` (and a recurrent state ``h``) are the members' side by side,
    ``[B, members * hidden]``, so that ``DQNPolicy`` acts with an ensemble as with one network."""

    def __init__(self, nets: list[DuelingQ]) -> None:
        super().__init__()
        if len(nets) < 2:
            raise ValueError("an ensemble needs at least two networks")
        if len({type(n) for n in nets}) != 1 or len({n.recurrent for n in nets}) != 1:
            raise ValueError("the networks of an ensemble must share one architecture")
        self.nets = nn.ModuleList(nets)
        # The genie-move head, as a single network has it: None when the members were trained without one.
        self.aux = self._mean_aux if nets[0].aux is not None else None

    @property
    def recurrent(self) -> bool:
        return self.nets[0].recurrent

    def _parts(self, z: torch.Tensor) -> tuple[torch.Tensor, ...]:
        return z.chunk(len(self.nets), dim=1)

    def initial_state(self, n: int) -> torch.Tensor:
        return torch.cat([net.initial_state(n) for net in self.nets], dim=1)

    def _features(self, obs: torch.Tensor) -> list[torch.Tensor]:
        """Each member's ``embed(obs)``; foveated members of one view geometry pool the observation once."""
        first = self.nets[0]
        if isinstance(first, FoveaQNetwork) and all(net.view_geometry == first.view_geometry for net in self.nets):
            views = first.views(obs)
            return [net.fc(views) for net in self.nets]
        return [net.embed(obs) for net in self.nets]

    def embed(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.cat(self._features(obs), dim=1)

    def encode(self, obs: torch.Tensor, h: torch.Tensor | None = None) -> torch.Tensor:
        if not self.recurrent:
            return self.embed(obs)
        parts = zip(self.nets, self._features(obs), self._parts(h), strict=True)
        return torch.cat([net.recur(z, part) for net, z, part in parts], dim=1)

    def head(self, z: torch.Tensor) -> torch.Tensor:
        """The mean of the members' Q values ``[B, n_actions]``."""
        return torch.stack([net.head(part) for net, part in zip(self.nets, self._parts(z), strict=True)]).mean(0)

    def _mean_aux(self, z: torch.Tensor) -> torch.Tensor:
        """The mean of the members' genie-move logits (``DQNPolicy``'s ``aux_weight``)."""
        return torch.stack([net.aux(part) for net, part in zip(self.nets, self._parts(z), strict=True)]).mean(0)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if self.recurrent:
            raise TypeError("a recurrent ensemble needs its state: encode(obs, h), then head")
        return torch.stack([net(obs) for net in self.nets]).mean(0)

    def fused(self) -> MeanQ:
        """``QNetwork.fused`` for each member that has it (the same Q values, faster acting)."""
        return MeanQ([net.fused() if isinstance(net, QNetwork) else copy.deepcopy(net).eval() for net in self.nets])

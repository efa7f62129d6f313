"""Bundles laid out for fast batched episodes: every (user, symmetry) map on one padded canvas.

A *scenario* is one user of one bundle; a *view* is a scenario under one of the
``S = config.symmetries`` symmetries of the square (``view = S * scenario + k``;
``transform(a, k)``: ``k % 4`` quarter turns counter-clockwise, ``np.rot90``, of the
map, or of its transpose for ``k >= 4``). Every map is placed at offset ``pad = window // 2`` on a square
canvas of side ``L = max(num_x, num_y over bundles) + 2 * pad``; the canvas
outside the map is beyond the edge: blocked, height ``edge_height_m``, SINR
memory ``P_L``. A window of side ``window`` centred on any map cell is then a
plain slice of the canvas. Positions are canvas coordinates ``(y, x)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from uavplace.dataset.bundle import Bundle, load_bundle
from uavplace.dataset.difficulty import UNREACHABLE, steps_to_target, valid_starts
from uavplace.infra.files import in_corpus
from uavplace.rl.randomness import canvas_key, stream_key, uniforms
from uavplace.rl.world.maperror import seen_heights
from uavplace.rl.world.settings import CanvasSettings
from uavplace.schemas import InputError

#: Moves of the 4 actions in canvas coordinates (dy, dx): 0 north (+y), 1 east (+x), 2 south (-y), 3 west (-x).
MOVES = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], dtype=np.int64)


def transform(a: np.ndarray, k: int) -> np.ndarray:
    """Symmetry ``k`` (0-7) of the square applied to the last two axes of ``a``: ``k % 4`` quarter turns
    counter-clockwise, of ``a`` (``k < 4``) or of its transpose (``k >= 4``)."""
    return np.rot90(np.swapaxes(a, -1, -2) if k >= 4 else a, k % 4, axes=(-2, -1))


def city_weight(weights: dict[str, float], city: str) -> float:
    """``city``'s weight in ``CanvasSettings.city_weights``: its own name's, else its corpus's, else 1."""
    if city in weights:
        return weights[city]
    return next((w for name, w in weights.items() if in_corpus(city, name)), 1.0)


@dataclass(frozen=True)
class Scenario:
    bundle: int  # index in MapSet.bundles
    city: str
    user: int  # user index in the bundle


class MapSet:
    """The maps of one or more bundles, for one ``CanvasSettings``. Arrays are indexed by view (or view-of-map).

    ``height`` [num_bundles * S, L, L] float32, ``blocked`` [num_bundles * S, L, L] bool,
    ``sinr`` / ``steps`` [num_views, L, L] float32 / int32 (``steps``: genie's BFS moves to a target),
    ``memory0`` [num_views, L, L] float32 (the SINR memory channel at the start of an episode).
    With ``config.context_zoom`` = z: ``context_height`` [num_bundles * S, Lc, Lc] float32 (mean height of each
    z x z block) and ``context_memory0`` [num_views, Lc, Lc] float32 (the context SINR channel at the start of an
    episode: P_H for a block with a cell ``memory0`` shows as P_H, else P_L).
    """

    def __init__(self, bundles: list[Bundle], config: CanvasSettings, users: list[np.ndarray] | None = None) -> None:
        """``users``: the user indices to play in each bundle (default: ``config.split``'s, or all)."""
        if not bundles:
            raise ValueError("a MapSet needs at least one bundle")
        if config.window % 2 != 1:
            raise ValueError(f"window {config.window} must be odd")
        self.bundles = bundles
        self.buildings_shown: bool | str = True  # show_buildings: True (the city's), False (none) or the donor's city
        self.config = config
        self.pad = config.window // 2
        side = max(max(b.shape) for b in bundles)
        self.side = side + 2 * self.pad
        L, p = self.side, self.pad
        scenarios = []
        if users is not None and len(users) != len(bundles):
            raise ValueError(f"users: {len(users)} lists for {len(bundles)} bundles")
        for i, b in enumerate(bundles):
            picked = users[i] if users is not None else b.user_indices(config.split)
            scenarios += [Scenario(i, b.city, int(u)) for u in picked]
        if not scenarios:
            raise ValueError(f"no user of split {config.split!r} in bundles {[b.city for b in bundles]}")
        self.scenarios = scenarios
        S = self.symmetries = config.symmetries
        #: [S * num_bundles] uint64: each canvas (a city under a symmetry) named by its public map only (its grid, its
        #: buildings: ``Bundle.public_digest``) and its symmetry, never by a user or the bundle's version: what a
        #: policy's per-episode draws are keyed by (``rl.randomness``, ``canvas_key``).
        self.canvas_keys = np.array([canvas_key(b.public_digest, k) for b in bundles for k in range(S)], np.uint64)
        nb, nv = len(bundles), S * len(scenarios)
        self.height = np.full((S * nb, L, L), config.edge_height_m, np.float32)
        self.blocked = np.ones((S * nb, L, L), bool)
        self.sinr = np.full((nv, L, L), config.p_l_db, np.float32)
        self.dead = np.ones((nv, L, L), bool)
        self.steps = np.full((nv, L, L), UNREACHABLE, np.int32)
        self.shapes = np.zeros((S * nb, 2), np.int64)  # transformed (num_y, num_x) per bundle-symmetry
        self.on_map = np.zeros((S * nb, L, L), bool)  # False beyond the edge
        #: per bundle, the building heights of the UAV's map (``rl.world.maperror``; the bundle's own when exact): what
        #: the height channel and the public maps hold, never which cells may be entered
        self.seen_heights = tuple(seen_heights(b, config.map_error) for b in bundles)
        for i, b in enumerate(bundles):
            self._paint_buildings(i, self.seen_heights[i], b.blocked, self.blocked)
            for k in range(S):
                ny, nx = self.shapes[S * i + k] = transform(b.blocked, k).shape
                self.on_map[S * i + k, p : p + ny, p : p + nx] = True
        for s, sc in enumerate(scenarios):
            b = bundles[sc.bundle]
            legal = ~b.blocked
            target = config.reaches(b.sinr_db[sc.user], b.dead[sc.user], legal)
            steps = steps_to_target(legal, target)
            for k in range(S):
                v = S * s + k
                ny, nx = self.shapes[S * sc.bundle + k]
                self.sinr[v, p : p + ny, p : p + nx] = transform(b.sinr_db[sc.user], k)
                self.dead[v, p : p + ny, p : p + nx] = transform(b.dead[sc.user], k)
                self.steps[v, p : p + ny, p : p + nx] = transform(steps, k)
        self.view_map = np.repeat(S * np.array([sc.bundle for sc in scenarios]), S) + np.tile(np.arange(S), len(scenarios))
        #: [num_views] each view's user (its number in its bundle) and its bundle's grid spacing [m]: what the world
        #: draws a measurement's error by (``rl.world.measurement``), never a policy
        self.view_user = np.repeat(np.array([sc.user for sc in scenarios], np.int64), S)
        self.view_spacing_m = np.repeat(np.array([bundles[sc.bundle].spacing_m for sc in scenarios], np.float64), S)
        blocked_v = self.blocked[self.view_map]
        self.context_pad = config.window // 2
        self.memory0, context_height, context_memory0 = self._start_channels(self.blocked)
        if config.context_zoom:
            self.context_height, self.context_memory0 = context_height, context_memory0
        # Valid starts per view, concatenated: flat canvas indices, with offset and count per view.
        valid = valid_starts(blocked_v, self.dead, self.sinr, config.p_t_db, self.steps)
        flat = [np.flatnonzero(valid[v]) for v in range(nv)]
        self.start_count = np.array([len(f) for f in flat], np.int64)
        self.start_offset = np.r_[0, np.cumsum(self.start_count)[:-1]]
        self.start_cells = np.concatenate(flat) if flat else np.zeros(0, np.int64)
        self.startable = np.flatnonzero(self.start_count[::S] > 0)  # scenarios with at least one valid start
        # config.city_weights: the chance of each startable scenario (None: uniform, drawn as before the weights).
        self.start_p = None
        if config.city_weights and len(self.startable):
            weight = np.array([city_weight(config.city_weights, scenarios[s].city) for s in self.startable])
            self.start_p = weight / weight.sum()

    def show_buildings(self, donor: Bundle | None) -> None:
        """Let the agent see ``donor``'s buildings instead of its city's (None: no building at all), in place: the
        height channel, the context channels and the SINR memory's blocked cells at the start of an episode. The
        moves (which cells are blocked), the SINR and the genie stay the city's: the experiment that asks whether
        an agent uses the map (experiments/log/map_claim.md). ``donor`` must have the city's grid shape."""
        seen_blocked = np.ones_like(self.blocked)  # beyond the edge: blocked, as in ``blocked``
        for i, b in enumerate(self.bundles):
            if donor is not None and donor.shape != b.shape:
                raise ValueError(f"{donor.city} is {donor.shape} cells, {b.city} {b.shape}: a donor map needs the same shape")
            height = np.full(b.shape, -b.altitude_m, np.float32) if donor is None else donor.height_rel_m
            self._paint_buildings(i, height, np.zeros(b.shape, bool) if donor is None else donor.blocked, seen_blocked)
        self.buildings_shown = False if donor is None else donor.city
        memory0, context_height, context_memory0 = self._start_channels(seen_blocked)
        self.memory0[...] = memory0  # in place: an env made from these maps holds views of them
        if self.config.context_zoom:
            self.context_height[...], self.context_memory0[...] = context_height, context_memory0

    def forget_users(self) -> MapSet:
        """Blank every user's map (SINR at P_L, every cell dead, no target reachable), in place, and return the maps:
        for an env that only keeps an agent's channels from another task's measurements (the tracking and fleet tasks
        running a placement agent), whose maps must hold nothing of a user."""
        self.sinr[...], self.dead[...], self.steps[...] = self.config.p_l_db, True, UNREACHABLE
        return self

    def _paint_buildings(self, i: int, height: np.ndarray, blocked: np.ndarray, into_blocked: np.ndarray) -> None:
        """Bundle ``i``'s canvases under every symmetry: ``height`` (clipped) into ``self.height``, ``blocked`` into
        ``into_blocked`` (``self.blocked``, or what the agent is shown)."""
        cfg, S, p = self.config, self.symmetries, self.pad
        for k in range(S):
            h = transform(np.clip(height, -cfg.height_clip_m, cfg.height_clip_m), k)
            ny, nx = h.shape
            self.height[S * i + k, p : p + ny, p : p + nx] = h
            into_blocked[S * i + k, p : p + ny, p : p + nx] = transform(blocked, k)

    def _start_channels(self, seen_blocked: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """(``memory0``, ``context_height``, ``context_memory0``) from ``self.height`` and the blocked cells the agent
        sees; the context ones None without ``context_zoom``."""
        cfg = self.config
        # Blind: buildings unknown, so blocked map cells look unvisited; beyond the edge stays P_L.
        hidden = ~self.on_map[self.view_map] if cfg.blind else seen_blocked[self.view_map]
        memory0 = np.where(hidden, cfg.p_l_db, cfg.p_h_db).astype(np.float32)
        if not cfg.context_zoom:
            return memory0, None, None
        # Context channels: the canvas in z x z blocks, padded by half a window of blocks, so that a window of
        # blocks centred on the block of any map cell is a plain slice too. context_height [S * nb, Lc, Lc];
        # context_memory0 [nv, Lc, Lc]: P_H where the block has a cell the memory shows as P_H (one that can be
        # visited), else P_L.
        z, edge = cfg.context_zoom, cfg.edge_height_m
        return memory0, self._blocks(self.height, z, edge, np.mean), self._blocks(memory0, z, np.float32(cfg.p_l_db), np.max)

    def _blocks(self, a: np.ndarray, z: int, fill: float, reduce: Callable[..., np.ndarray]) -> np.ndarray:
        """``reduce`` over the ``z x z`` blocks of canvases ``a`` ``[K, L, L]`` (the last blocks filled with ``fill``),
        padded with ``fill`` by ``context_pad`` blocks on every side: ``[K, Lc, Lc]``."""
        k, side = len(a), -(-self.side // z)
        full = np.full((k, side * z, side * z), fill, a.dtype)
        full[:, : self.side, : self.side] = a
        blocks = reduce(full.reshape(k, side, z, side, z), axis=(2, 4))
        p = self.context_pad
        out = np.full((k, side + 2 * p, side + 2 * p), fill, a.dtype)
        out[:, p : p + side, p : p + side] = blocks
        return out

    def context_cell(self, y: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The context block ``(cy, cx)`` of canvas cells ``(y, x)`` (``config.context_zoom`` > 0)."""
        z, p = self.config.context_zoom, self.context_pad
        return y // z + p, x // z + p

    @classmethod
    def load(cls, datasets: list[str] | str, config: CanvasSettings, root: str = "data/processed") -> MapSet:
        names = [datasets] if isinstance(datasets, str) else list(datasets)
        return cls([load_bundle(n, root=root) for n in names], config)

    @property
    def num_views(self) -> int:
        return len(self.view_map)

    def scenario_of(self, view: np.ndarray) -> np.ndarray:
        return np.asarray(view) // self.symmetries

    def symmetry_of(self, view: np.ndarray) -> np.ndarray:
        return np.asarray(view) % self.symmetries

    def sample_episodes(self, n: int, rng: np.random.Generator, rotate: bool | None = None) -> np.ndarray:
        """``[n, 3]`` int64 episode specs ``(view, y, x)``: a startable scenario (uniform, or by ``config.city_weights``),
        symmetry (if ``rotate``, default ``config.rotate``; else the identity) and start cell (with
        ``config.far_starts``, that share of the starts is the farther from a target of two draws)."""
        if len(self.startable) == 0:
            cities = ", ".join(sorted({b.manifest.city for b in self.bundles}))
            raise InputError(
                cities,
                f"no user has a start cell at P_T = {self.config.p_t_db:g} dB (a legal, live cell below P_T "
                "from which a target is reachable): choose another P_T (--p-t-db) or other users",
                field="p_t_db",
            )
        rotate = self.config.rotate if rotate is None else rotate
        if self.start_p is None:
            scen = self.startable[rng.integers(0, len(self.startable), n)]
        else:
            scen = rng.choice(self.startable, n, p=self.start_p)
        S = self.symmetries
        k = rng.integers(0, S, n) if rotate else np.zeros(n, np.int64)
        view = S * scen + k
        pick = self.start_offset[view] + np.floor(rng.random(n) * self.start_count[view]).astype(np.int64)
        if self.config.far_starts > 0:
            other = self.start_offset[view] + np.floor(rng.random(n) * self.start_count[view]).astype(np.int64)
            far = rng.random(n) < self.config.far_starts
            flat_steps = self.steps.reshape(len(self.steps), -1)
            farther = flat_steps[view, self.start_cells[other]] > flat_steps[view, self.start_cells[pick]]
            pick = np.where(far & farther, other, pick)
        y, x = np.divmod(self.start_cells[pick], self.side)
        return np.stack([view, y, x], axis=1)

    def episode_list(self, n: int, seed: int, rotate: bool | None = None) -> np.ndarray:
        """``[n, 3]`` episode specs like ``sample_episodes``'s, episode ``i`` drawn from its own uniforms (``seed`` and
        ``i`` hashed, ``rl.randomness``): the first ``m`` of a list of ``n`` are the list of ``m``, so any prefix of an
        evaluation plays as in the full one. Drawn as ``sample_episodes`` draws (scenario, symmetry, start cell, the
        farther of two starts with ``config.far_starts``)."""
        self.sample_episodes(0, np.random.default_rng(0))  # the same refusal when no user can start
        rotate = self.config.rotate if rotate is None else rotate
        u = uniforms(stream_key("episode list", seed), np.arange(n, dtype=np.uint64), np.zeros(n, np.int64), 5)
        if self.start_p is None:
            scen = self.startable[np.minimum((u[:, 0] * len(self.startable)).astype(np.int64), len(self.startable) - 1)]
        else:
            scen = self.startable[
                np.minimum(np.searchsorted(np.cumsum(self.start_p), u[:, 0], side="right"), len(self.startable) - 1)
            ]
        S = self.symmetries
        k = np.minimum((u[:, 1] * S).astype(np.int64), S - 1) if rotate else np.zeros(n, np.int64)
        view = S * scen + k
        pick = self.start_offset[view] + np.floor(u[:, 2] * self.start_count[view]).astype(np.int64)
        if self.config.far_starts > 0:
            other = self.start_offset[view] + np.floor(u[:, 3] * self.start_count[view]).astype(np.int64)
            flat_steps = self.steps.reshape(len(self.steps), -1)
            farther = flat_steps[view, self.start_cells[other]] > flat_steps[view, self.start_cells[pick]]
            pick = np.where((u[:, 4] < self.config.far_starts) & farther, other, pick)
        y, x = np.divmod(self.start_cells[pick], self.side)
        return np.stack([view, y, x], axis=1)

    def can_start(self, episodes: np.ndarray) -> np.ndarray:
        """``[n]`` bool: whether each episode spec ``(view, y, x)`` starts on one of its view's start cells here (a
        legal, live cell below P_T from which a target is reachable): specs drawn on another MapSet of the same
        scenarios and canvas, such as a twin city's, may not."""
        episodes = np.asarray(episodes, np.int64)
        out = np.zeros(len(episodes), bool)
        for k, (view, y, x) in enumerate(episodes):
            off, count = self.start_offset[view], self.start_count[view]
            out[k] = y * self.side + x in self.start_cells[off : off + count]
        return out

    def episodes_from(self, episodes: np.ndarray, other: MapSet) -> np.ndarray:
        """Episode specs drawn on ``other`` as specs of this MapSet: the same views and start cells. Canvas
        coordinates include the pad of half a window, so two windows put one cell at different ``(y, x)``;
        the two must hold the same scenarios under the same symmetries."""
        same = [(s.city, s.user) for s in self.scenarios] == [(s.city, s.user) for s in other.scenarios]
        if not same or self.symmetries != other.symmetries:
            raise ValueError("episodes_from: the two MapSets hold different scenarios or symmetries")
        out = np.array(episodes, np.int64, copy=True)
        out[:, 1:] += self.pad - other.pad
        return out

    def unrotate(self, view: np.ndarray, y: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map cells ``(iy, ix)`` (bundle indices) of canvas positions in a view, undoing its symmetry."""
        sym = self.symmetry_of(view)
        k = sym % 4
        m = self.view_map[np.asarray(view)]
        ny, nx = self.shapes[m, 0], self.shapes[m, 1]
        r, c = np.asarray(y) - self.pad, np.asarray(x) - self.pad
        # np.rot90(a, k)[r, c] == a[...]: invert one quarter turn at a time.
        for _ in range(4):
            turn = k > 0
            # a = rot90(b): a[r, c] = b[c, n_cols_b - 1 - r] where b has shape (nx_a, ny_a)
            r, c = np.where(turn, c, r), np.where(turn, ny - 1 - r, c)
            ny, nx = np.where(turn, nx, ny), np.where(turn, ny, nx)
            k = np.where(turn, k - 1, k)
        mirrored = sym >= 4  # (r, c) are now cells of the transpose
        return np.where(mirrored, c, r), np.where(mirrored, r, c)

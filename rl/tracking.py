"""The tracking task: a UAV keeps a usable link to a user who moves along a ray-traced route.

The second task beside placement (placement is unchanged). A bundle with routes (``uavdata simulate
--routes``, then ingest and build) holds a radio map per route point. An episode picks a route, a start
time on it and a start cell (legal, live, below P_T, a target reachable at the start time), and lasts a
fixed ``horizon`` of steps. Each step takes ``step_s`` = cell side / ``uav_speed_mps`` seconds (4 m at
10 m/s: 0.4 s): the UAV moves one cell (actions 0-3, the placement moves) or stays (action 4); the user
walks on by speed x time, to the route's end and back (``user_point``). The UAV measures the SINR of its
cell to the user's current position, the route point nearest in time, and nothing else of the user.

Observation ``[C, window, window]`` around the UAV: the height channel (not blind), the age of each
measurement (seconds since the cell was last measured, clipped at ``age_clip_s``; unvisited cells and
blocked ones show the clip), and the SINR memory (the last SINR measured at each cell; P_H unvisited, P_L
blocked or beyond the edge), which stays last as in placement. Reward: ``cover_reward`` for each step at
or above P_T plus ``gain_weight`` times the SINR change.

Per-episode metrics (``episode_metrics``): steps to first reach P_T, the share of the steps after that at
or above P_T (coverage), the longest outage after it, and the share of the whole horizon covered.
Baselines: the ``oracle`` (dynamic programming over (time, cell) on the whole route and every map: the
most covered steps possible, the upper bound), the placement genie re-planned every step toward the
current P_T region (``ReplanningGenie``), and the placement baselines, which act through the same
interface (``rl.policies``), as they are or holding the cell while it covers the user (``Holding``). Agents:
a placement agent run unchanged (``PlacementInTracking``; also with ``Holding``), or one trained on this task
(``uavrl train --task tracking``, ``rl.agent.train.TrackingTrainer``) on its own observation (``TrackingAgent``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from pydantic import ConfigDict, Field

from uavplace.dataset.bundle import Bundle
from uavplace.dataset.difficulty import UNREACHABLE, steps_to_target
from uavplace.rl.config import EnvConfig
from uavplace.rl.maps import MOVES, MapSet, transform
from uavplace.rl.randomness import combine
from uavplace.rl.vec_env import EpisodeRows, encode_obs, refuse_bad_rows
from uavplace.schemas.base import Contract
from uavplace.schemas.constants import P_T_DB, reaches_target

#: The 5 tracking actions in canvas coordinates (dy, dx): the 4 placement moves, then 4 = stay.
TRACK_MOVES = np.vstack([MOVES, [[0, 0]]])
STAY = 4
#: The action of each move (dy + 1, dx + 1) in ``TRACK_MOVES`` (-1: no action makes it).
ACTION_OF = np.full((3, 3), -1, np.int64)
ACTION_OF[TRACK_MOVES[:, 0] + 1, TRACK_MOVES[:, 1] + 1] = np.arange(len(TRACK_MOVES))


#: The fields of ``TrackingConfig`` that shape what an agent observes (the others define the task).
OBSERVATION_FIELDS = ("window", "blind", "p_h_db", "p_l_db", "age_clip_s", "edge_height_m", "height_clip_m")


class TrackingConfig(Contract):
    """Everything that defines the tracking task (saved with every run and report that uses it)."""

    model_config = ConfigDict(allow_inf_nan=False)

    p_t_db: float = Field(default=P_T_DB, description="SINR target P_T [dB]: a step at or above it is covered")
    horizon: int = Field(default=300, ge=1, le=100_000, description="Steps per episode")
    uav_speed_mps: float = Field(default=10.0, gt=0, le=100, description="UAV speed: one cell per cell side / speed seconds")
    window: int = Field(default=61, ge=3, description="Observation side in cells (odd), centred on the UAV")
    blind: bool = Field(default=False, description="No height channel; blocked cells shown as P_H in the SINR memory")
    p_h_db: float = Field(default=50.0, description="SINR memory of unvisited cells [dB]")
    p_l_db: float = Field(default=-150.0, description="SINR memory of blocked cells and beyond the edge [dB]")
    age_clip_s: float = Field(
        default=100.0, gt=0, description="Measurement ages are clipped at this [s]; unvisited cells show it"
    )
    cover_reward: float = Field(default=1.0, description="Reward of a covered step")
    gain_weight: float = Field(default=0.05, description="Reward per dB of SINR change")
    edge_height_m: float = Field(default=100.0, description="Height channel beyond the map edge [m]")
    height_clip_m: float = Field(default=100.0, gt=0, description="Height channel clipped to +/- this [m]")
    rotate: bool = Field(
        default=False,
        description="Training: every route also under the quarter turns of its city (each city seen four ways, as "
        "placement's rotate); evaluation and reports play the routes as they are",
    )

    @property
    def num_channels(self) -> int:
        return 2 if self.blind else 3

    def observed_as(self, agent: TrackingConfig) -> TrackingConfig:
        """This task (horizon, P_T, speeds) with ``agent``'s observation (``OBSERVATION_FIELDS``): what a tracking
        agent trained with ``agent`` sees when it plays this task."""
        return self.model_copy(update={k: getattr(agent, k) for k in OBSERVATION_FIELDS})

    def placement_env(self) -> EnvConfig:
        """The placement ``EnvConfig`` whose canvases (height, blocked, padding) this task shares."""
        return EnvConfig(p_t_db=self.p_t_db, window=self.window, blind=self.blind, p_h_db=self.p_h_db, p_l_db=self.p_l_db,
                         edge_height_m=self.edge_height_m, height_clip_m=self.height_clip_m, rotate=False)  # fmt: skip


def user_point(times_s: np.ndarray, start_s: np.ndarray, t: np.ndarray, step_s: np.ndarray) -> np.ndarray:
    """Index along each route of the point the user is at after ``t`` steps of ``step_s`` seconds from ``start_s``:
    the user walks to the route's end and back (period twice the route's duration), at the point nearest in time.
    ``times_s``: ``[K, n_max]`` point times per route (``inf`` past a route's last point); the others ``[K]``."""
    rows = np.arange(len(times_s))
    final = np.isfinite(times_s).sum(axis=1) - 1  # each route's last point
    last = times_s[rows, final]
    s = np.mod(start_s + t * step_s, 2 * last)
    s = np.where(s > last, 2 * last - s, s)  # on the way back
    after = np.clip((times_s <= s[:, None]).sum(axis=1), 1, times_s.shape[1] - 1)  # the first point later than s
    lo, hi = np.minimum(after - 1, final), np.minimum(after, final)
    nearer_hi = np.abs(times_s[rows, hi] - s) < np.abs(s - times_s[rows, lo])
    return np.where(nearer_hi, hi, lo)


class RouteSet:
    """The routes of one or more bundles laid on the placement canvases (``MapSet``): as they are, or with
    ``rotate`` (training) also under the MapSet's other symmetries, each (route, symmetry) a route of its own.

    ``sinr`` / ``dead`` ``[P, L, L]`` (every route point's map on the canvas; beyond the edge P_L / dead),
    ``steps`` ``[P, L, L]`` (moves to a target of that point's map), ``times`` ``[R, n_max]`` (inf padded),
    ``first`` ``[R]`` (each route's first point in ``sinr``), ``count`` ``[R]``, ``bundle`` ``[R]``, ``canvas``
    ``[R]`` (its row of the MapSet's height and blocked canvases), ``step_s`` ``[R]``.
    """

    def __init__(self, bundles: list[Bundle], config: TrackingConfig, rotate: bool = False) -> None:
        with_routes = [b for b in bundles if b.routes is not None]
        if not with_routes:
            raise ValueError(f"no bundle with routes among {[b.city for b in bundles]}: simulate them with --routes")
        self.bundles, self.config = with_routes, config
        self.maps = MapSet(with_routes, config.placement_env())
        p, L, S = self.maps.pad, self.maps.side, self.maps.symmetries
        self.turns = S if rotate else 1  # the symmetries each route is laid under (the identity first)
        total = self.turns * sum(len(b.routes) for b in with_routes)
        self.sinr = np.full((total, L, L), config.p_l_db, np.float32)
        self.dead = np.ones((total, L, L), bool)
        self.steps = np.full((total, L, L), UNREACHABLE, np.int32)
        first, count, bundle, canvas, step_s, times, keys, names = [], [], [], [], [], [], [], []
        start_cells: list[np.ndarray] = []  # per route point: the canvas cells an episode may start in then
        offset = 0
        for i, b in enumerate(with_routes):
            target = reaches_target(b.route_sinr_db, config.p_t_db, b.route_dead, ~b.blocked)
            steps = steps_to_target(~b.blocked, target)
            for k in range(self.turns):
                ny, nx = self.maps.shapes[S * i + k]
                sl = slice(offset, offset + len(b.routes))
                self.sinr[sl, p : p + ny, p : p + nx] = transform(b.route_sinr_db, k)
                self.dead[sl, p : p + ny, p : p + nx] = transform(b.route_dead, k)
                self.steps[sl, p : p + ny, p : p + nx] = transform(steps, k)
                starts = ~self.maps.blocked[S * i + k] & ~self.dead[sl] & ~reaches_target(self.sinr[sl], config.p_t_db)
                start_cells += [np.flatnonzero(ok) for ok in starts & (self.steps[sl] != UNREACHABLE)]
                for route, rows in b.routes.groupby("route", sort=False):
                    first.append(offset + int(rows.index[0]))
                    count.append(len(rows))
                    bundle.append(i)
                    canvas.append(S * i + k)
                    step_s.append(b.spacing_m / config.uav_speed_mps)
                    times.append(rows["time_s"].to_numpy())
                    keys.append(self.maps.canvas_keys[S * i + k])  # its canvas's public map: no route, no user
                    names.append((b.city, int(route), str(rows["kind"].iloc[0])))
                offset += len(b.routes)
        n_max = max(len(t) for t in times)
        self.times = np.full((len(times), n_max), np.inf)
        for r, t in enumerate(times):
            self.times[r, : len(t)] = t
        self.first, self.count, self.bundle, self.canvas = np.array(first), np.array(count), np.array(bundle), np.array(canvas)
        self.step_s = np.array(step_s)
        self.route_keys = np.array(keys, np.uint64)
        self.names = names  # (city, route id, kind) per route
        self.start_cells = start_cells

    @property
    def num_routes(self) -> int:
        return len(self.first)

    def point(self, route: np.ndarray, start_s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Row in ``sinr`` of the point the user of each episode is at after ``t`` steps."""
        return self.first[route] + user_point(self.times[route], start_s, t, self.step_s[route])

    def sample_episodes(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``[n, 4]`` float64 episode specs ``(route, start_s, y, x)``: a route (uniform), a start time on it (uniform
        over the route's duration) and a start cell: legal, live, below P_T, with a target reachable at that time."""
        out = np.zeros((n, 4))
        for k in range(n):
            for _attempt in range(100):
                r = int(rng.integers(self.num_routes))
                start = float(rng.random() * self.times[r, self.count[r] - 1])
                cells = self.start_cells[int(self.point(np.array([r]), np.array([start]), np.array([0]))[0])]
                if len(cells):
                    y, x = divmod(int(cells[rng.integers(len(cells))]), self.maps.side)
                    out[k] = (r, start, y, x)
                    break
            else:
                raise ValueError("no route has a time and a start cell below P_T with a reachable target")
        return out


def episode_metrics(covered: np.ndarray) -> dict[str, np.ndarray]:
    """Per-episode metrics of ``covered`` ``[K, H]`` (step 1..H at or above P_T): ``first_reach`` (steps to the first
    covered step, inf if none), ``coverage`` (share of the steps from it on that are covered, 0 if none),
    ``longest_outage`` (longest run of uncovered steps after it; the horizon if never reached) and ``covered_share``
    (share of all H steps covered)."""
    k, h = covered.shape
    ever = covered.any(axis=1)
    first = np.where(ever, covered.argmax(axis=1) + 1, np.inf)
    after = np.arange(1, h + 1)[None, :] >= np.where(ever, first, h + 1)[:, None]
    coverage = np.where(ever, (covered & after).sum(axis=1) / np.maximum(after.sum(axis=1), 1), 0.0)
    outage = np.zeros(k, np.int64)
    run = np.zeros(k, np.int64)
    for t in range(h):
        run = np.where(after[:, t] & ~covered[:, t], run + 1, 0)
        outage = np.maximum(outage, run)
    return {"first_reach": first, "coverage": coverage, "longest_outage": np.where(ever, outage, h),
            "covered_share": covered.mean(axis=1)}  # fmt: skip


def oracle_path(legal: np.ndarray, covered: np.ndarray, start: tuple[int, int]) -> tuple[np.ndarray, int]:
    """The UAV's cells ``[H + 1, 2]`` (start first) that cover the most of steps 1..H, by dynamic programming over
    (time, cell): ``covered`` ``[H, ny, nx]`` (step t's map: the cell covers the user then), ``legal`` ``[ny, nx]``;
    moves to a 4-neighbour or stay. Returns (path, covered steps). Ties go to staying, then actions 0-3 in order."""
    h, ny, nx = covered.shape
    neg = np.iinfo(np.int32).min // 4
    value = np.zeros((ny, nx), np.int32)  # best covered count from step t on, standing in the cell after step t - 1
    choice = np.zeros((h, ny, nx), np.int8)
    for t in range(h - 1, -1, -1):
        here = np.where(legal, covered[t].astype(np.int32) + value, neg)  # being in the cell at step t
        best = here.copy()
        arg = np.full((ny, nx), STAY, np.int8)
        for a, (dy, dx) in enumerate(MOVES):  # from cell c, moving to c + (dy, dx)
            shifted = np.full((ny, nx), neg, np.int32)
            ys, yd = (slice(0, ny - dy), slice(dy, ny)) if dy >= 0 else (slice(-dy, ny), slice(0, ny + dy))
            xs, xd = (slice(0, nx - dx), slice(dx, nx)) if dx >= 0 else (slice(-dx, nx), slice(0, nx + dx))
            shifted[ys, xs] = here[yd, xd]
            better = shifted > best
            best = np.where(better, shifted, best)
            arg = np.where(better, a, arg)
        choice[t], value = arg, np.where(legal, best, neg)
    path = [np.array(start)]
    for t in range(h):
        path.append(path[-1] + TRACK_MOVES[choice[t, path[-1][0], path[-1][1]]])
    return np.array(path), int(value[start])


@dataclass
class TrackingEpisodes:
    """What ``run_tracking`` returns: one row per episode, and each episode's covered steps ``[K, H]``; with
    ``record``, also the UAV's canvas cells ``path`` ``[K, H + 1, 2]`` (the start first) and the user's route point
    ``points`` ``[K, H + 1]`` (rows of ``RouteSet.sinr``) at each step."""

    table: pd.DataFrame
    covered: np.ndarray
    path: np.ndarray | None = None
    points: np.ndarray | None = None


class TrackingEnv(EpisodeRows):
    """``num_envs`` tracking episodes stepped together in numpy, played from ``queue`` (``[K, 4]`` specs of
    ``RouteSet.sample_episodes``) or drawn with the generator of ``reset(seed)``; a finished episode restarts at once
    (``info["final_index"]``, with the ended rows' last observation, mask, cell and route point) unless the queue has
    run out (``exhausted``), or unless ``autoreset`` is False (the single Gymnasium env). ``compact``: uint8
    observations (``rl.vec_env.encode_obs``, 1 dB / 1 m / 1 s a step), as the trainer stores them.

    The trainer's interface is placement's (``rl.vec_env.EpisodeRows``, which it shares with ``BatchedEnv``), with
    ``info["sinr"]``, ``info["steps"]`` and ``info["covered_share"]`` (each row's episode so far; at its end, the
    ended episode's)."""

    def __init__(
        self,
        routes: RouteSet,
        num_envs: int,
        *,
        queue: np.ndarray | None = None,
        autoreset: bool = True,
        compact: bool = False,
    ) -> None:
        self._init_rows(num_envs, queue, np.float64)
        self.routes, self.config, self.maps, self.autoreset = routes, routes.config, routes.maps, autoreset
        self.compact = compact
        n, L, w = num_envs, self.maps.side, routes.config.window
        self.route = np.zeros(n, np.int64)
        self.start_s = np.zeros(n)
        self.pos = np.zeros((n, 2), np.int64)
        self.t = np.zeros(n, np.int64)
        self.episode_id = np.full(n, -1, np.int64)
        self.memory = np.zeros((n, L, L), np.float32)
        self.seen_at = np.zeros((n, L, L), np.float32)  # when each cell was last measured [s]; -inf never
        self.covered_steps = np.zeros(n, np.int64)  # steps of this episode at or above P_T so far
        self._memory_windows = np.lib.stride_tricks.sliding_window_view(self.memory, (w, w), axis=(1, 2))
        self._seen_windows = np.lib.stride_tricks.sliding_window_view(self.seen_at, (w, w), axis=(1, 2))
        self._height_windows = np.lib.stride_tricks.sliding_window_view(self.maps.height, (w, w), axis=(1, 2))

    def canvas(self, idx: np.ndarray | None = None) -> np.ndarray:
        """The height/blocked canvas row of each env's bundle."""
        idx = self._rows if idx is None else idx
        return self.routes.canvas[self.route[idx]]

    def point(self) -> np.ndarray:
        """Each env's route point now (a row of ``routes.sinr``)."""
        return self.routes.point(self.route, self.start_s, self.t)

    def sinr_here(self) -> np.ndarray:
        return self.routes.sinr[self.point(), self.pos[:, 0], self.pos[:, 1]]

    def _sample(self, k: int) -> np.ndarray:
        return self.routes.sample_episodes(k, self.rng)

    def _start(self, idx: np.ndarray) -> None:
        specs, ids = self._next_specs(len(idx))
        self.route[idx], self.start_s[idx] = specs[:, 0].astype(np.int64), specs[:, 1]
        self.pos[idx] = specs[:, 2:].astype(np.int64)
        self.t[idx], self.episode_id[idx], self.exhausted[idx], self.covered_steps[idx] = 0, ids, ids < 0, 0
        hidden = ~self.maps.on_map[self.canvas(idx)] if self.config.blind else self.maps.blocked[self.canvas(idx)]
        self.memory[idx] = np.where(hidden, self.config.p_l_db, self.config.p_h_db)
        self.seen_at[idx] = -np.inf
        self._measure(idx)

    def _measure(self, idx: np.ndarray) -> np.ndarray:
        y, x = self.pos[idx, 0], self.pos[idx, 1]
        sinr = self.routes.sinr[self.routes.point(self.route[idx], self.start_s[idx], self.t[idx]), y, x]
        self.memory[idx, y, x] = sinr
        self.seen_at[idx, y, x] = self.t[idx] * self.routes.step_s[self.route[idx]]
        return sinr

    def info(self) -> dict:
        return {"action_mask": self.action_mask()}

    @property
    def state_arrays(self) -> tuple[str, ...]:
        """Names of the arrays that hold the episodes' state: with the episode counter and the generator, what a
        checkpoint keeps to continue exactly."""
        return ("route", "start_s", "pos", "t", "episode_id", "memory", "seen_at", "covered_steps")

    def check_state(self, source: object) -> None:
        """``InputError`` (naming ``source``) unless the episode state (``state_arrays``, as a checkpoint restores it)
        is one this env can be in: routes in range, positions on open canvas cells, start times and counters from 0."""
        problems = {
            "route": (self.route < 0) | (self.route >= self.routes.num_routes),
            "start_s": ~np.isfinite(self.start_s) | (self.start_s < 0),
            "pos": ((self.pos < 0) | (self.pos >= self.maps.side)).any(axis=1),
            "t": (self.t < 0) | (self.t >= self.config.horizon),
            "memory": ~np.isfinite(self.memory).all(axis=(1, 2)),
            "covered_steps": (self.covered_steps < 0) | (self.covered_steps > self.t),
        }
        refuse_bad_rows(source, problems, self.maps.blocked[self.canvas(), self.pos[:, 0], self.pos[:, 1]])

    def genie_moves(self) -> np.ndarray:
        """``[N, 5]`` bool: the re-planning genie's choice (privileged, for training aids only; never part of an
        observation): stay on a cell that covers the user's point now, else the moves that start a shortest legal path
        to that point's P_T region; none where no target is reachable."""
        point = self.point()
        ny, nx = self.neighbours()
        here = self.routes.steps[point, self.pos[:, 0], self.pos[:, 1]]
        # Blocked and off-map cells hold UNREACHABLE, never below a reachable cell's distance: no legality mask needed.
        moves = self.routes.steps[point[:, None], ny, nx] < here[:, None]
        return np.c_[moves & (here > 0)[:, None], here == 0]

    def action_mask(self) -> np.ndarray:
        """``[N, 5]`` bool: the moves into a legal cell, and staying (always legal)."""
        ny, nx = self.neighbours()
        return np.c_[~self.maps.blocked[self.canvas()[:, None], ny, nx], np.ones(self.num_envs, bool)]

    def episode_keys(self) -> np.ndarray:
        """[N] uint64 keys of each row's episode for per-episode random draws (``rl.randomness``)."""
        return combine(self.routes.route_keys[self.route], self.episode_id)

    def observe(self) -> np.ndarray:
        cfg, rows = self.config, self._rows
        y0, x0 = self.pos[:, 0] - cfg.window // 2, self.pos[:, 1] - cfg.window // 2
        obs = np.empty((self.num_envs, cfg.num_channels, cfg.window, cfg.window), np.float32)
        if not cfg.blind:
            obs[:, 0] = self._height_windows[self.canvas(), y0, x0]
        now = (self.t * self.routes.step_s[self.route]).astype(np.float32)
        np.minimum(now[:, None, None] - self._seen_windows[rows, y0, x0], np.float32(cfg.age_clip_s), out=obs[:, -2])
        obs[:, -1] = self._memory_windows[rows, y0, x0]
        return encode_obs(obs) if self.compact else obs

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        actions = np.asarray(actions, np.int64)
        old = self.sinr_here()
        target = self.pos + TRACK_MOVES[actions]
        legal = ~self.maps.blocked[self.canvas(), target[:, 0], target[:, 1]]
        self.pos = np.where(legal[:, None], target, self.pos)
        self.t += 1
        new = self._measure(self._rows)
        covered = reaches_target(new, self.config.p_t_db)
        self.covered_steps += covered
        reward = (self.config.cover_reward * covered + self.config.gain_weight * (new - old)).astype(np.float32)
        truncated = self.t >= self.config.horizon
        info = {"illegal": ~legal, "covered": covered, "episode_id": self.episode_id.copy(), "steps": self.t.copy(),
                "sinr": new, "covered_share": self.covered_steps / self.t}  # fmt: skip
        if truncated.any() and self.autoreset:
            ended = np.flatnonzero(truncated)
            info["final_index"] = ended
            info["final_pos"], info["final_point"] = self.pos[ended].copy(), self.point()[ended]
            info["final_obs"], info["final_mask"] = self.observe()[ended], self.action_mask()[ended]
            self._start(ended)
        info["action_mask"] = self.action_mask()
        return self.observe(), reward, np.zeros(self.num_envs, bool), truncated, info


class MovesOnly:
    """A placement policy (``rl.policies``: 4 moves, never stays) acting in the tracking env: it is shown the moves'
    legal mask only, and keeps acting by its own rule after it first reaches P_T."""

    def __init__(self, policy) -> None:  # noqa: ANN001 - a rl.policies.Policy
        self.policy, self.name = policy, policy.name

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        self.policy.reset(rows, num_envs)

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingEnv) -> np.ndarray:
        return self.policy.act(obs, mask[:, :4], env)


class Holding:
    """A method without a stay action (a placement agent run unchanged, a placement baseline) with one rule on top:
    stay while its own measurement now (the SINR memory's centre, the cell it stands in) is at or above P_T, else
    act as ``policy`` does. ``policy`` still sees every observation, so a recurrent agent's state and a placement
    agent's mirror follow the episode while it holds; it reads nothing the UAV did not measure."""

    def __init__(self, policy) -> None:  # noqa: ANN001 - a tracking method (MovesOnly, PlacementInTracking)
        self.policy, self.name = policy, f"{policy.name} + hold"

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        self.policy.reset(rows, num_envs)

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingEnv) -> np.ndarray:
        action = self.policy.act(obs, mask, env)
        centre = env.config.window // 2
        return np.where(reaches_target(obs[:, -1, centre, centre], env.config.p_t_db), STAY, action)


class PlacementInTracking:
    """A placement policy that reads placement observations (a trained placement agent, run unchanged) acting in the
    tracking env. A placement env over the same cities (``BatchedEnv``, built for the agent's own ``EnvConfig``) keeps
    the agent's channels (SINR memory, visited cells, homing cone, context) from the tracking env's positions and
    measurements, as if the user's map were the placement episode's; the agent sees its observations, moves by its
    own rule (never stays) and keeps acting after it first reaches P_T."""

    def __init__(self, policy, env: EnvConfig, name: str | None = None) -> None:  # noqa: ANN001 - a rl.policies.Policy
        self.policy, self.name = policy, name or policy.name
        self.env_config = env.model_copy(update={"rotate": False, "city_weights": {}, "split": None})
        self.mirror = None
        self.key: tuple = ()

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        self.policy.reset(rows, num_envs)

    def _mirror(self, env: TrackingEnv):  # noqa: ANN202 - a BatchedEnv
        from uavplace.rl.vec_env import BatchedEnv

        if env.routes.turns != 1:
            raise ValueError("a placement agent plays the routes as they are: a RouteSet without rotate")
        key = (id(env.routes), env.num_envs)
        if self.key != key:
            maps = MapSet(env.routes.bundles, self.env_config)
            self.mirror, self.key = BatchedEnv(maps, env.num_envs, autoreset=False), key
            # per bundle, a view of its identity symmetry: its height and blocked canvases
            first = np.array([np.flatnonzero(maps.view_map == maps.symmetries * b)[0] for b in range(len(env.routes.bundles))])
            self.views, self.shift = first, maps.pad - env.maps.pad
            self.episode = np.full(env.num_envs, -2, np.int64)
        return self.mirror

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingEnv) -> np.ndarray:
        mirror = self._mirror(env)
        rows = np.arange(env.num_envs)
        pos, sinr = env.pos + self.shift, env.sinr_here()
        new = (env.t == 0) | (self.episode != env.episode_id)
        if new.any():
            idx = rows[new]
            mirror.begin(idx, self.views[env.routes.bundle[env.route[idx]]], pos[idx, 0], pos[idx, 1], sinr[idx],
                         env.episode_id[idx])  # fmt: skip
            self.episode[idx] = env.episode_id[idx]
        if (~new).any():
            idx = rows[~new]
            mirror.pos[idx], mirror.t[idx] = pos[idx], env.t[idx]
            mirror.measure(idx, sinr[idx])
        return self.policy.act(mirror.observe(), mask[:, :4], mirror)


class TrackingAgent:
    """An agent trained on the tracking task (``uavrl train --task tracking``), acting on the observations it was
    trained with (``observation``: its ``TrackingConfig``); ``run_tracking`` plays it on a ``RouteSet`` of those."""

    def __init__(self, policy, observation: TrackingConfig, name: str) -> None:  # noqa: ANN001 - a DQNPolicy
        self.policy, self.observation, self.name = policy, observation, name

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        self.policy.reset(rows, num_envs)

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingEnv) -> np.ndarray:
        return self.policy.act(obs, mask, env)


class ReplanningGenie:
    """The placement genie re-planned every step: knows the user's map now (not the future); stays while covered,
    else takes a shortest legal path toward the current P_T region."""

    name = "re-planning genie"

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        pass

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingEnv) -> np.ndarray:
        point = env.point()
        ny, nx = env.neighbours()
        steps = env.routes.steps[point[:, None], ny, nx].astype(np.int64)
        steps[~mask[:, :4]] = np.iinfo(np.int64).max
        here = env.routes.steps[point, env.pos[:, 0], env.pos[:, 1]]
        return np.where(here == 0, STAY, np.argmin(steps, axis=1))


class OraclePolicy:
    """The upper bound: knows the whole route and every map; follows ``oracle_path`` of its episode (computed when the
    episode starts), the most covered steps possible."""

    name = "oracle"

    def __init__(self) -> None:
        self.plans = np.zeros((0, 0, 2), np.int64)  # [num_envs, horizon + 1, 2]: each row's planned canvas cells
        self.planned = np.zeros(0, np.int64)  # the episode each row's plan is for

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        pass

    def plan(self, env: TrackingEnv, row: int) -> np.ndarray:
        r, p = int(env.route[row]), env.maps.pad
        canvas = env.routes.canvas[r]
        ny, nx = env.maps.shapes[canvas]
        t = np.arange(1, env.config.horizon + 1)
        points = env.routes.point(np.full(len(t), r), np.full(len(t), env.start_s[row]), t)
        sinr = env.routes.sinr[points, p : p + ny, p : p + nx]
        covered = reaches_target(sinr, env.config.p_t_db, env.routes.dead[points, p : p + ny, p : p + nx])
        legal = ~env.maps.blocked[canvas, p : p + ny, p : p + nx]
        path, _ = oracle_path(legal, covered, (int(env.pos[row, 0]) - p, int(env.pos[row, 1]) - p))
        return path + p

    def act(self, obs: np.ndarray, mask: np.ndarray, env: TrackingEnv) -> np.ndarray:
        n = env.num_envs
        if self.plans.shape[:2] != (n, env.config.horizon + 1):
            self.plans = np.zeros((n, env.config.horizon + 1, 2), np.int64)
            self.planned = np.full(n, -2, np.int64)
        for row in np.flatnonzero((env.t == 0) | (self.planned != env.episode_id)):  # episodes that just began
            self.plans[row], self.planned[row] = self.plan(env, row), env.episode_id[row]
        dy, dx = (self.plans[np.arange(n), env.t + 1] - env.pos).T
        return ACTION_OF[dy + 1, dx + 1]


def run_tracking(
    routes: RouteSet,
    policy,
    episodes: np.ndarray,
    *,
    num_envs: int = 256,
    record: bool = False,  # noqa: ANN001
) -> TrackingEpisodes:
    """Play ``episodes`` (``[K, 4]`` specs) to the horizon with ``policy`` (``rl.policies`` interface: ``reset``,
    ``act(obs, mask, env)``); one row per episode with the metrics of ``episode_metrics`` (and with ``record``, the
    UAV's path and the user's route points, for drawing). A ``TrackingAgent`` whose observation differs from
    ``routes.config``'s plays the same episodes on routes laid out for its own (cells and paths shifted between
    the two canvases' paddings)."""
    own = getattr(policy, "observation", None)
    if own is not None and routes.config.observed_as(own) != routes.config:
        mine = RouteSet(routes.bundles, routes.config.observed_as(own))
        shift = mine.maps.pad - routes.maps.pad
        played = run_tracking(mine, policy, np.asarray(episodes, float) + [0, 0, shift, shift], num_envs=num_envs,
                              record=record)  # fmt: skip
        if played.path is not None:
            played.path -= shift
        return played
    k, h = len(episodes), routes.config.horizon
    env = TrackingEnv(routes, min(num_envs, k), queue=np.asarray(episodes, float))
    obs, info = env.reset()
    policy.reset(np.arange(env.num_envs), env.num_envs)
    covered = np.zeros((k, h), bool)
    path = np.zeros((k, h + 1, 2), np.int64) if record else None
    points = np.zeros((k, h + 1), np.int64) if record else None
    done = 0
    while done < k:
        live = ~env.exhausted
        ids, t = env.episode_id.copy(), env.t.copy()
        if record:
            path[ids[live], t[live]], points[ids[live], t[live]] = env.pos[live], env.point()[live]
        obs, _, _, truncated, info = env.step(policy.act(obs, info["action_mask"], env))
        covered[ids[live], t[live]] = info["covered"][live]
        finished = truncated & live
        if record and finished.any():  # the last step's cell and point, from before the env restarted these rows
            final = np.searchsorted(info["final_index"], np.flatnonzero(finished))
            path[ids[finished], h], points[ids[finished], h] = info["final_pos"][final], info["final_point"][final]
        done += int(finished.sum())
        if finished.any():
            policy.reset(np.flatnonzero(finished), env.num_envs)
    metrics = episode_metrics(covered)
    table = pd.DataFrame({"episode": np.arange(k), "route": episodes[:, 0].astype(int), "start_s": episodes[:, 1]} | metrics)
    table["city"] = [routes.names[int(r)][0] for r in table["route"]]
    table["kind"] = [routes.names[int(r)][2] for r in table["route"]]
    return TrackingEpisodes(table, covered, path, points)

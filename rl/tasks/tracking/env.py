"""The tracking task stepped in numpy (``TrackingEnv``), and what its UAVs know of it (``TrackingView``)."""

from __future__ import annotations

import numpy as np

from uavplace.rl.randomness import combine
from uavplace.rl.tasks.tracking.config import TRACK_MOVES, TrackingConfig
from uavplace.rl.tasks.tracking.maps import RouteSet
from uavplace.rl.world.measurement import read
from uavplace.rl.world.rows import EpisodeRows, encode_obs, refuse_bad_rows
from uavplace.rl.world.view import UavView, frozen, public_maps


class TrackingEnv(EpisodeRows):
    """``num_envs`` tracking episodes stepped together in numpy, played from ``queue`` (``[K, 4]`` specs of
    ``RouteSet.sample_episodes``) or drawn with the generator of ``reset(seed)``; a finished episode restarts at once
    (``info["final_index"]``, with the ended rows' last observation, mask, cell and route point) unless the queue has
    run out (``exhausted``), or unless ``autoreset`` is False (the single Gymnasium env). ``compact``: uint8
    observations (``rl.world.rows.encode_obs``, 1 dB / 1 m / 1 s a step), as the trainer stores them. ``observing``
    off (``run_tracking``, for a policy that reads no observation): ``observe`` makes none and returns None.

    The trainer's interface is placement's (``rl.world.rows.EpisodeRows``, which it shares with ``BatchedEnv``), with
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
        first: int = 0,
    ) -> None:
        self._init_rows(num_envs, queue, np.float64, first)
        self.routes, self.config, self.maps, self.autoreset = routes, routes.config, routes.maps, autoreset
        self.compact = compact
        self.observing = True
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
        """Rows ``idx`` measure where they stand: their memory takes what the UAV reads (``rl.world.measurement``);
        returns the true SINR, which covers the user or not."""
        y, x = self.pos[idx, 0], self.pos[idx, 1]
        point = self.routes.point(self.route[idx], self.start_s[idx], self.t[idx])
        sinr = self.routes.sinr[point, y, x]
        reading = sinr
        if not self.config.measurement.exact:
            p, route = self.maps.pad, self.route[idx]
            spacing = self.routes.step_s[route] * self.config.uav_speed_mps
            keys = combine(self.episode_keys(idx), route)  # the world's: its route too
            dead = self.routes.dead[point, y, x]
            reading = read(self.config.measurement, sinr, dead, keys, self.t[idx], (x - p) * spacing, (y - p) * spacing)
        self.memory[idx, y, x] = reading
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

    def episode_keys(self, idx: np.ndarray | None = None) -> np.ndarray:
        """[N] (or ``[len(idx)]``) uint64 keys of each row's episode for per-episode random draws (``rl.randomness``):
        its canvas's public map (``RouteSet.route_keys``, the same for every route of a canvas) and its number in the
        played list."""
        idx = self._rows if idx is None else idx
        return combine(self.routes.route_keys[self.route[idx]], self.episode_id[idx])

    def agent_view(self) -> TrackingView:
        """What the rows' UAVs know now: what a policy other than the re-planning genie and the oracle receives."""
        return TrackingView(self)

    def observe(self) -> np.ndarray | None:
        """The rows' observations ``[N, C, w, w]``; None while ``observing`` is off (a policy that reads none)."""
        if not self.observing:
            return None
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
        covered = self.config.reaches(new)
        self.covered_steps += covered
        reward = (self.config.cover_reward * covered + self.config.gain_weight * (new - old)).astype(np.float32)
        truncated = self.t >= self.config.horizon
        info = {
            "illegal": ~legal,
            "covered": covered,
            "episode_id": self.episode_id.copy(),
            "steps": self.t.copy(),
            "sinr": new,
            "covered_share": self.covered_steps / self.t,
        }
        if truncated.any() and self.autoreset:
            ended = np.flatnonzero(truncated)
            info["final_index"] = ended
            info["final_pos"], info["final_point"] = self.pos[ended].copy(), self.point()[ended]
            obs = self.observe()
            info["final_obs"], info["final_mask"] = None if obs is None else obs[ended], self.action_mask()[ended]
            self._start(ended)
        info["action_mask"] = self.action_mask()
        return self.observe(), reward, np.zeros(self.num_envs, bool), truncated, info


class TrackingView(UavView):
    """The rows of a ``TrackingEnv`` as their UAVs know them at one step, made anew for every ``act``: what a tracking
    policy other than the re-planning genie and the oracle reads (``rl.world.view.UavView``: positions, steps, the
    SINR last measured at each cell, the canvas, the keys, the public maps), and ``seen_at`` [N, L, L] when each cell
    was last measured [s] (-inf never; a read-only view). No route, no route point, no user's map: nothing in it leads
    back to the env or to the ``RouteSet``."""

    config: TrackingConfig

    def __init__(self, env: TrackingEnv) -> None:
        canvas, keys = env.canvas(), env.episode_keys()
        super().__init__(public_maps(env), env.config, env.pos, env.t, env.exhausted, env.memory, canvas, keys)
        self.seen_at = frozen(env.seen_at)

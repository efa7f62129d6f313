"""N episodes stepped together in numpy: the environment every trainer and evaluator uses.

Observation ``[N, C, window, window]`` (C = 2: height channel, then SINR memory;
blind: the SINR memory only; with ``context_zoom`` the context channels after the
height channel, the window again in blocks of ``context_zoom`` cells; with
``fleet_channel`` the fleet's other UAVs (``fleet_plane``: none in placement); with
``visited_channel`` a channel of the visited cells, then with ``homing_channel`` the
homing cone (the best SINR measured so far less ``homing_slope_db`` per cell of
distance from where it was measured), then with ``belief_channel`` the map searcher's
posterior probability [%] of reaching P_T (``rl.belief.BeliefTracker``), before the
SINR memory, which stays last),
float32, or uint8 with ``compact=True`` (``encode_obs``: 1 dB / 1 m per step, offset
150; two 61 x 61 uint8 channels are 7.4 kB, so 5e5 transitions that store each
observation once take 3.5 GiB).

Step semantics (docs/method.md): a legal action moves the UAV one cell; an illegal
one (into a blocked cell or off the map, never taken by a masked policy)
leaves it in place. Reward ``SINR_{t+1} - SINR_t + c_E * [new cell never
visited]``, less ``step_cost`` and ``revisit_cost`` times the earlier visits of the
cell it enters (``visits`` counts them), plus the potential-based shaping term
``shaping * (shaping_gamma * phi' - phi)`` with ``phi = -(genie moves to a target)``
(0 unless configured: a training aid), all times ``reward_scale``. ``terminated`` when ``SINR >= P_T``; ``truncated`` when ``t_max``
moves are spent without it. Finished episodes restart at once (same step):
the returned observation is the new episode's first; ``info["final_obs"]`` and
``info["final_mask"]`` hold the last observation and legal moves of the
finished ones (rows ``info["final_index"]``).
"""

from __future__ import annotations

import numpy as np

from uavplace.rl.randomness import combine
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.world.maps import MOVES, MapSet
from uavplace.rl.world.measurement import read
from uavplace.rl.world.rows import EpisodeRows, encode_obs, refuse_bad_rows
from uavplace.rl.world.view import AgentView, public_maps


class BatchedEnv(EpisodeRows):
    """``num_envs`` UAV placement episodes over a ``MapSet``, stepped with whole-array numpy operations.

    Episodes are drawn from ``maps.sample_episodes`` with the generator seeded by ``reset(seed)``,
    or taken in order from ``queue`` (``[K, 3]`` episode specs) when one is given: evaluation
    then plays exactly those episodes, and ``exhausted`` tells which slots have no episode left.
    With ``autoreset=False`` finished episodes stay as they ended (the single Gymnasium env).
    """

    def __init__(
        self, maps: MapSet, num_envs: int, *, compact: bool = False, queue: np.ndarray | None = None, autoreset: bool = True
    ) -> None:
        self._init_rows(num_envs, queue)
        self.maps = maps
        self.autoreset = autoreset
        self.config: EnvConfig = maps.config
        self.compact = compact
        n, L = num_envs, maps.side
        self.view = np.zeros(n, np.int64)
        self.pos = np.zeros((n, 2), np.int64)
        self.t = np.zeros(n, np.int64)
        self.episode_id = np.full(n, -1, np.int64)
        self.start = np.zeros((n, 2), np.int64)  # each episode's start cell in its view's map (canvas less the pad)
        self.memory = np.zeros((n, L, L), np.float32)
        self.visits = np.zeros((n, L, L), np.uint16)  # times this episode stood in each canvas cell (the start counted)
        self.best_sinr = np.zeros(n, np.float32)  # the best SINR this episode measured, and where (canvas cell)
        self.best_pos = np.zeros((n, 2), np.int64)
        w = self.config.window
        # [n or M, L - w + 1, L - w + 1, w, w] views: window (y0, x0) is [.., y0, x0] (no copy until indexed).
        self._memory_windows = np.lib.stride_tricks.sliding_window_view(self.memory, (w, w), axis=(1, 2))
        self._height_windows = np.lib.stride_tricks.sliding_window_view(maps.height, (w, w), axis=(1, 2))
        self._visits_windows = np.lib.stride_tricks.sliding_window_view(self.visits, (w, w), axis=(1, 2))
        if self.config.homing_channel:
            # The cone's fall at every offset a window cell can have from the best cell (-L .. L + w in each axis): a
            # window of it is the fall over that window, taken as a block copy like the canvases' windows.
            offsets = np.arange(-L, L + w, dtype=np.float32)
            fall = np.float32(self.config.homing_slope_db) * np.hypot(offsets[:, None], offsets[None, :])
            self._fall_windows = np.lib.stride_tricks.sliding_window_view(fall, (w, w))
        if self.config.context_zoom:
            # The context SINR channel's canvas (the best SINR measured in each block once one of its cells is
            # visited, ``context_seen``) and its windows, as for the fine channels.
            self.context_memory = np.zeros((n, *maps.context_memory0.shape[1:]), np.float32)
            self.context_seen = np.zeros(self.context_memory.shape, bool)
            self._context_memory_windows = np.lib.stride_tricks.sliding_window_view(self.context_memory, (w, w), axis=(1, 2))
            self._context_height_windows = np.lib.stride_tricks.sliding_window_view(maps.context_height, (w, w), axis=(1, 2))
        self.belief = None
        if self.config.belief_channel:  # imported here: the predictors (torch) load only for the envs that use them
            from uavplace.rl.belief import PREDICTIONS, BeliefTracker, PredictionCache
            from uavplace.rl.config import DEFAULT_PREDICTOR, SearchConfig
            from uavplace.rl.predictor import load_predictor

            predictor = load_predictor(self.config.belief_predictor or DEFAULT_PREDICTOR)
            cache = PredictionCache(maps.bundles[0].path.parent.parent / PREDICTIONS)
            precision = self.config.belief_precision
            self.belief = BeliefTracker(maps, n, predictor, SearchConfig(), cache, window=w, precision=precision)
            self._belief_windows = np.lib.stride_tricks.sliding_window_view(self.belief.cover, (w, w), axis=(1, 2))

    @property
    def state_arrays(self) -> tuple[str, ...]:
        """Names of the arrays that hold the episodes' state: with the episode counter and the generator, what a
        checkpoint keeps to continue exactly."""
        return (
            ("view", "pos", "t", "episode_id", "start", "memory", "visits")
            + (("best_sinr", "best_pos") if self.config.homing_channel else ())
            + (("context_memory", "context_seen") if self.config.context_zoom else ())
            + (("belief_log",) if self.config.belief_channel else ())
        )

    @property
    def belief_log(self) -> np.ndarray:
        """``[N, C_max]`` the belief channel's log-beliefs (``BeliefTracker.log_b``; a checkpoint restores them in place)."""
        return self.belief.log_b

    def check_state(self, source: object) -> None:
        """``InputError`` (naming ``source``) unless the episode state (``state_arrays``, as a checkpoint restores it)
        is one this env can be in: views in range, positions on open canvas cells, counters from 0, finite SINR, beliefs
        that are finite somewhere; then the belief channel's canvases are made again from the restored beliefs."""
        problems = {
            "view": (self.view < 0) | (self.view >= self.maps.num_views),
            "pos": ((self.pos < 0) | (self.pos >= self.maps.side)).any(axis=1),
            "t": self.t < 0,
            "memory": ~np.isfinite(self.memory).all(axis=(1, 2)),
        }
        if self.config.homing_channel:
            problems["best_sinr"] = ~np.isfinite(self.best_sinr)
            problems["best_pos"] = ((self.best_pos < 0) | (self.best_pos >= self.maps.side)).any(axis=1)
        if self.config.context_zoom:
            problems["context_memory"] = ~np.isfinite(self.context_memory).all(axis=(1, 2))
        if self.belief is not None:  # each row's belief: finite somewhere, never NaN or +inf
            log_b = self.belief.log_b
            problems["belief_log"] = np.isnan(log_b).any(axis=1) | (log_b == np.inf).any(axis=1) | ~(log_b > -np.inf).any(axis=1)
        refuse_bad_rows(source, problems, self.maps.blocked[self.maps.view_map[self.view], self.pos[:, 0], self.pos[:, 1]])
        if self.belief is not None:  # the restored beliefs' cover canvases, as the steps that made them left them
            self.belief.canvas[:] = self.maps.view_map[self.view]
            self.belief.paint(self._rows)

    # -- episodes -----------------------------------------------------------------------------
    def _sample(self, k: int) -> np.ndarray:
        return self.maps.sample_episodes(k, self.rng)

    def _start(self, idx: np.ndarray) -> None:
        specs, ids = self._next_specs(len(idx))
        view, y, x = specs.T
        p = self.maps.pad
        first = self._read(view, y - p, x - p, y, x, np.zeros(len(idx), np.int64))
        self.begin(idx, view, y, x, first, ids)

    def _read(self, view: np.ndarray, sy: np.ndarray, sx: np.ndarray, y: np.ndarray, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        """What the UAVs of episodes (``view``, start map cell ``(sy, sx)``) read at canvas cells ``(y, x)`` at step
        ``t``: the true SINR plus the measurement error (``rl.world.measurement``; the true SINR when exact)."""
        true = self.maps.sinr[view, y, x]
        cfg = self.config.measurement
        if cfg.exact:
            return true
        p, spacing = self.maps.pad, self.maps.view_spacing_m[view]
        keys = combine(self._keys_of(view, sy, sx), self.maps.view_user[view])  # the world's: its user too
        return read(cfg, true, self.maps.dead[view, y, x], keys, t, (x - p) * spacing, (y - p) * spacing)

    def begin(self, idx: np.ndarray, view: np.ndarray, y: np.ndarray, x: np.ndarray, first: np.ndarray, ids: np.ndarray) -> None:
        """Start episodes ``ids`` in rows ``idx``: views ``view``, the UAV at canvas cells ``(y, x)``, which measure
        ``first`` (the view's SINR there; another task's measurement when this env only keeps an agent's channels)."""
        self.view[idx], self.pos[idx, 0], self.pos[idx, 1] = view, y, x
        self.t[idx] = 0
        self.episode_id[idx] = ids
        self.start[idx, 0], self.start[idx, 1] = y - self.maps.pad, x - self.maps.pad
        self.exhausted[idx] = ids < 0
        self.memory[idx] = self.maps.memory0[view]
        self.visits[idx] = 0
        self.visits[idx, y, x] = 1
        self.memory[idx, y, x] = first
        if self.config.homing_channel:
            self.best_sinr[idx], self.best_pos[idx] = first, self.pos[idx]
        if self.config.context_zoom:
            self.context_memory[idx] = self.maps.context_memory0[view]
            self.context_seen[idx] = False
            self._remember_context(idx, y, x, first)
        if self.belief is not None:
            pad, unread = self.maps.pad, self.exhausted[idx]  # a played-out queue's placeholders: no one reads their belief
            self.belief.start(idx, self.maps.view_map[view], y - pad, x - pad, first, unread)

    def _remember_context(self, idx: np.ndarray, y: np.ndarray, x: np.ndarray, sinr: np.ndarray) -> None:
        """Envs ``idx`` measured ``sinr`` at canvas cells ``(y, x)``: their context blocks keep the best."""
        cy, cx = self.maps.context_cell(y, x)
        seen = self.context_seen[idx, cy, cx]
        self.context_memory[idx, cy, cx] = np.where(seen, np.maximum(self.context_memory[idx, cy, cx], sinr), sinr)
        self.context_seen[idx, cy, cx] = True

    # -- state queries --------------------------------------------------------------------------
    def sinr_here(self) -> np.ndarray:
        """SINR [dB] at each UAV position, ``[N]``."""
        return self.maps.sinr[self.view, self.pos[:, 0], self.pos[:, 1]]

    def action_mask(self, idx: np.ndarray | None = None) -> np.ndarray:
        """``[len(idx), 4]`` bool (all envs by default): the moves into a legal cell (not blocked, on the map)."""
        idx = self._rows if idx is None else idx
        ny, nx = self.neighbours(idx)
        return ~self.maps.blocked[self.maps.view_map[self.view[idx]][:, None], ny, nx]

    @property
    def visited(self) -> np.ndarray:
        """``[N, side, side]`` bool: the cells this episode has stood in."""
        return self.visits > 0

    def neighbour_visits(self) -> np.ndarray:
        """``[N, 4]``: how often this episode has stood in the cell each move leads to (the agent's own route;
        0 off the map, where no move leads)."""
        ny, nx = self.neighbours()
        return self.visits[self._rows[:, None], ny, nx]

    def genie_steps(self) -> np.ndarray:
        """Shortest number of legal moves from each UAV position to a target cell, ``[N]``."""
        return self.maps.steps[self.view, self.pos[:, 0], self.pos[:, 1]]

    def genie_moves(self) -> np.ndarray:
        """``[N, 4]`` bool: the moves that start a shortest legal path to a target (privileged: the genie's
        choice, for training aids only; never part of an observation)."""
        ny, nx = self.neighbours()
        # Blocked and off-map cells hold UNREACHABLE, never below a reachable cell's distance: no legality mask needed.
        return self.maps.steps[self.view[:, None], ny, nx] < self.genie_steps()[:, None]

    def agent_view(self) -> AgentView:
        """What the rows' UAVs know now (``rl.world.view``): what a policy other than the genie receives."""
        return AgentView(self, public_maps(self))

    def episode_keys(self) -> np.ndarray:
        """[N] uint64: each row's episode, as ``rl.randomness`` keys it: by what the UAV knows of it, the public map
        of its canvas (``MapSet.canvas_keys``: the city's grid and buildings under a symmetry) and its start cell,
        never by its user, the bundle's version or its place in a list. An episode plays the same in any list and at
        any batch size; episodes of one canvas and start draw alike whoever the user is (nothing names the user)."""
        return self._keys_of(self.view, self.start[:, 0], self.start[:, 1])

    def _keys_of(self, view: np.ndarray, sy: np.ndarray, sx: np.ndarray) -> np.ndarray:
        """The keys of episodes of views ``view`` started at map cells ``(sy, sx)`` (``episode_keys``)."""
        return combine(self.maps.canvas_keys[self.maps.view_map[view]], sy * self.maps.side + sx)

    def info(self) -> dict:
        return {"action_mask": self.action_mask(), "episode_id": self.episode_id.copy(), "view": self.view.copy()}

    def observe(self, idx: np.ndarray | None = None) -> np.ndarray:
        """Observations ``[len(idx), C, w, w]`` (all envs by default).

        Windows are taken from sliding-window views of the canvases, so each is a block copy
        of ``w`` rows rather than ``w * w`` element lookups.
        """
        idx = self._rows if idx is None else idx
        y0 = self.pos[idx, 0] - self.config.window // 2
        x0 = self.pos[idx, 1] - self.config.window // 2
        cfg = self.config
        mem = self._memory_windows[idx, y0, x0]
        obs = np.empty((len(idx), cfg.num_channels, *mem.shape[1:]), np.float32)
        m = None if cfg.blind else self.maps.view_map[self.view[idx]]  # the height canvases' rows (blind: none read)
        if m is not None:
            obs[:, 0] = self._height_windows[m, y0, x0]
        if cfg.context_zoom:  # the context channels follow the height channel: height (not blind), then SINR
            cy, cx = self.maps.context_cell(self.pos[idx, 0], self.pos[idx, 1])
            cy0, cx0 = cy - cfg.window // 2, cx - cfg.window // 2
            if m is not None:
                obs[:, 1] = self._context_height_windows[m, cy0, cx0]
            obs[:, 0 if cfg.blind else 2] = self._context_memory_windows[idx, cy0, cx0]
        if cfg.fleet_channel:
            self.fleet_plane(idx, y0, x0, out=obs[:, cfg.fleet_index])
        if cfg.visited_channel:
            obs[:, -2 - cfg.homing_channel - cfg.belief_channel] = (self._visits_windows[idx, y0, x0] > 0) * np.float32(
                cfg.p_h_db
            )
        if cfg.homing_channel:
            self._homing(idx, y0, x0, out=obs[:, -2 - cfg.belief_channel])
        if cfg.belief_channel:
            obs[:, -2] = self._belief_windows[idx, y0, x0]
        obs[:, -1] = mem
        return encode_obs(obs) if self.compact else obs

    def fleet_plane(self, idx: np.ndarray, y0: np.ndarray, x0: np.ndarray, out: np.ndarray) -> None:
        """Write into ``out`` ``[len(idx), w, w]`` the fleet channel of the windows whose corners are canvas cells
        ``(y0, x0)``: p_h_db where another UAV stands. A placement UAV flies alone (zeros); the fleet's agents' env
        (``rl.tasks.fleet.policies``) marks its other UAVs."""
        out[...] = 0.0

    def _homing(self, idx: np.ndarray, y0: np.ndarray, x0: np.ndarray, out: np.ndarray) -> None:
        """Write into ``out`` ``[len(idx), w, w]`` the homing cone over the windows whose corners are canvas cells
        ``(y0, x0)``."""
        side = self.maps.side  # the window's corner less the best cell, shifted to index the fall's windows
        fall = self._fall_windows[y0 - self.best_pos[idx, 0] + side, x0 - self.best_pos[idx, 1] + side]
        np.subtract(self.best_sinr[idx, None, None], fall, out=out)
        np.maximum(out, np.float32(self.config.p_l_db), out=out)

    # -- dynamics -------------------------------------------------------------------------------
    def measure(self, rows: np.ndarray, new: np.ndarray) -> np.ndarray:
        """Rows ``rows`` measured ``new`` in the cells they stand in: the visit counts, the SINR memory, the context
        and the best SINR move on. Returns the cells' earlier visits."""
        y, x = self.pos[rows, 0], self.pos[rows, 1]
        before = self.visits[rows, y, x]
        self.visits[rows, y, x] = before + 1
        self.memory[rows, y, x] = new
        if self.config.context_zoom:
            self._remember_context(rows, y, x, new)
        if self.config.homing_channel:
            better = new > self.best_sinr[rows]  # the first cell of the best SINR stays the best
            self.best_sinr[rows[better]], self.best_pos[rows[better]] = new[better], self.pos[rows[better]]
        if self.belief is not None:
            self.belief.measure(rows, y - self.maps.pad, x - self.maps.pad, new, unread=self.exhausted[rows])
        return before

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        actions = np.asarray(actions, np.int64)
        rows, view, cfg = self._rows, self.view, self.config
        old = self.sinr_here()
        old_steps = self.genie_steps() if cfg.shaping else None
        target = self.pos + MOVES[actions]
        legal = ~self.maps.blocked[self.maps.view_map[view], target[:, 0], target[:, 1]]
        self.pos = np.where(legal[:, None], target, self.pos)
        y, x = self.pos[:, 0], self.pos[:, 1]
        new = self.maps.sinr[view, y, x]
        reading = self._read(view, self.start[:, 0], self.start[:, 1], y, x, self.t + 1)  # what the UAV reads there
        before = self.measure(rows, reading)  # earlier visits of the cell it now stands in
        fresh = before == 0
        self.t += 1
        terminated = cfg.reaches(new)
        reward = new - old + cfg.c_e * fresh + cfg.success_bonus * terminated - cfg.step_cost
        if cfg.revisit_cost:
            reward = reward - cfg.revisit_cost * before
        if cfg.shaping:
            # phi = -steps; the terminal state's potential is 0 (a target is 0 moves from itself).
            new_steps = np.where(terminated, 0, self.maps.steps[view, y, x])
            reward = reward + cfg.shaping * (old_steps - cfg.shaping_gamma * new_steps)
        reward = (reward * cfg.reward_scale).astype(np.float32)
        truncated = (self.t >= cfg.t_max) & ~terminated
        info = {"illegal": ~legal, "steps": self.t.copy(), "sinr": new, "episode_id": self.episode_id.copy()}
        done = (terminated | truncated) & self.autoreset
        if done.any():
            ended = np.flatnonzero(done)
            info["final_obs"] = self.observe(ended)
            info["final_mask"] = self.action_mask(ended)
            info["final_index"] = ended
            self._start(ended)
        info |= {"action_mask": self.action_mask(), "view": self.view.copy(), "started": done}
        return self.observe(), reward, terminated, truncated, info

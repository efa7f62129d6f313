"""The fleet task as the learner's (``learning``, the hook of its entry): placement's network, learner, loop,
checkpoints and run folder on ``FleetTrainEnv``, fleet episodes of the training cities' training users (a row per
UAV); ``best.pt`` is the network that, run on every UAV of fixed fleet episodes of the validation cities
(``FleetPlacement``), served every user in the most of them (ties: the fewer median steps)."""

from __future__ import annotations

import numpy as np

from uavplace.dataset.difficulty import UNREACHABLE
from uavplace.rl.tasks.entry import Learning, RunSettings
from uavplace.rl.tasks.fleet.config import STAY
from uavplace.rl.tasks.fleet.env import BatchedFleet, FleetView
from uavplace.rl.tasks.fleet.maps import FleetMaps
from uavplace.rl.tasks.fleet.policies import FleetPlacement
from uavplace.rl.tasks.fleet.rollout import run_fleet
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.world.cities import Cities
from uavplace.rl.world.maps import MOVES
from uavplace.schemas.base import InputError


class FleetTrainEnv:
    """The fleet task as the learner's environment (``learning``): a row per UAV of ``num_envs /
    K`` fleet episodes (row ``e * K + k``), each observing what ``FleetPlacement`` shows a UAV's agent (the placement
    observation of its dealt users' weakest SINR, from the fleet's shared measurements) and acting with the placement
    network's 4 moves: one network shared by every UAV, each acting from the shared memory and its own position.

    A UAV that ``FleetPlacement`` keeps still (no user, all of its users served, no free move) stays whatever its row
    chose. A row's reward is placement's, on the task its UAV was dealt when it moved: the change of its users'
    weakest SINR at its cell, plus ``c_e`` when it enters a cell the fleet never visited, plus ``success_bonus`` when
    it comes to serve all its users (times ``reward_scale``); a UAV that stays gets nothing. The rows of an episode end
    with it (every user served, or ``t_max``); a finished episode starts another, drawn with ``rng`` from the
    training cities (``FleetMaps.draw``). The genie's moves of a row (the auxiliary head's labels): those that start a
    shortest path to a cell serving every user dealt to its UAV (``FleetMaps.group_reach``; none where no cell
    does). The trainer's interface is ``rl.world.rows.EpisodeRows``'s, checkpoints included (``state_arrays``: the
    fleet's episode state; the dealt rows are read afresh from it)."""

    state_arrays = ("city", "users", "pos", "t", "memory", "visits", "best", "served_at", "done", "episode_id", "keys")

    def __init__(self, maps: FleetMaps, env: EnvConfig, num_envs: int) -> None:
        k = maps.config.uavs
        if num_envs % k:
            raise ValueError(f"num_envs {num_envs} is not a multiple of the fleet's {k} UAVs")
        self.maps, self.uavs, self.num_envs, self.env_config = maps, k, num_envs, env
        self.fleet = BatchedFleet(maps, num_envs // k)
        self.deal = FleetPlacement(None, env, "fleet", compact=True).bind(maps)
        self.rng = np.random.default_rng()
        self._episodes_started = 0
        self._idle = np.zeros((num_envs // k, k), bool)
        for name in self.state_arrays:  # the fleet's arrays themselves (changed in place), as a checkpoint saves them
            setattr(self, name, getattr(self.fleet, name))

    def _begin(self, rows: np.ndarray) -> None:
        episodes, tries = [], 0
        while len(episodes) < len(rows):
            drawn = self.maps.draw(self.rng)
            tries += 1
            if drawn is not None:
                episodes.append(drawn)
            elif tries > 1000 * len(rows):
                names = ", ".join(c.name for c in self.maps.cities)
                raise InputError(
                    names,
                    "no fleet episode found in 1000 draws a row: every user needs a target cell "
                    "reachable from the starts (fewer fleet.users or another fleet.p_t_db)",
                    field="fleet",
                )
        ids = self._episodes_started + np.arange(len(rows))
        self._episodes_started += len(rows)
        self.fleet.begin(rows, np.array(episodes, np.int64), ids)
        self.deal.reset_deal(rows, self.fleet.num_envs, self.uavs)

    def _dealt(self) -> tuple[np.ndarray, np.ndarray]:
        obs, moves, self._idle = self.deal.dealt(self.fleet.action_mask(), FleetView.of(self.fleet))
        return obs, moves

    def reset(self, *, seed: int | None = None) -> tuple[np.ndarray, dict]:
        self.rng = np.random.default_rng(seed)
        self._begin(np.arange(self.fleet.num_envs))
        obs, moves = self._dealt()
        return obs, {"action_mask": moves}

    def observe(self) -> np.ndarray:
        return self._dealt()[0]

    def action_mask(self) -> np.ndarray:
        return self._dealt()[1]

    def check_state(self, source: object) -> None:
        """``InputError`` (naming ``source``) unless the restored episode state is one of these cities'; then every
        UAV's row is read afresh from it."""
        f, cfg = self.fleet, self.maps.config
        users = np.array([len(c.sinr_db) for c in self.maps.cities])
        ok = ((f.city >= 0) & (f.city < len(self.maps.cities))).all() and (f.t >= 0).all() and (f.t <= cfg.t_max).all()
        ok = ok and ((f.users >= 0) & (f.users < users[np.clip(f.city, 0, len(users) - 1), None])).all()
        ok = ok and ((f.pos >= self.maps.pad) & (f.pos < self.maps.side - self.maps.pad)).all()
        if not ok or self.maps.blocked[f.city[:, None], f.pos[..., 0], f.pos[..., 1]].any():
            raise InputError(source, "the fleet's episode state is not one of these cities' (city, users, cells)", field="pos")
        self.deal.reset_deal(np.arange(f.num_envs), f.num_envs, self.uavs)

    def sinr_here(self) -> np.ndarray:
        """``[num_envs]`` the weakest user's best SINR in each row's episode (what the training log's gain reads)."""
        return np.repeat(self.fleet.best.min(axis=1), self.uavs)

    def neighbour_visits(self) -> np.ndarray:
        """``[num_envs, 4]`` the fleet's visits of the cell each move leads to."""
        return self.deal.mirror.neighbour_visits()

    def genie_moves(self) -> np.ndarray:
        """``[num_envs, 4]`` bool: the moves of each UAV that start a shortest path to a cell serving all its users
        (privileged: a training aid only, never an observation)."""
        f, p, k = self.fleet, self.maps.pad, self.uavs
        out = np.zeros((self.num_envs, STAY), bool)
        for e, uav in zip(*np.nonzero(self.deal.groups.any(axis=2) & ~self._idle), strict=True):
            reach = self.maps.group_reach(int(f.city[e]), tuple(int(u) for u in np.flatnonzero(self.deal.groups[e, uav])))
            y, x = f.pos[e, uav] - p
            here = reach[y, x]
            if here >= UNREACHABLE:
                continue
            ny, nx = y + MOVES[:, 0], x + MOVES[:, 1]
            inside = (ny >= 0) & (ny < reach.shape[0]) & (nx >= 0) & (nx < reach.shape[1])
            out[e * k + uav, inside] = reach[ny[inside], nx[inside]] < here
        return out

    def _weakest(self, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``[E, K]`` each UAV's weakest SINR of the users in ``groups`` [E, K, N] where it stands (0 without users), and
        whether it serves them all."""
        here = FleetView.of(self.fleet).at_uavs()
        weakest = np.where(groups, here, np.inf).min(axis=2)
        has = groups.any(axis=2)
        return np.where(has, weakest, 0.0), has & self.maps.config.reaches(weakest)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        k, cfg, f = self.uavs, self.env_config, self.fleet
        chosen = np.asarray(actions, np.int64).reshape(-1, k)
        groups = self.deal.groups.copy()  # the task each UAV moves for
        before, served_before = self._weakest(groups)
        moving = ~self._idle & ~f.done[:, None]
        _, terminated, truncated = f.step(np.where(self._idle, STAY, chosen))
        after, served_after = self._weakest(groups)
        rows = np.arange(f.num_envs)[:, None]
        fresh = f.visits[rows, f.pos[..., 0], f.pos[..., 1]] == 1
        reward = after - before + cfg.c_e * fresh + cfg.success_bonus * (served_after & ~served_before)
        reward = np.where(moving, reward, 0.0) * cfg.reward_scale
        term, trunc = np.repeat(terminated, k), np.repeat(truncated, k)
        final = np.flatnonzero(trunc)
        info = {"final_index": final, "sinr": self.sinr_here(), "steps": np.repeat(self.fleet.t, k)}
        if len(final):  # the last observation of the rows cut short, before their next episodes begin
            obs, moves = self._dealt()
            info["final_obs"], info["final_mask"] = obs[final], moves[final]
        ended = np.flatnonzero(terminated | truncated)
        if len(ended):
            self._begin(ended)
        obs, moves = self._dealt()  # a second deal in one step (after a cut) changes nothing but the begun rows
        info["action_mask"] = moves
        return obs, reward.ravel().astype(np.float32), term, trunc, info


def learning(run: RunSettings, cities: Cities) -> Learning:
    """The fleet's training env over the training cities' training users, and the validation on fixed fleet
    episodes of the validation cities."""
    task, env = run.task.fleet(), run.env_config()
    maps, eval_maps = FleetMaps.of(cities.train, task, cities.train_users), FleetMaps.of(cities.val, task, cities.val_users)
    episodes = eval_maps.episode_list(run.eval_episodes, run.seed)

    def validate(policy) -> tuple[dict, tuple[float, float]]:
        fleet = FleetPlacement(policy, run.env_config(evaluation=True), prefix="").bind(eval_maps)
        table = run_fleet(eval_maps, fleet, episodes)
        row = {
            "success": float(table["success"].mean()),
            "median_steps": float(np.median(table["steps"])),
            "spl": float(table["spl"].mean()),
        }
        return row, (row["success"], -row["median_steps"])

    return Learning(FleetTrainEnv(maps, env, run.num_envs), task.t_max, cities.train, cities.val, validate)

"""Play a fixed list of episodes with any policy, batched: the same episodes for every method."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.tasks.placement.maps import MOVES, MapSet
from uavplace.rl.tasks.placement.policies import Policy
from uavplace.rl.view import view_for


def run_episodes(
    maps: MapSet,
    policy: Policy,
    episodes: np.ndarray,
    *,
    num_envs: int = 256,
    on_step: Callable[[int, int], None] | None = None,
    record: np.ndarray | None = None,
) -> pd.DataFrame:
    """Play ``episodes`` (``[K, 3]`` specs from ``MapSet.sample_episodes``) to their end with ``policy``.

    Returns one row per episode: ``episode, view, city, user, rotation`` (the view's symmetry, 0-7), ``start_y, start_x``
    (the start's cell of the bundle's map, the view's symmetry undone, whatever the window), ``genie_steps`` (shortest possible), ``steps`` (moves played), ``success`` (P_T reached
    within ``t_max``) and ``return_`` (sum of rewards). ``on_step(done, total)`` reports progress.
    ``record``: episode numbers whose cells, start included, go to ``df.attrs["paths"]``
    (``{episode: [T + 1, 2] (iy, ix)}``, cells of the bundle's map, the view's rotation undone).
    """
    k = len(episodes)
    env = BatchedEnv(maps, min(num_envs, k), queue=episodes)
    obs, info = env.reset()
    policy.reset(np.arange(env.num_envs), env.num_envs)
    genie = np.zeros(k, np.int64)
    genie[env.episode_id[~env.exhausted]] = env.genie_steps()[~env.exhausted]
    steps = np.zeros(k, np.int64)
    success = np.zeros(k, bool)
    ret = np.zeros(k, np.float64)
    acc = np.zeros(env.num_envs, np.float64)
    wanted = np.zeros(k, bool)
    if record is not None:
        wanted[np.asarray(record, np.int64)] = True
    trail: dict[int, list[np.ndarray]] = {}
    paths: dict[int, np.ndarray] = {}

    def follow(rows: np.ndarray) -> None:
        for r in rows[wanted[env.episode_id[rows]] & ~env.exhausted[rows]]:
            trail[int(env.episode_id[r])] = [env.pos[r].copy()]

    follow(np.arange(env.num_envs))
    finished = 0
    while finished < k:
        actions = policy.act(obs, info["action_mask"], view_for(policy, env))
        live = ~env.exhausted
        ids = env.episode_id.copy()
        moved = env.pos.copy()
        obs, reward, terminated, truncated, info = env.step(actions)
        for r in np.flatnonzero(live & wanted[ids]):
            # After an episode ends the row restarts; its last cell is the move's target, not env.pos.
            here = env.pos[r] if not info["started"][r] else _landed(moved[r], actions[r], info["illegal"][r])
            trail[int(ids[r])].append(here.copy())
        acc += reward
        done = (terminated | truncated) & live
        if done.any():
            rows = np.flatnonzero(done)
            steps[ids[rows]] = info["steps"][rows]
            success[ids[rows]] = terminated[rows]
            ret[ids[rows]] = acc[rows]
            acc[rows] = 0.0
            finished += len(rows)
            for r in rows[wanted[ids[rows]]]:
                canvas = np.array(trail.pop(int(ids[r])), np.int64)  # [T + 1, 2] (y, x) in the view
                iy, ix = maps.unrotate(np.full(len(canvas), episodes[ids[r], 0]), canvas[:, 0], canvas[:, 1])
                paths[int(ids[r])] = np.stack([iy, ix], axis=1)
            follow(rows)
            policy.reset(rows, env.num_envs)
            fresh = rows[~env.exhausted[rows]]
            genie[env.episode_id[fresh]] = env.genie_steps()[fresh]
            if on_step is not None:
                on_step(finished, k)
    view = episodes[:, 0]
    scen = [maps.scenarios[v] for v in maps.scenario_of(view)]
    start_y, start_x = maps.unrotate(view, episodes[:, 1], episodes[:, 2])
    df = pd.DataFrame(
        {
            "episode": np.arange(k),
            "view": view,
            "city": [s.city for s in scen],
            "user": [s.user for s in scen],
            "rotation": maps.symmetry_of(view),
            "start_y": start_y,
            "start_x": start_x,
            "genie_steps": genie,
            "steps": steps,
            "success": success,
            "return_": ret,
        }
    )
    df.attrs["paths"] = paths
    return df


def _landed(pos: np.ndarray, action: int, illegal: bool) -> np.ndarray:
    return pos if illegal else pos + MOVES[action]


def summarise(df: pd.DataFrame) -> dict[str, float]:
    """Success rate, and steps to P_T over all episodes with failures counted as infinite (> t_max)."""
    stats = episode_stats(df["steps"].to_numpy(), df["success"].to_numpy(), df["genie_steps"].to_numpy())
    return {name: float(v) for name, v in stats.items()}


#: The statistics of ``episode_stats``, in table order, with their labels (one wording in every table).
STATS = {
    "success": "success",
    "median_steps": "median steps",
    "p75_steps": "p75 steps",
    "within_100": "solved within 100 steps",
    "steps_over_genie": "median of per-episode steps / genie",
    "medians_ratio": "median / genie's median (paper's ratio)",
    "spl": "SPL",
    "iqm_over_genie": "IQM of steps / genie",
    "iqm_spl": "IQM of SPL",
    "mean_steps_success": "mean steps of its own successes (unpaired)",
}
#: The statistics that are ratios to the genie (infinite: the median episode failed, not a step count).
RATIOS = ("steps_over_genie", "medians_ratio", "iqm_over_genie")
#: The statistics of scores in [0, 1] (three decimals).
SCORES = ("spl", "iqm_spl")
#: The share of the episodes cut from each end by the interquartile mean (rliable's IQM: ``scipy.stats.trim_mean``).
IQM_CUT = 0.25
#: ``within_100``'s step budget.
WITHIN = 100


def episode_stats(steps: np.ndarray, success: np.ndarray, genie_steps: np.ndarray) -> dict[str, np.ndarray]:
    """The evaluation's statistics over the last axis (episodes); leading axes are kept (bootstrap resamples).

    ``success`` rate; ``median_steps`` and ``p75_steps`` of steps to P_T with failures infinite;
    ``within_100``: share of episodes solved within 100 steps; ``steps_over_genie``: median of steps /
    genie steps per episode (infinite for failures); ``medians_ratio``: the median steps over the genie's median
    steps (the paper's way of comparing; infinite when the median is a failure); ``spl``: success weighted by path
    length (Anderson et al. 2018, "On evaluation of embodied navigation agents"), the mean over episodes of
    ``success * genie / max(steps, genie)``, the genie's steps as the shortest path; ``iqm_over_genie`` and
    ``iqm_spl``: the interquartile means (``interquartile_mean``; Agarwal et al. 2021, "Deep reinforcement learning
    at the edge of the statistical precipice") of the per-episode steps / genie (inf when more than a quarter of the
    episodes fail) and of the SPL terms; ``mean_steps_success``: the mean over the method's
    own successes (nan without any), so two methods' values average different episodes. Quantiles are
    order statistics (``inverted_cdf``), so a quantile that falls on a failure is inf.
    """
    ok = np.asarray(success, bool)
    to_target = np.where(ok, steps, np.inf)
    ratio = np.where(ok, steps / np.maximum(genie_steps, 1), np.inf)
    spl = spl_terms(steps, ok, genie_steps)
    n_ok = ok.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_ok = np.where(n_ok > 0, np.where(ok, steps, 0).sum(axis=-1) / n_ok, np.nan)
    return {
        "success": ok.mean(axis=-1),
        "median_steps": np.quantile(to_target, 0.5, axis=-1, method="inverted_cdf"),
        "p75_steps": np.quantile(to_target, 0.75, axis=-1, method="inverted_cdf"),
        "within_100": (to_target <= WITHIN).mean(axis=-1),
        "steps_over_genie": np.quantile(ratio, 0.5, axis=-1, method="inverted_cdf"),
        "medians_ratio": np.quantile(to_target, 0.5, axis=-1, method="inverted_cdf")
        / np.maximum(np.quantile(genie_steps, 0.5, axis=-1, method="inverted_cdf"), 1),
        "spl": spl.mean(axis=-1),
        "iqm_over_genie": interquartile_mean(ratio),
        "iqm_spl": interquartile_mean(spl),
        "mean_steps_success": mean_ok,
    }


def interquartile_mean(values: np.ndarray) -> np.ndarray:
    """The mean of the middle half over the last axis: ``int(n / 4)`` values cut from each end of the sorted sample, as
    ``scipy.stats.trim_mean(values, 0.25)`` (rliable's IQM); inf when an inf value is kept."""
    v = np.sort(np.asarray(values, np.float64), axis=-1)
    cut = int(IQM_CUT * v.shape[-1])
    return v[..., cut : v.shape[-1] - cut].mean(axis=-1)


def spl_terms(steps: np.ndarray, success: np.ndarray, genie_steps: np.ndarray) -> np.ndarray:
    """Each episode's term of SPL: ``success * genie / max(steps, genie)`` (1 for a success in the genie's steps; a
    start on a target, genie 0, counts 1 when reached). Shapes broadcast."""
    genie = np.asarray(genie_steps, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(genie > 0, genie / np.maximum(np.maximum(steps, genie), 1), 1.0)
    return np.where(np.asarray(success, bool), ratio, 0.0)


def format_stat(stat: str, value: float, lo: float | None = None, hi: float | None = None, t_max: int | None = None) -> str:
    """A table cell: percentages for shares, ``> t_max`` (``> 500`` with ``t_max``) for infinite steps, ``[lo, hi]``
    when given."""
    share = stat in ("success", "within_100")
    if stat in SCORES:
        return f"{value:.3f}" + (f" [{lo:.3f}, {hi:.3f}]" if lo is not None and hi is not None else "")
    beyond = "> t_max" if t_max is None else f"> {t_max}"

    def one(v: float, bound: bool = False) -> str:
        if share:
            return f"{100 * v:.1f} %"
        if np.isinf(v):
            if stat in RATIOS and bound:
                return "inf"
            if stat == "iqm_over_genie":
                return "inf (over a quarter failed)"
            return "inf (median a failure)" if stat in RATIOS else beyond
        if np.isnan(v):
            return "-"
        return f"{v:.2f}" if stat in RATIOS else f"{v:.1f}" if stat == "mean_steps_success" else f"{v:g}"

    text = one(value)
    if lo is not None and hi is not None:
        text += f" [{one(lo).removesuffix(' %')}, {one(hi)}]" if share else f" [{one(lo, True)}, {one(hi, True)}]"
    return text

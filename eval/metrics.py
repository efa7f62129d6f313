"""The evaluation protocol's figures: per-method statistics with paired bootstrap confidence intervals.

Every method plays the same episodes (``rl.rollout.run_episodes`` on one list of episode specs), so
one resample of episode numbers is applied to all methods at once (a paired bootstrap): the intervals
of two methods are comparable episode for episode.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rl.rollout import episode_stats

#: The statistics of ``rl.rollout.episode_stats``, in table order, with their labels.
STATS = {
    "success": "success",
    "median_steps": "median steps",
    "mean_steps_success": "mean steps (successes)",
    "p90_steps": "p90 steps",
    "steps_over_genie": "median steps / genie",
}


def bootstrap_table(results: dict[str, pd.DataFrame], *, n_boot: int = 2000, level: float = 0.95, seed: int = 0) -> pd.DataFrame:
    """One row per method: each statistic with its percentile bootstrap interval (``<stat>_lo``, ``<stat>_hi``).

    ``results`` maps a method name to its ``run_episodes`` frame; all frames must hold the same
    episodes (same ``episode``, ``view``, ``start_y``, ``start_x``), which is checked.
    """
    if not results:
        raise ValueError("no method to tabulate")
    frames = list(results.values())
    key = ["episode", "view", "start_y", "start_x"]
    first = frames[0][key].reset_index(drop=True)
    for name, df in results.items():
        if not df[key].reset_index(drop=True).equals(first):
            raise ValueError(f"method {name!r} played other episodes than {next(iter(results))!r}: not a paired comparison")
    n = len(first)
    rng = np.random.default_rng(seed)
    resample = rng.integers(0, n, size=(n_boot, n))  # [n_boot, n] episode numbers, shared by all methods
    alpha = (1.0 - level) / 2.0
    rows = []
    for name, df in results.items():
        steps, ok, genie = (df[c].to_numpy() for c in ("steps", "success", "genie_steps"))
        point = episode_stats(steps, ok, genie)
        boot = episode_stats(steps[resample], ok[resample], genie[resample])
        row: dict[str, object] = {"method": name, "episodes": n}
        for stat in STATS:
            row[stat] = float(point[stat])
            lo, hi = np.quantile(boot[stat], [alpha, 1.0 - alpha], method="inverted_cdf")
            row[f"{stat}_lo"], row[f"{stat}_hi"] = float(lo), float(hi)
        rows.append(row)
    return pd.DataFrame(rows)


def ecdf(df: pd.DataFrame, t_max: int) -> tuple[np.ndarray, np.ndarray]:
    """Share of episodes that reached P_T within ``s`` steps, for ``s = 0 .. t_max``: ``(s [t_max+1], F [t_max+1])``."""
    s = np.arange(t_max + 1)
    reached = np.where(df["success"].to_numpy(), df["steps"].to_numpy(), t_max + 1)
    counts = np.bincount(np.minimum(reached, t_max + 1), minlength=t_max + 2)[: t_max + 1]
    return s, np.cumsum(counts) / max(len(df), 1)


def format_stat(stat: str, value: float, lo: float | None = None, hi: float | None = None) -> str:
    """A table cell: percentages for the success rate, ``> t_max`` for infinite steps, ``[lo, hi]`` when given."""

    def one(v: float) -> str:
        if stat == "success":
            return f"{100 * v:.1f} %"
        if np.isinf(v):
            return "> t_max"
        if np.isnan(v):
            return "-"
        return f"{v:.2f}" if stat == "steps_over_genie" else f"{v:.1f}" if stat == "mean_steps_success" else f"{v:g}"

    text = one(value)
    if lo is not None and hi is not None:
        text += f" [{one(lo).removesuffix(' %')}, {one(hi)}]" if stat == "success" else f" [{one(lo)}, {one(hi)}]"
    return text

"""The evaluation protocol's figures: per-method statistics with paired bootstrap confidence intervals.

Every method plays the same episodes (``rl.rollout.run_episodes`` on one list of episode specs), so
one resample of episode numbers is applied to all methods at once (a paired bootstrap): the intervals
of two methods are comparable episode for episode.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from uavplace.rl.rollout import STATS, episode_stats, format_stat

__all__ = ["STATS", "bootstrap_table", "ecdf", "format_stat"]


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

"""The episode statistics every task's report reads: success, steps to P_T against the genie's, SPL and the
interquartile means (``episode_stats``), their labels (``STATS``) and how a table writes them (``format_stat``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd


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

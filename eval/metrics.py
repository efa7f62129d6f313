"""The evaluation protocol's figures: per-method statistics and paired differences with bootstrap intervals.

Every method plays the same episodes (``rl.tasks.placement.rollout.run_episodes`` on one list of episode specs), so
one resample is applied to all methods at once (a paired bootstrap): the intervals of two methods,
and of their difference, are comparable episode for episode.

The episodes come from a few users (25 per test city), and episodes of one user are alike, so the
resample has two levels (``resample_counts``): users with replacement, then the episodes of each
drawn user with replacement. Resampling the episodes alone treats 1000 episodes of 25 users as
1000 independent draws and gives intervals 2-3 times too narrow.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from uavplace.rl.world.stats import IQM_CUT, STATS, WITHIN, format_stat, spl_terms

__all__ = [
    "STATS",
    "aggregate_table",
    "bootstrap_table",
    "difference_table",
    "ecdf",
    "format_stat",
    "group_tables",
    "performance_profile",
    "profiles",
    "resample_counts",
    "stratified_counts",
    "weighted_iqm",
    "weighted_stats",
]

#: The statistics a difference is reported for (the two the paper reports).
DIFFERENCE_STATS = ("success", "median_steps")


def resample_counts(groups: np.ndarray | None, n: int, n_boot: int, seed: int | tuple[int, ...]) -> np.ndarray:
    """[n_boot, n] how often each of ``n`` episodes is drawn in each bootstrap replicate.

    ``groups`` [n] (the user of each episode): users drawn with replacement, then for each drawn user
    as many of its episodes as it has, with replacement (a user drawn twice contributes two draws).
    ``None``: every episode is its own group (the plain bootstrap of episodes).
    """
    rng = np.random.default_rng(seed)
    if groups is None:
        return rng.multinomial(n, np.full(n, 1.0 / n), size=n_boot)
    _, label = np.unique(np.asarray(groups), return_inverse=True)
    num_groups = label.max() + 1
    drawn = rng.multinomial(num_groups, np.full(num_groups, 1.0 / num_groups), size=n_boot)  # [n_boot, groups]
    counts = np.zeros((n_boot, n), np.int64)
    for g in range(num_groups):
        members = np.flatnonzero(label == g)
        # c independent draws of the group's size from its episodes = one multinomial of c * size trials.
        counts[:, members] = rng.multinomial(drawn[:, g] * len(members), np.full(len(members), 1.0 / len(members)))
    return counts


def stratified_counts(strata: np.ndarray, groups: np.ndarray, n_boot: int, seed: int) -> np.ndarray:
    """``resample_counts`` within each stratum (a city) on its own: every replicate keeps each city's share of the
    episodes (rliable's stratified bootstrap over tasks), resampling the city's users, then their episodes."""
    strata, groups = np.asarray(strata), np.asarray(groups)
    counts = np.zeros((n_boot, len(strata)), np.int64)
    for i, stratum in enumerate(np.unique(strata)):
        members = np.flatnonzero(strata == stratum)
        counts[:, members] = resample_counts(groups[members], len(members), n_boot, (seed, i))
    return counts


def _weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> np.ndarray:
    """The ``inverted_cdf`` q-quantile of ``values`` [n] under each row of ``weights`` [B, n] (inf may occur)."""
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[:, order], axis=1)
    k = np.argmax(cum >= q * cum[:, -1:] - 1e-9, axis=1)
    return values[order][k]


def weighted_stats(steps: np.ndarray, success: np.ndarray, genie_steps: np.ndarray, weights: np.ndarray) -> dict:
    """``rl.world.stats.episode_stats`` under episode weights [B, n] (bootstrap counts): each statistic [B]."""
    ok = np.asarray(success, bool)
    w = np.asarray(weights, np.float64)
    to_target = np.where(ok, steps, np.inf)
    ratio = np.where(ok, steps / np.maximum(genie_steps, 1), np.inf)
    spl = spl_terms(steps, ok, genie_steps)
    total = w.sum(axis=1)
    w_ok = (w * ok).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_ok = np.where(w_ok > 0, (w * np.where(ok, steps, 0)).sum(axis=1) / w_ok, np.nan)
    return {
        "success": w_ok / total,
        "median_steps": _weighted_quantile(to_target, w, 0.5),
        "p75_steps": _weighted_quantile(to_target, w, 0.75),
        "within_100": (w * (to_target <= WITHIN)).sum(axis=1) / total,
        "steps_over_genie": _weighted_quantile(ratio, w, 0.5),
        "medians_ratio": _weighted_quantile(to_target, w, 0.5)
        / np.maximum(_weighted_quantile(np.asarray(genie_steps, np.float64), w, 0.5), 1),
        "spl": (w * spl).sum(axis=1) / total,
        "iqm_over_genie": weighted_iqm(ratio, w),
        "iqm_spl": weighted_iqm(spl, w),
        "mean_steps_success": mean_ok,
    }


def weighted_iqm(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``rl.world.stats.interquartile_mean`` of the sample in which value ``i`` occurs ``weights[b, i]``
    times (bootstrap counts: whole numbers), for each row ``b``: [B]. The same values as expanding the sample and
    trimming it."""
    order = np.argsort(values, kind="stable")
    v = np.asarray(values, np.float64)[order]
    w = np.asarray(weights, np.float64)[:, order]
    total = w.sum(axis=1, keepdims=True)
    cut = np.floor(IQM_CUT * total)
    upto = np.cumsum(w, axis=1)  # the ranks [upto - w, upto) of each value in the expanded, sorted sample
    kept = np.clip(np.minimum(upto, total - cut) - np.maximum(upto - w, cut), 0.0, None)
    with np.errstate(invalid="ignore"):  # 0 x inf: a failure outside the middle half
        return np.where(kept > 0, kept * v, 0.0).sum(axis=1) / (total - 2 * cut)[:, 0]


def performance_profile(
    steps: np.ndarray, success: np.ndarray, genie_steps: np.ndarray, taus: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """The share of episodes solved within ``tau`` x the genie's steps, for each ``tau`` of ``taus`` (Dolan and More's
    performance profile, as rliable draws score distributions): [len(taus)], or [B, len(taus)] under ``weights`` [B, n]
    (bootstrap counts)."""
    ratio = np.where(np.asarray(success, bool), steps / np.maximum(genie_steps, 1), np.inf)
    within = ratio[None, :] <= np.asarray(taus, np.float64)[:, None]  # [taus, n]
    if weights is None:
        return within.mean(axis=1)
    w = np.asarray(weights, np.float64)
    return (w @ within.T) / w.sum(axis=1, keepdims=True)


def _paired(results: dict[str, pd.DataFrame]) -> int:
    """The number of episodes; a ``ValueError`` unless every frame holds the same episodes."""
    if not results:
        raise ValueError("no method to tabulate")
    frames = list(results.values())
    key = ["episode", "view", "start_y", "start_x"]
    first = frames[0][key].reset_index(drop=True)
    for name, df in results.items():
        if not df[key].reset_index(drop=True).equals(first):
            raise ValueError(f"method {name!r} played other episodes than {next(iter(results))!r}: not a paired comparison")
    return len(first)


def _groups(results: dict[str, pd.DataFrame], by_user: bool) -> np.ndarray | None:
    """Each episode's user (``city/user``), or None for the bootstrap of episodes alone."""
    df = next(iter(results.values()))
    return (df["city"].astype(str) + "/" + df["user"].astype(str)).to_numpy() if by_user else None


def _resamples(results: dict[str, pd.DataFrame], n_boot: int, seed: int, by_user: bool) -> tuple[int, np.ndarray]:
    """(episodes, ``resample_counts``) of paired results: the same for the table and the differences of one seed."""
    n = _paired(results)
    return n, resample_counts(_groups(results, by_user), n, n_boot, seed)


def _stats_of(df: pd.DataFrame, weights: np.ndarray) -> dict:
    return weighted_stats(*(df[c].to_numpy() for c in ("steps", "success", "genie_steps")), weights)


def bootstrap_table(
    results: dict[str, pd.DataFrame], *, n_boot: int = 2000, level: float = 0.95, seed: int = 0, by_user: bool = True
) -> pd.DataFrame:
    """One row per method: each statistic with its percentile bootstrap interval (``<stat>_lo``, ``<stat>_hi``).

    ``results`` maps a method name to its ``run_episodes`` frame; all frames must hold the same
    episodes (same ``episode``, ``view``, ``start_y``, ``start_x``), which is checked. ``by_user``:
    resample users, then episodes within them (``resample_counts``); else episodes alone.
    """
    n, counts = _resamples(results, n_boot, seed, by_user)
    return _table(results, counts, len(np.unique(_groups(results, True))), level)


def _table(results: dict[str, pd.DataFrame], counts: np.ndarray, users: int, level: float) -> pd.DataFrame:
    """``bootstrap_table``'s rows under the resamples ``counts`` [B, episodes]."""
    alpha = (1.0 - level) / 2.0
    rows = []
    for name, df in results.items():
        point = _stats_of(df, np.ones((1, counts.shape[1])))
        boot = _stats_of(df, counts)
        row: dict[str, object] = {"method": name, "episodes": counts.shape[1], "users": users}
        for stat in STATS:
            row[stat] = float(point[stat][0])
            lo, hi = np.quantile(boot[stat], [alpha, 1.0 - alpha], method="inverted_cdf")
            row[f"{stat}_lo"], row[f"{stat}_hi"] = float(lo), float(hi)
        rows.append(row)
    return pd.DataFrame(rows)


def pooled(by_city: dict[str, dict[str, pd.DataFrame]]) -> dict[str, pd.DataFrame]:
    """The methods played in every city of ``by_city`` (``{city: {method: run_episodes frame}}``), each with its
    episodes of every city in one frame (in the cities' order: paired across methods)."""
    common = [m for m in next(iter(by_city.values())) if all(m in r for r in by_city.values())]
    return {m: pd.concat([r[m] for r in by_city.values()], ignore_index=True) for m in common}


def aggregate_table(
    by_city: dict[str, dict[str, pd.DataFrame]], *, n_boot: int = 2000, level: float = 0.95, seed: int = 0
) -> pd.DataFrame:
    """``bootstrap_table`` of the methods played in every city, over the episodes of all of them at once, with
    stratified bootstrap intervals (``stratified_counts``: each city's users, then their episodes, resampled within
    the city), as rliable aggregates across tasks: the IQM across test cities is its headline."""
    results = pooled(by_city)
    counts = _stratified(results, n_boot, seed)
    return _table(results, counts, len(np.unique(_groups(results, True))), level).assign(cities=len(by_city))


def _stratified(results: dict[str, pd.DataFrame], n_boot: int, seed: int) -> np.ndarray:
    """``stratified_counts`` of paired results pooled over cities (``pooled``): their cities, then their users."""
    cities = next(iter(results.values()))["city"].astype(str).to_numpy()
    return stratified_counts(cities, _groups(results, True), n_boot, seed)


#: The step ratios (method / genie) at which a performance profile is read: tau from 1 to 10.
PROFILE_TAUS = np.round(np.linspace(1.0, 10.0, 91), 1)


def profile_bands(
    results: dict[str, pd.DataFrame], counts: np.ndarray, taus: np.ndarray = PROFILE_TAUS, level: float = 0.95
) -> dict[str, np.ndarray]:
    """``{method: [3, len(taus)]}``: each method's ``performance_profile`` and its bootstrap interval (rows: value,
    low, high) under the resamples ``counts`` [B, episodes]."""
    alpha = (1.0 - level) / 2.0
    out = {}
    for name, df in results.items():
        args = [df[c].to_numpy() for c in ("steps", "success", "genie_steps")]
        boot = performance_profile(*args, taus, counts)
        lo, hi = np.quantile(boot, [alpha, 1.0 - alpha], axis=0, method="inverted_cdf")
        out[name] = np.stack([performance_profile(*args, taus), lo, hi])
    return out


def profiles(results: dict[str, pd.DataFrame], *, n_boot: int = 2000, seed: int = 0, stratified: bool = False) -> dict:
    """``profile_bands`` of paired ``results`` with the report's resamples (users, then episodes; ``stratified``:
    within each city, for results pooled over cities)."""
    counts = _stratified(results, n_boot, seed) if stratified else _resamples(results, n_boot, seed, True)[1]
    return profile_bands(results, counts)


def difference_table(
    results: dict[str, pd.DataFrame],
    against: list[str],
    *,
    n_boot: int = 2000,
    level: float = 0.95,
    seed: int = 0,
    by_user: bool = True,
) -> pd.DataFrame:
    """Paired differences ``method - reference`` for every method and every reference of ``against`` present in
    ``results``: one row per (method, reference, statistic of ``DIFFERENCE_STATS``) with the difference and its
    interval, from the same resamples as ``bootstrap_table`` (same ``seed``). A median that falls on a failure is
    infinite; a difference involving one is reported as NaN (undefined), with the share of resamples where it is."""
    n, counts = _resamples(results, n_boot, seed, by_user)
    ones = np.ones((1, n))
    alpha = (1.0 - level) / 2.0
    rows = []
    for ref in (r for r in against if r in results):
        ref_point, ref_boot = _stats_of(results[ref], ones), _stats_of(results[ref], counts)
        for name, df in results.items():
            if name == ref:
                continue
            point, boot = _stats_of(df, ones), _stats_of(df, counts)
            for stat in DIFFERENCE_STATS:
                with np.errstate(invalid="ignore"):
                    d = boot[stat] - ref_boot[stat]
                    p = float(point[stat][0] - ref_point[stat][0])
                finite = np.isfinite(d)
                ok = finite.mean() >= 1.0 - alpha and np.isfinite(p)
                lo, hi = np.quantile(d[finite], [alpha, 1.0 - alpha], method="inverted_cdf") if ok else (np.nan, np.nan)
                rows.append(
                    {
                        "method": name,
                        "against": ref,
                        "stat": stat,
                        "difference": p if ok else np.nan,
                        "lo": float(lo),
                        "hi": float(hi),
                        "undefined_share": float(1.0 - finite.mean()),
                    }
                )
    return pd.DataFrame(rows, columns=["method", "against", "stat", "difference", "lo", "hi", "undefined_share"])


def group_tables(
    results: dict[str, pd.DataFrame],
    groups: dict[str, list[str]],
    against: list[str],
    *,
    n_boot: int = 2000,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Methods made of several runs (seeds of one preset): (table, differences).

    A group's statistic is the mean of its runs' (``groups``: name -> the run names of ``results``). Its interval
    resamples three levels: the group's runs with replacement (each group on its own: seeds of two presets are
    unrelated), then users, then episodes within each drawn user (those two paired across all runs, which play
    the same episodes). The table holds one row per group and statistic of ``DIFFERENCE_STATS``: the mean over runs,
    its interval, and the runs' own minimum and maximum; the differences ``group - reference`` for every group and
    each reference group of ``against``, paired in the users and episodes. A median on a failure is infinite; a mean
    or difference involving one is NaN, with the share of resamples where it is."""
    n, counts = _resamples(results, n_boot, seed, True)
    rng = np.random.default_rng([seed, 1])
    alpha = (1.0 - level) / 2.0
    ones = np.ones((1, n))
    point, boot = {}, {}
    for name, runs in groups.items():
        stats = [(_stats_of(results[r], ones), _stats_of(results[r], counts)) for r in runs]
        draws = rng.integers(0, len(runs), size=(n_boot, len(runs)))  # the runs of each replicate
        point[name] = {st: np.array([s[0][st][0] for s in stats]) for st in DIFFERENCE_STATS}
        boot[name] = {
            st: np.stack([s[1][st] for s in stats])[draws, np.arange(n_boot)[:, None]].mean(axis=1) for st in DIFFERENCE_STATS
        }

    def interval(values: np.ndarray, at: float) -> tuple[float, float, float, float]:
        finite = np.isfinite(values)
        ok = finite.mean() >= 1.0 - alpha and np.isfinite(at)
        lo, hi = np.quantile(values[finite], [alpha, 1.0 - alpha], method="inverted_cdf") if ok else (np.nan, np.nan)
        return (at if ok else np.nan), float(lo), float(hi), float(1.0 - finite.mean())

    rows = []
    for name, runs in groups.items():
        for st in DIFFERENCE_STATS:
            value, lo, hi, undefined = interval(boot[name][st], float(point[name][st].mean()))
            rows.append(
                {
                    "group": name,
                    "runs": len(runs),
                    "stat": st,
                    "value": value,
                    "lo": lo,
                    "hi": hi,
                    "run_min": float(point[name][st].min()),
                    "run_max": float(point[name][st].max()),
                    "undefined_share": undefined,
                }
            )
    diffs = []
    for ref in (r for r in against if r in groups):
        for name in groups:
            if name == ref:
                continue
            for st in DIFFERENCE_STATS:
                with np.errstate(invalid="ignore"):
                    d, at = boot[name][st] - boot[ref][st], float(point[name][st].mean() - point[ref][st].mean())
                value, lo, hi, undefined = interval(d, at)
                diffs.append(
                    {
                        "group": name,
                        "against": ref,
                        "stat": st,
                        "difference": value,
                        "lo": lo,
                        "hi": hi,
                        "undefined_share": undefined,
                    }
                )
    return pd.DataFrame(rows), pd.DataFrame(diffs)


def ecdf(df: pd.DataFrame, t_max: int) -> tuple[np.ndarray, np.ndarray]:
    """Share of episodes that reached P_T within ``s`` steps, for ``s = 0 .. t_max``: ``(s [t_max+1], F [t_max+1])``."""
    s = np.arange(t_max + 1)
    reached = np.where(df["success"].to_numpy(), df["steps"].to_numpy(), t_max + 1)
    counts = np.bincount(np.minimum(reached, t_max + 1), minlength=t_max + 2)[: t_max + 1]
    return s, np.cumsum(counts) / max(len(df), 1)

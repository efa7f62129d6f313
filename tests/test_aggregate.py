"""The field's evaluation habits: the interquartile mean (tested against rliable's), performance profiles, the
stratified bootstrap across cities, and the findings a report leads with."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from uavplace.eval.findings import city_findings, paired, ranking
from uavplace.eval.metrics import (
    aggregate_table,
    bootstrap_table,
    performance_profile,
    stratified_counts,
    weighted_iqm,
    weighted_stats,
)
from uavplace.rl.world.stats import episode_stats, interquartile_mean


def test_the_iqm_is_rliables():
    rliable = pytest.importorskip("rliable.metrics")
    rng = np.random.default_rng(0)
    for n in (4, 7, 100, 1001):
        x = rng.gamma(2.0, 3.0, size=n)
        assert interquartile_mean(x) == pytest.approx(rliable.aggregate_iqm(x[:, None]), rel=1e-12)
        counts = rng.integers(0, 4, size=(3, n))
        counts[:, 0] += 1  # never an empty sample
        for row, iqm in zip(counts, weighted_iqm(x, counts), strict=True):  # as if each value were drawn row[i] times
            assert iqm == pytest.approx(rliable.aggregate_iqm(np.repeat(x, row)[:, None]), rel=1e-12)


def test_the_iqm_of_steps_is_infinite_once_over_a_quarter_fail():
    steps, genie = np.full(8, 10), np.full(8, 5)
    ok = np.ones(8, bool)
    ok[:2] = False  # a quarter: cut from the top
    assert episode_stats(steps, ok, genie)["iqm_over_genie"] == 2.0
    ok[2] = False
    assert np.isinf(episode_stats(steps, ok, genie)["iqm_over_genie"])
    assert episode_stats(steps, ok, genie)["iqm_spl"] == 0.375  # the middle half of 0, 0, 0, 0.5 x 5: 0, 0.5, 0.5, 0.5


def test_the_weighted_statistics_are_the_plain_ones_of_the_expanded_sample():
    rng = np.random.default_rng(1)
    n = 50
    steps, genie = rng.integers(1, 60, n), rng.integers(1, 20, n)
    ok = rng.random(n) < 0.9
    counts = rng.multinomial(n, np.full(n, 1 / n), size=4)
    weighted = weighted_stats(steps, ok, genie, counts)
    for b, row in enumerate(counts):
        plain = episode_stats(*(np.repeat(a, row) for a in (steps, ok, genie)))
        for stat in ("iqm_over_genie", "iqm_spl", "spl", "success"):
            assert weighted[stat][b] == pytest.approx(plain[stat], rel=1e-12), stat


def test_a_performance_profile_counts_the_episodes_within_tau_of_the_genie():
    steps, genie, ok = np.array([2, 4, 10, 3]), np.array([2, 2, 2, 1]), np.array([True, True, False, True])
    taus = np.array([1.0, 2.0, 3.0, 10.0])
    assert performance_profile(steps, ok, genie, taus).tolist() == [0.25, 0.5, 0.75, 0.75]  # a failure never counts
    counts = np.array([[2, 0, 1, 1], [0, 0, 4, 0]])
    assert performance_profile(steps, ok, genie, taus, counts).tolist() == [[0.5, 0.5, 0.75, 0.75], [0, 0, 0, 0]]


def test_the_stratified_bootstrap_resamples_within_each_city():
    strata = np.array(["a"] * 30 + ["b"] * 10)
    users = np.array([f"{c}/{i % 5}" for i, c in enumerate(strata)])
    counts = stratified_counts(strata, users, n_boot=300, seed=3)
    assert (counts[:, :30].sum(axis=1) == 30).all() and (counts[:, 30:].sum(axis=1) == 10).all()
    assert (counts[:, :30].std(axis=0) > 0).all()  # resampled, not copied
    assert np.array_equal(counts, stratified_counts(strata, users, n_boot=300, seed=3))


def _frame(city: str, steps: np.ndarray, ok: np.ndarray, genie: np.ndarray) -> pd.DataFrame:
    n = len(steps)
    return pd.DataFrame({"episode": np.arange(n), "view": 0, "start_y": 0, "start_x": 0, "city": city,
                         "user": np.arange(n) % 5, "steps": steps, "success": ok, "genie_steps": genie})  # fmt: skip


def test_the_aggregate_pools_the_cities_and_keeps_their_weights():
    rng = np.random.default_rng(2)
    by_city = {}
    for city, n in (("a", 40), ("b", 20)):
        genie = rng.integers(1, 10, n)
        by_city[city] = {"genie": _frame(city, genie, np.ones(n, bool), genie),
                         "m": _frame(city, genie * 2, rng.random(n) < 0.8, genie)}  # fmt: skip
    agg = aggregate_table(by_city, n_boot=500, seed=0).set_index("method")
    pooled = {m: pd.concat([by_city[c][m] for c in by_city], ignore_index=True) for m in ("genie", "m")}
    plain = bootstrap_table(pooled, n_boot=10, seed=0).set_index("method")  # its points are the pooled statistics
    for stat in ("success", "iqm_over_genie", "iqm_spl", "spl"):
        assert agg.loc["m", stat] == plain.loc["m", stat]
        assert agg.loc["m", f"{stat}_lo"] <= agg.loc["m", stat] <= agg.loc["m", f"{stat}_hi"]
    assert agg.loc["genie", "iqm_over_genie"] == 1.0 and (agg["episodes"] == 60).all() and (agg["cities"] == 2).all()


def test_the_findings_name_the_leader_its_margin_and_the_maps_cost():
    names = ["a", "genie", "b", "b, no buildings"]
    table = pd.DataFrame({"method": names, "success": [0.9, 1.0, 0.95, 0.7], "medians_ratio": [2.0, 1.0, 3.0, 5.0],
                          "spl": [0.5, 1.0, 0.4, 0.2], "iqm_over_genie": [2.0, 1.0, 3.0, 6.0]})  # fmt: skip
    assert ranking(table) == ["b", "a"]  # success first; the genie and the ablations are not contenders
    diff = pd.DataFrame([
        {"method": "a", "against": "b", "stat": "success", "difference": -0.05, "lo": -0.08, "hi": -0.01, "undefined_share": 0},
        {"method": "a", "against": "b", "stat": "median_steps", "difference": -4.0, "lo": -6.0, "hi": -1.0, "undefined_share": 0},
        {"method": "b, no buildings", "against": "the same with buildings", "stat": "success", "difference": -0.25,
         "lo": -0.3, "hi": -0.2, "undefined_share": 0},
        {"method": "b, no buildings", "against": "the same with buildings", "stat": "median_steps", "difference": 9.0,
         "lo": 4.0, "hi": 15.0, "undefined_share": 0},
    ])  # fmt: skip
    mirrored = paired(diff, "b", "a")
    assert (mirrored["success"]["difference"], mirrored["success"]["lo"], mirrored["success"]["hi"]) == (0.05, 0.01, 0.08)
    lead, margin, cost = city_findings(table, diff, t_max=500)
    assert lead.startswith("b leads: 95.0 % of the episodes reach P_T, at 3.00 x the genie's median steps")
    assert margin == "Against the next, a, paired: +5.0 points [+1.0, +8.0] of success and +4 [+1, +6] median steps."
    assert cost.startswith("Shown no building, b changes by -25.0 points [-30.0, -20.0]") and "the map matters" in cost

"""The evaluation protocol and `uavrl report`: metrics on hand-made episodes, and a report made end to end."""

from __future__ import annotations

import json
import re

import click
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from tests.conftest import REPO, write_grid_city
from uavplace.cli import uavrl
from uavplace.dataset.build import build_city
from uavplace.eval.metrics import bootstrap_table, difference_table, ecdf, format_stat, group_tables
from uavplace.ingest.pipeline import ingest_city
from uavplace.rl.agent.config import preset_config
from uavplace.rl.agent.train import Trainer
from uavplace.rl.world.stats import summarise
from uavplace.schemas.bundle import BuildConfig


def episodes(steps, success, genie=None, user=None) -> pd.DataFrame:
    """A ``run_episodes`` frame; every episode its own user unless ``user`` says."""
    n = len(steps)
    return pd.DataFrame(
        {
            "episode": np.arange(n),
            "city": "c",
            "user": np.arange(n) if user is None else np.asarray(user),
            "view": np.zeros(n, np.int64),
            "start_y": np.arange(n),
            "start_x": np.arange(n),
            "steps": np.asarray(steps),
            "success": np.asarray(success, bool),
            "genie_steps": np.ones(n, np.int64) if genie is None else np.asarray(genie),
        }
    )


def test_median_counts_failures_as_beyond_t_max():
    # 5 episodes: 3 successes in 2, 4, 6 steps and 2 failures (played to t_max = 10).
    df = episodes([2, 4, 6, 10, 10], [1, 1, 1, 0, 0], genie=[1, 2, 2, 1, 1])
    table = bootstrap_table({"m": df}, n_boot=200)
    row = table.iloc[0]
    assert row["success"] == pytest.approx(0.6)
    assert row["median_steps"] == 6  # order statistic 3 of 5: the failures sit above every success
    assert row["mean_steps_success"] == pytest.approx(4.0)
    assert row["p75_steps"] == np.inf  # order statistic 4 of 5: a failure
    assert row["within_100"] == pytest.approx(0.6)
    assert row["steps_over_genie"] == 3.0  # ratios 2, 2, 3, inf, inf
    assert row["medians_ratio"] == 6.0  # median steps 6 over the genie's median 1 (genie steps 1, 2, 2, 1, 1)
    assert format_stat("medians_ratio", np.inf, 2.0, np.inf) == "inf (median a failure) [2.00, inf]"
    assert summarise(df) == pytest.approx({k: row[k] for k in summarise(df)})
    # With failures in the majority the median is past t_max (at exactly half, it is the last success).
    assert bootstrap_table({"m": episodes([2, 4, 6, 10, 10, 10], [1, 1, 1, 0, 0, 0])}, n_boot=200).iloc[0]["median_steps"] == 6
    worse = episodes([2, 4, 6, 10, 10, 10, 10], [1, 1, 1, 0, 0, 0, 0])
    assert bootstrap_table({"m": worse}, n_boot=200).iloc[0]["median_steps"] == np.inf
    assert format_stat("median_steps", np.inf) == "> t_max" and format_stat("success", 0.6, 0.2, 1.0) == "60.0 % [20.0, 100.0 %]"
    long = episodes([50, 100, 101, 300, 500], [1, 1, 1, 1, 0], genie=[5] * 5)
    row = bootstrap_table({"m": long}, n_boot=200).iloc[0]
    assert row["within_100"] == pytest.approx(0.4) and row["p75_steps"] == 300 and format_stat("within_100", 0.4) == "40.0 %"


def test_ecdf_of_known_steps():
    df = episodes([1, 1, 3, 5, 5], [1, 1, 1, 1, 0])
    s, f = ecdf(df, t_max=5)
    np.testing.assert_array_equal(s, np.arange(6))
    np.testing.assert_allclose(f, [0, 0.4, 0.4, 0.6, 0.6, 0.8])  # the failure never counts


def test_bootstrap_interval_covers_a_known_rate():
    rng = np.random.default_rng(3)
    n, p = 1000, 0.7
    ok = rng.random(n) < p
    table = bootstrap_table({"m": episodes(np.where(ok, 5, 500), ok)}, n_boot=2000, seed=1)
    lo, hi = table.iloc[0][["success_lo", "success_hi"]]
    half = 1.96 * np.sqrt(p * (1 - p) / n)
    assert lo < ok.mean() < hi and hi - lo == pytest.approx(2 * half, rel=0.15)
    again = bootstrap_table({"m": episodes(np.where(ok, 5, 500), ok)}, n_boot=2000, seed=1)
    pd.testing.assert_frame_equal(table, again)


def test_user_level_intervals_are_wider_when_users_differ():
    """20 users of 50 episodes each, every user with a success rate of its own: resampling users, then episodes, gives
    an interval about as wide as 20 independent draws allow; resampling episodes alone, one as narrow as 1000 would."""
    rng = np.random.default_rng(5)
    rate = rng.beta(2, 2, size=20)
    user = np.repeat(np.arange(20), 50)
    ok = rng.random(1000) < rate[user]
    df = episodes(np.where(ok, 5, 500), ok, user=user)
    two = bootstrap_table({"m": df}, n_boot=2000, seed=1).iloc[0]
    flat = bootstrap_table({"m": df}, n_boot=2000, seed=1, by_user=False).iloc[0]
    wide, narrow = two["success_hi"] - two["success_lo"], flat["success_hi"] - flat["success_lo"]
    assert two["users"] == 20 and wide > 2 * narrow
    expected = 2 * 1.96 * np.sqrt(np.var(rate[user].reshape(20, 50).mean(axis=1)) / 20 + ok.mean() * (1 - ok.mean()) / 1000)
    assert wide == pytest.approx(expected, rel=0.3)


def test_paired_differences_recover_a_known_difference():
    """B fails exactly where A fails and in 10 % more of the episodes: success differs by the known -0.1 with a narrow
    interval that excludes 0 (paired: the shared failures cancel); median steps 10 against 20 differ by exactly 10."""
    rng = np.random.default_rng(7)
    n = 1000
    user = np.repeat(np.arange(25), 40)
    a_ok = rng.random(n) < 0.8
    b_ok = a_ok & ~np.isin(np.arange(n), rng.choice(np.flatnonzero(a_ok), size=100, replace=False))
    a = episodes(np.where(a_ok, 10, 500), a_ok, user=user)
    b = episodes(np.where(b_ok, 20, 500), b_ok, user=user)
    diff = difference_table({"a": a, "b": b}, against=["a", "missing"], n_boot=2000, seed=2)
    assert set(diff["against"]) == {"a"} and set(diff["method"]) == {"b"}
    success = diff[diff.stat == "success"].iloc[0]
    assert success["difference"] == pytest.approx(-0.1)
    assert success["lo"] < -0.1 < success["hi"] < 0 and success["hi"] - success["lo"] < 0.05
    steps = diff[diff.stat == "median_steps"].iloc[0]
    assert (steps["difference"], steps["lo"], steps["hi"]) == (10, 10, 10)
    worse = episodes(np.where(a_ok & (rng.random(n) < 0.3), 20, 500), a_ok & (rng.random(n) < 0.3), user=user)
    undefined = difference_table({"a": a, "w": worse}, against=["a"], n_boot=200).set_index("stat").loc["median_steps"]
    assert np.isnan(undefined["difference"]) and undefined["undefined_share"] == 1.0  # w's median is a failure


def test_groups_of_seeds_average_their_runs_and_resample_them():
    """Preset A's three seeds succeed in 90, 80 and 70 % of the same 1000 episodes, preset B's three in 50 %: A is
    80 % with its seeds' range 70-90 % and an interval wider than any one seed's (the seeds differ), and A - B is the
    known +0.3, its interval excluding 0. One seed alone has no seed variation: its interval is the user-level one."""
    rng = np.random.default_rng(11)
    n, user = 1000, np.repeat(np.arange(25), 40)
    u = rng.random(n)
    runs = {f"a{k}": u < rate for k, rate in enumerate((0.9, 0.8, 0.7))} | {f"b{k}": u < 0.5 for k in range(3)}
    results = {name: episodes(np.where(ok, 10, 500), ok, user=user) for name, ok in runs.items()}
    groups = {"A": ["a0", "a1", "a2"], "B": ["b0", "b1", "b2"], "A0": ["a0"]}
    table, diffs = group_tables(results, groups, against=["B"], n_boot=2000, seed=3)
    a = table[(table.group == "A") & (table.stat == "success")].iloc[0]
    assert a["value"] == pytest.approx(np.mean([(u < r).mean() for r in (0.9, 0.8, 0.7)]))
    assert (a["run_min"], a["run_max"]) == ((u < 0.7).mean(), (u < 0.9).mean()) and a["runs"] == 3
    one = table[(table.group == "A0") & (table.stat == "success")].iloc[0]
    assert a["hi"] - a["lo"] > one["hi"] - one["lo"]
    d = diffs[(diffs.group == "A") & (diffs.stat == "success")].iloc[0]
    assert d["against"] == "B" and d["difference"] == pytest.approx((u < 0.8).mean() - (u < 0.5).mean(), abs=0.02)
    assert 0 < d["lo"] < d["difference"] < d["hi"]
    steps = diffs[(diffs.group == "A") & (diffs.stat == "median_steps")].iloc[0]
    assert np.isnan(steps["difference"]) or steps["difference"] <= 0  # B's median is a failure: undefined


def test_bootstrap_refuses_unpaired_methods():
    a = episodes([1, 2, 3], [1, 1, 1])
    b = a.assign(start_x=[0, 1, 9])
    with pytest.raises(ValueError, match="other episodes"):
        bootstrap_table({"a": a, "b": b})


@pytest.fixture(scope="module")
def two_cities(tmp_path_factory):
    """A training city and a test city (different seeds), built; an agent trained a few hundred steps in the first."""
    tmp = tmp_path_factory.mktemp("eval")
    root = tmp / "p"
    for name, seed, role in (("citya", 5, "train"), ("cityb", 6, "test"), ("cityc", 7, "test")):
        ingest_city(write_grid_city(tmp / "raw" / name, nx=14, ny=12, n_tx=3, outputs=("power",), seed=seed), root, name=name)
        build_city(
            name,
            BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-58.0, role=role, val_users=1 if role == "train" else 0),
            root,
        )
    config = preset_config(
        "best", total_steps=256, num_envs=8, buffer_size=512, batch_size=16, train_every=4, learning_starts=64,
        eval_every=128, eval_episodes=8, hidden=16, env={"t_max": 30, "rotate": True},
    )  # fmt: skip
    Trainer(config, ["citya"], root, tmp / "runs" / "a").run()
    return root, tmp / "runs" / "a"


def test_report_end_to_end(tmp_path, two_cities):
    root, run = two_cities
    out = tmp_path / "report"
    args = ["report", "--run", str(run), "--dataset", "cityb", "--root", str(root), "--out", str(out)]
    res = CliRunner().invoke(uavrl, [*args, "--episodes", "60", "--t-max", "40", "--bootstrap", "200", "--quiet"])
    assert res.exit_code == 0, res.output
    assert "report.html" in res.output and "genie" in res.output
    page = (out / "report.html").read_text()
    assert page.count('src="data:image/png;base64,') == 4  # CDF, performance profiles, training curves, trajectories
    assert page.count("<figcaption>") == 4 and "<details>" in page and "Provenance" in page
    assert (out / "profile.png").is_file() and "Performance profiles in cityb" in page
    # The page leads with what it found: the leader by the table's own ranking, then the headline table, then details
    table = pd.read_csv(out / "results.csv")
    rivals = table[(table.method != "genie") & ~table.method.str.endswith(", no buildings")]
    lead = rivals.sort_values(["success", "medians_ratio", "spl"], ascending=[False, True, False]).method.iloc[0]
    found = page.index("What it found")
    assert found < page.index(f"<li>{lead} leads: ") < page.index("IQM of SPL") < page.index('<section id="cityb">')
    assert "median steps" in page and "p75 steps" in page and "100 % (genie)" in page
    assert "90 % (proposed)" not in page  # the paper's numbers stand beside the paper's agents only, not ours
    for text in ("PQN + GRU (best)", "genie", "steered random walk", "greedy hill-climbing", "paper: success", "cityb", "citya"):
        assert text in page
    table = pd.read_csv(out / "results.csv")
    assert list(table["method"]) == ["PQN + GRU (best)", "genie", "steered random walk", "greedy hill-climbing", "map searcher",
                                     "map searcher, no buildings", "PQN + GRU (best), no buildings"]  # fmt: skip
    diffs = pd.read_csv(out / "differences.csv")  # the map ablation's cost, paired, for the agent and the searcher
    ablation = diffs[diffs.against == "the same with buildings"]
    assert set(ablation["method"]) == {"PQN + GRU (best), no buildings", "map searcher, no buildings"}
    assert "success - the same with buildings" in page
    assert table.loc[table.method == "genie", "success"].item() == 1.0
    assert (table["success_lo"] <= table["success"]).all() and (table["success"] <= table["success_hi"]).all()
    eps = pd.read_parquet(out / "episodes.parquet")
    starts = {m: g[["episode", "view", "start_y", "start_x", "genie_steps"]].to_numpy() for m, g in eps.groupby("method")}
    first = next(iter(starts.values()))
    assert len(first) == 60 and all(np.array_equal(first, s) for s in starts.values())  # identical episodes
    wide = eps.pivot(index="episode", columns="method", values="steps")
    ok = eps.pivot(index="episode", columns="method", values="success")
    assert ok["genie"].all() and (wide["genie"] == eps[eps.method == "genie"].set_index("episode")["genie_steps"]).all()
    for m in wide.columns:  # the genie is never slower than any method on any episode it finished
        assert (wide["genie"][ok[m]] <= wide[m][ok[m]]).all(), m
    doc = json.loads((out / "report.json").read_text())
    assert doc["test_bundle"] and set(doc["agents"]["PQN + GRU (best)"]["trained_on"]) == {"citya"}
    assert doc["report_config"]["episodes"] == 60 and "upper_bounds_db" in doc
    assert doc["torch"]["threads"] >= 1 and doc["torch"]["version"]
    # where the test city's values came from (an InSite-like export: every reached receiver ray-traced), in the page too
    cells = doc["test_bundle_cells"]
    assert set(cells) == {"unreached", "ray-traced"} and f"{sum(cells.values()):,} user-cells outside buildings" in page
    # The searcher's trajectories (what the page leads with), by the stated rule: the success nearest the median, the
    # successes' p90, a failure.
    assert doc["trajectories"]["agent"] == "map searcher" and re.search(r"map searcher: \d+ of its 60 episodes in cityb", page)
    shown = eps[eps.method == "map searcher"].set_index("episode")
    picks = dict(zip(doc["trajectories"]["rules"], doc["trajectories"]["episodes"], strict=True))
    ok = shown[shown.success]
    median = np.quantile(np.where(shown.success, shown.steps, np.inf), 0.5, method="inverted_cdf")
    median = median if np.isfinite(median) else ok.steps.max()
    assert abs(shown.steps[picks["median"]] - median) == (ok.steps - median).abs().min()
    if "failure" in picks:
        assert not shown.success[picks["failure"]]
    assert doc["agents"]["PQN + GRU (best)"]["commands"] == [json.loads((run / "run.json").read_text())["command"]]
    # The same command again gives the same table (seeded episodes, agent moves and bootstrap).
    res = CliRunner().invoke(uavrl, [*args, "--episodes", "60", "--t-max", "40", "--bootstrap", "200", "--quiet"])
    pd.testing.assert_frame_equal(table, pd.read_csv(out / "results.csv"))


def test_report_groups_runs_as_one_preset(tmp_path, two_cities):
    """`--group best=A,B` plays both runs and reports them as one method: the mean over the runs, their range, an
    interval over runs, users and episodes, differences against the genie; groups.csv and the page hold it."""
    import shutil

    root, run = two_cities
    twin = tmp_path / "twin"
    shutil.copytree(run, twin)  # the same weights under another folder: a group whose runs agree exactly
    out = tmp_path / "report"
    args = ["report", "--dataset", "cityb", "--root", str(root), "--out", str(out), "--episodes", "40", "--t-max", "40",
            "--bootstrap", "200", "--quiet", "--trajectories", "0", "--group", f"best={run},{twin}"]  # fmt: skip
    res = CliRunner().invoke(uavrl, args)
    assert res.exit_code == 0, res.output
    assert "groups of runs in cityb" in res.output
    groups = pd.read_csv(out / "groups.csv")
    best = groups[(groups.table == "group") & (groups.group == "best") & (groups.stat == "success")].iloc[0]
    assert best["runs"] == 2 and best["run_min"] == best["run_max"] == best["value"]
    assert ((groups.table == "difference") & (groups.group == "best") & (groups.against == "genie")).sum() == 2
    page = (out / "report.html").read_text()
    assert "Presets as groups of runs" in page and json.loads((out / "report.json").read_text())["groups"]["best"]


def test_report_on_several_cities(tmp_path, two_cities):
    """One report folder per test city under --out, then one summary line per method across the cities."""
    root, run = two_cities
    args = ["report", "--run", str(run), "--dataset", "cityb", "--dataset", "cityc", "--root", str(root)]
    md = tmp_path / "tables.md"
    res = CliRunner().invoke(uavrl, [*args, "--out", str(tmp_path / "r"), "--episodes", "20", "--t-max", "30", "--quiet",
                                     "--markdown", str(md)])  # fmt: skip
    assert res.exit_code == 0, res.output
    text = md.read_text()  # the tables the command printed, as Markdown: a README copies them, never retypes them
    # led by what it found over both cities (stratified intervals), then the summary, then each city's tables
    assert text.startswith("- ") and "over the 40 episodes of the 2 cities" in text
    assert text.index("| method | cityb: success") < text.index("**cityb** (20 episodes") < text.index("**cityc** (20 episodes")
    assert "Paired differences in cityb, method minus reference" in text and "| genie | 100.0 % [100.0, 100.0 %]" in text
    for city in ("cityb", "cityc"):
        doc = json.loads((tmp_path / "r" / city / "report.json").read_text())
        assert doc["report_config"]["dataset"] == city
    assert "cityb: success / median steps" in res.output and "cityc: success / median steps" in res.output
    summary = res.output[res.output.index("cityb: success / median steps") :]
    assert "genie" in summary and "100.0 %" in summary
    page = (tmp_path / "r" / "report.html").read_text()  # one page: what it found, the summary, a section per city
    assert (
        page.index("What it found")
        < page.index("Summary")
        < page.index('<section id="cityb">')
        < page.index('<section id="cityc">')
    )
    # the pooled profiles, the training once, then CDF, profiles and trajectories per city
    assert page.count("<figcaption>") == 8 and "Figure 8." in page and (tmp_path / "r" / "profile.png").is_file()
    summary_csv = pd.read_csv(tmp_path / "r" / "summary.csv")
    assert list(summary_csv.columns[:7]) == ["city", "method", "episodes", "users", "success", "success_lo", "success_hi"]
    assert sorted(set(summary_csv.city)) == ["cityb", "cityc"] and (summary_csv.episodes == 20).all()
    genie_rows = summary_csv[summary_csv.method == "genie"]
    assert (genie_rows.success == 1.0).all() and genie_rows.success_minus_genie.isna().all()
    others = summary_csv[summary_csv.method != "genie"]
    assert others.success_minus_genie.notna().all() and (others.success_minus_genie <= 0).all()
    assert summary_csv.select_dtypes("number").shape[1] == summary_csv.shape[1] - 2  # numbers, but for city and method
    assert "Paired differences, method minus reference" in page and "resample the" in page
    # A page of the user's own under --out is never replaced, and the refusal comes before any episode.
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "report.html").write_text("my notes")
    res = CliRunner().invoke(uavrl, [*args, "--out", str(mine), "--episodes", "20", "--quiet"])
    assert res.exit_code == 2 and "not a uavplace report" in res.output
    assert sorted(p.name for p in mine.iterdir()) == ["report.html"] and (mine / "report.html").read_text() == "my notes"


def test_an_agent_of_another_window_plays_the_same_episodes(tmp_path, two_cities):
    """Canvas coordinates depend on the window (its pad); an agent trained with a 21-cell window starts each
    episode on the very cells the genie and a 61-cell agent start on (same map cell, same genie distance)."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.eval.evaluate import ReportConfig, evaluate, load_agent

    root, run = two_cities
    config = preset_config(
        "best", total_steps=128, num_envs=8, buffer_size=256, batch_size=16, train_every=4, learning_starts=64,
        eval_every=128, eval_episodes=8, hidden=16, fovea=7, env={"t_max": 30, "rotate": True, "window": 21},
    )  # fmt: skip
    Trainer(config, ["citya"], root, tmp_path / "narrow").run()
    agents = [load_agent(run, 0.096, 0), load_agent(tmp_path / "narrow", 0.096, 0)]
    agents[1].name = agents[1].policy.name = "narrow"
    results = evaluate(ReportConfig(dataset="cityb", episodes=40, t_max=30), load_bundle("cityb", root=root), agents)
    key = ["episode", "view", "start_y", "start_x", "genie_steps"]
    genie = results["genie"][key].to_numpy()
    for name in ("PQN + GRU (best)", "narrow"):
        np.testing.assert_array_equal(results[name][key].to_numpy(), genie, err_msg=name)


def test_twin_cities_play_the_same_episodes_where_both_can_start(two_cities):
    """Episodes drawn on one city and kept where another of the same grid and users ``can_start`` them play from the
    same cells in both (``evaluate(episodes=...)``, the exact-path twin's benchmark); one that cannot start is refused."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.eval.evaluate import ReportConfig, evaluate
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.policies import GeniePolicy
    from uavplace.rl.world.maps import MapSet

    root, _ = two_cities
    b, c = load_bundle("cityb", root=root), load_bundle("cityc", root=root)
    base = EnvConfig(t_max=30, rotate=False)
    maps_b, maps_c = MapSet([b], base), MapSet([c], base)
    draw = maps_b.sample_episodes(200, np.random.default_rng(0))
    assert maps_b.can_start(draw).all()
    ok = maps_c.can_start(draw)
    assert 0 < ok.sum() < len(draw)  # other maps: some starts are not start cells there
    config = ReportConfig(dataset="cityb", episodes=40, t_max=30)
    key = ["episode", "view", "start_y", "start_x"]
    kept = draw[ok][:40]
    frames = [evaluate(config, bundle, [], baselines=[GeniePolicy()], episodes=kept)["genie"] for bundle in (b, c)]
    np.testing.assert_array_equal(frames[0][key].to_numpy(), frames[1][key].to_numpy())
    assert len(frames[0]) == len(kept)
    with pytest.raises(ValueError, match="does not start"):
        evaluate(config, c, [], baselines=[GeniePolicy()], episodes=draw[~ok][:1])


def test_report_refuses_the_training_city(tmp_path, two_cities):
    root, run = two_cities
    res = CliRunner().invoke(uavrl, ["report", "--run", str(run), "--dataset", "citya", "--root", str(root), "--out", str(tmp_path / "r"),
                                     "--episodes", "5", "--quiet"])  # fmt: skip
    assert res.exit_code == 2 and "trained in citya" in res.output and not (tmp_path / "r").exists()


def test_trajectories_are_picked_by_the_stated_rule():
    from uavplace.eval.figures import pick_trajectories

    # 10 episodes: successes in 5, 9, 12, 20, 30, 40, 60 steps and 3 failures; median steps to P_T (failures
    # infinite) is the 5th order statistic, 30; the successes' 90th percentile is their 7th, 60.
    df = episodes([5, 9, 12, 20, 30, 40, 60, 500, 500, 500], [1, 1, 1, 1, 1, 1, 1, 0, 0, 0])
    df = df.assign(success=df["success"].astype(bool))
    assert pick_trajectories({"a": df}, "a", 3) == [(4, "median"), (6, "p90"), (7, "failure")]
    assert pick_trajectories({"a": df}, "a", 1) == [(4, "median")]
    never = df.assign(success=False)
    assert pick_trajectories({"a": never}, "a", 3) == [(0, "failure")]
    always = df.assign(success=True, steps=[5, 9, 12, 20, 30, 40, 60, 70, 80, 90])
    # median 30 (episode 4), p90 80 (episode 8), no failure: the longest success (episode 9).
    assert pick_trajectories({"a": always}, "a", 3) == [(4, "median"), (8, "p90"), (9, "longest success")]


def test_development_scripts_see_validation_cities_and_test_cities_only_for_a_release(tmp_path):
    """``development_cities``: every built validation city by default; a test city refused without ``release``."""
    from tests.conftest import write_grid_city
    from uavplace.dataset.build import build_city
    from uavplace.eval.cities import development_cities
    from uavplace.ingest.pipeline import ingest_city
    from uavplace.schemas import InputError
    from uavplace.schemas.bundle import BuildConfig

    root = tmp_path / "p"
    for name, role in (("va", "val"), ("vb", "val"), ("te", "test"), ("tr", "train")):
        ingest_city(write_grid_city(tmp_path / name, nx=8, ny=6, n_tx=2, outputs=("power",), seed=1), root, name=name)
        build_city(name, BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-58.0, role=role), root)
    assert development_cities(None, root) == ["va", "vb"]
    assert development_cities(["tr", "va"], root) == ["tr", "va"]
    with pytest.raises(InputError, match="te: city: is a test city.*--release"):
        development_cities(["va", "te"], root)
    assert development_cities(["te"], root, release=True) == ["te"]


def test_training_curves_order_episodes_by_their_start():
    """One env, t_max 10: a failure begun at step 0 ends at 10, after quick successes begun at 1-5. Ordered by start it
    comes first (by end, the curve would open on successes only); episodes begun in the last t_max steps are left out."""
    from uavplace.eval.figures import by_episode_start

    metrics = pd.DataFrame({"step": [2, 3, 4, 5, 6, 10, 25, 30], "length": [1, 1, 1, 1, 1, 10, 2, 1],
                            "success": [True] * 5 + [False, True, True]})  # fmt: skip
    out = by_episode_start(metrics, num_envs=1, t_max=10)
    assert out["start"].tolist() == [0, 1, 2, 3, 4, 5] and not out["success"].iloc[0]  # 23 and 29 begin after 30 - 10


def test_a_default_build_is_what_the_shipped_agents_expect_and_another_is_named(tiny, tmp_path):
    """Every shipped agent records the settings of its training bundles, which a default build has; a report names
    a bundle of another noise level, or another P_T, in one line per city naming the agents (the page's findings
    too), and refuses it with --strict."""
    import shutil

    from click.testing import CliRunner

    from uavplace.cli import uavrl
    from uavplace.dataset.build import build_city
    from uavplace.eval.evaluate import unlike_training
    from uavplace.rl.agent.runs import read_run_json
    from uavplace.schemas.bundle import BuildConfig

    agents = sorted(p.parent for p in (REPO / "data" / "agents").glob("*/run.json"))
    assert len(agents) >= 5
    default = BuildConfig(grid_m=4.0, altitude_m=10.0)
    for folder in agents:
        settings = read_run_json(folder).bundle_settings
        assert settings and {s.noise_dbm for s in settings.values()} == {default.noise_dbm}, folder.name
    best = REPO / "data" / "agents" / "best"
    assert unlike_training(agents, ["tiny"], tiny, 5.0) == []

    root = tmp_path / "processed"
    shutil.copytree(tiny, root)
    other = build_city("tiny", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-104.0), root).path.name
    lines = unlike_training([best], [f"tiny@{other}"], root, 5.0)
    assert lines == [f"best on tiny@{other}: noise -104 dBm (trained at -75 dBm): the agent plays outside what it was "
                     "trained on"]  # fmt: skip
    assert unlike_training([best], ["tiny@" + other], root, 3.0)[0].count("; P_T 3 dB (trained at 5 dB)") == 1
    res = CliRunner().invoke(uavrl, ["report", "--dataset", f"tiny@{other}", "--root", str(root), "--run", str(best),
                                     "--out", str(tmp_path / "r"), "--strict", "--quiet"])  # fmt: skip
    assert res.exit_code == 2 and "noise -104 dBm (trained at -75 dBm)" in res.output and not (tmp_path / "r").exists()
    # several agents alike: one line naming them all; without --strict the page's findings say it too
    (line,) = unlike_training([best, REPO / "data" / "agents" / "blind"], [f"tiny@{other}"], root, 5.0)
    assert line.startswith(f"best and blind on tiny@{other}: noise -104 dBm") and "the agents play" in line
    res = CliRunner().invoke(uavrl, ["report", "--dataset", f"tiny@{other}", "--root", str(root), "--run", str(best),
                                     "--out", str(tmp_path / "r"), "--episodes", "2", "--bootstrap", "100", "--quiet"])  # fmt: skip
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r" / "report.html").read_text(encoding="utf-8")
    assert f"Caution: best on tiny@{other}: noise -104 dBm (trained at -75 dBm)" in page


def test_evaluations_over_the_step_limit_are_refused_before_any_work(tiny):
    """The limits bound the product that costs time and memory (episodes x step budget), not only each factor."""
    from click.testing import CliRunner

    from uavplace.cli import uavrl

    for args in (
        ["report", "--dataset", "tiny", "--episodes", "1000000"],
        ["report", "--task", "tracking", "--dataset", "tiny", "--horizon", "100000"],
        ["report", "--task", "fleet", "--dataset", "tiny", "--episodes", "200000"],
        ["baselines", "--dataset", "tiny", "--episodes", "1000000"],
    ):
        res = CliRunner().invoke(
            uavrl, [*args, "--root", str(tiny), "--quiet"] if args[0] == "report" else [*args, "--root", str(tiny)]
        )
        assert res.exit_code == 2 and "over the limit episode_steps" in res.output, (args, res.output)


def test_a_terminal_gets_the_columns_that_fit():
    from uavplace.eval.reports.placement import TERMINAL_COLUMNS, terminal_columns
    from uavplace.rl.world.stats import STATS

    header = ["method", *STATS.values(), "paper: success", "paper: median steps"]
    rows = terminal_columns([header, [f"m{i}" for i in range(len(header))]])
    assert rows[0] == list(TERMINAL_COLUMNS) and rows[1] == ["m0", "m1", "m2", "m5"]


def test_shipped_agents_and_predictor_are_found_from_any_working_folder(tiny, tmp_path, monkeypatch):
    """`uavrl report` run from a folder that is not the repository finds the shipped agents and predictor (the
    project's data/agents, not the working folder's); a predictor path that does not exist says where they are."""
    from uavplace.rl.config import DEFAULT_PREDICTOR
    from uavplace.rl.predictor import load_predictor
    from uavplace.schemas import InputError

    monkeypatch.chdir(tmp_path)
    args = ["report", "--dataset", "tiny", "--root", str(tiny), "--episodes", "4", "--bootstrap", "100", "--out",
            str(tmp_path / "rep"), "--quiet"]  # fmt: skip
    res = CliRunner().invoke(uavrl, args)
    assert res.exit_code == 0, res.output
    methods = pd.read_csv(tmp_path / "rep" / "results.csv")["method"].tolist()
    assert "map searcher" in methods and any("(best)" in m for m in methods)
    with pytest.raises(InputError, match=str(DEFAULT_PREDICTOR)):
        load_predictor(tmp_path / "nowhere")


def test_a_report_folder_takes_one_report_at_a_time(tiny, tmp_path):
    """While one report works on a folder (its job lock held), a second report of that folder, of any task, is
    refused at once in one line, and nothing of it is written."""
    from uavplace.infra.files import exclusive_folder

    out = tmp_path / "same"
    args = ["report", "--dataset", "tiny", "--root", str(tiny), "--episodes", "4", "--bootstrap", "100", "--out",
            str(out), "--predictor", "none", "--quiet"]  # fmt: skip
    with exclusive_folder(out, "report", kind="job"):  # as a first report holds it while it plays
        res = CliRunner().invoke(uavrl, args)
        assert res.exit_code == 2 and "another process is working on this report now" in res.output, res.output
        assert not out.exists()
    res = CliRunner().invoke(uavrl, args)  # once the first is done, the folder is free
    assert res.exit_code == 0, res.output
    assert (out / "report.html").is_file()


def test_a_missing_training_bundle_is_said_in_words_in_the_caption(tmp_path):
    """The shipped agents' training bundles are not on a user's machine: the training figure's note says so in
    words, naming a few cities, never an error message."""
    from uavplace.eval.evaluate import load_agent, training_bounds

    agent = load_agent(REPO / "data" / "agents" / "best", 0.096, 0)
    bounds, notes = training_bounds([agent], tmp_path / "empty", 5.0)
    (note,) = notes.values()
    assert not bounds and note.startswith("no bound: the training cities (") and note.endswith("are not built here")
    assert "bundle version" not in note and "@" not in note


def test_report_progress_names_the_city_the_method_and_the_predicted_maps(tiny, tmp_path):
    """To a log, the report's progress names the city's place among the report's, each stage's (a method's episodes,
    a searcher's predicted maps) place among the city's, "stage j of m", and the predicted maps as they are made (a
    cold cache: no silent wait before the first episode); before the first stage, what it is loading."""
    import re
    import shutil

    root = tmp_path / "root"
    shutil.copytree(tiny, root)
    shutil.rmtree(root / ".predictions", ignore_errors=True)
    args = ["report", "--dataset", "tiny", "--root", str(root), "--episodes", "4", "--bootstrap", "100", "--out",
            str(tmp_path / "rep")]  # fmt: skip
    res = CliRunner().invoke(uavrl, args)  # not a terminal: plain progress lines
    assert res.exit_code == 0, res.output
    lines = [line for line in res.output.splitlines() if line.startswith("report city 1 of 1: tiny, stage ")]
    assert any("map searcher: predicted maps" in line and line.endswith("candidates") for line in lines), lines
    assert any(line.endswith("4/4 episodes") for line in lines)
    pattern = re.compile(r"report city 1 of 1: tiny, stage (\d+) of (\d+): ")
    counts = {tuple(map(int, pattern.match(line).groups())) for line in lines}
    total = {m for _, m in counts}
    assert len(total) == 1 and {j for j, _ in counts} == set(range(1, total.pop() + 1)), counts  # every stage, counted
    # before the first stage, what is being loaded (no blank wait): the bundle first
    first = next(i for i, line in enumerate(res.output.splitlines()) if line.startswith("report city 1 of 1: tiny"))
    assert res.output.splitlines()[first] == "report city 1 of 1: tiny: loading the bundle of tiny", res.output
    assert "report city 1 of 1: tiny: reading the agents' training cities (their upper bounds)" in res.output


def test_report_search_sets_the_searchers_settings(tiny, tmp_path):
    """``--search NAME=VALUE`` sets the searcher's settings on top of each task's default (the record says them); a
    mistyped name, a refused value or a setting the task's searcher does not read ends the command before anything is
    played or written."""
    from uavplace.eval.reports import task_report
    from uavplace.rl.config import SearchConfig
    from uavplace.rl.tasks.tracking.config import tracking_search

    out = tmp_path / "rep"
    args = ["report", "--dataset", "tiny", "--root", str(tiny), "--episodes", "4", "--bootstrap", "100", "--out", str(out),
            "--quiet", "--search", "planner=info", "--search", "info-weight=0.3"]  # fmt: skip
    res = CliRunner().invoke(uavrl, args)
    assert res.exit_code == 0, res.output
    search = json.loads((out / "report.json").read_text())["report_config"]["search"]
    assert search == SearchConfig(planner="info", info_weight=0.3).model_dump(mode="json")
    for bad, says in (("plan=info", "NAME one of stride"), ("stride=0", "stride"), ("planner=best", "planner"),
                      ("reach_cells=Infinity", "reach_cells"), ("min_sigma_db=1e999", "min_sigma_db"),
                      ("stride=true", "stride: true is not a whole number")):  # fmt: skip
        res = CliRunner().invoke(uavrl, [*args[:-4], "--out", str(tmp_path / "no"), "--search", bad])
        assert res.exit_code == 2 and "--search" in res.output and says in res.output, res.output
        assert not (tmp_path / "no").exists()
    res = CliRunner().invoke(uavrl, [*args, "--predictor", "none"])  # no searcher plays: nothing to set
    assert res.exit_code == 2 and "--predictor none leaves every searcher out" in res.output, res.output
    assert task_report("tracking").search(()) == tracking_search()  # each task's own default, changed name by name
    assert task_report("tracking").search(("stride=4",)) == tracking_search().model_copy(update={"stride": 4})
    assert task_report("fleet").search(("fleet_plan=makespan",)).fleet_plan == "makespan"
    refused = (("tracking", "planner=info", "does not read planner"), ("fleet", "error_share=0.5", "error_share"),
               ("fleet", "planner=lookahead", "it plans with cover or info"), ("placement", "fleet_plan=product",
               "fleet_plan"), ("placement", "buildings=false", "with the buildings and without"))  # fmt: skip
    for task, pair, says in refused:  # a setting its searcher does not read would be recorded and not played
        with pytest.raises(click.BadParameter, match=says):
            task_report(task).search((pair,))


def test_report_network_precision_is_the_tasks_own_unless_given(tiny, tmp_path):
    """``--network-precision``: placement's agents act in float32 by default, the tracking and fleet reports' in
    bfloat16; given, it is what the record says and what every agent is handed."""
    from uavplace.eval.config import ReportConfig
    from uavplace.eval.reports.fleet.config import FleetReportConfig
    from uavplace.eval.reports.tracking.config import TrackingReportConfig

    assert ReportConfig(dataset="x").network_precision == "float32"
    assert (
        TrackingReportConfig(datasets=["x"]).network_precision
        == FleetReportConfig(datasets=["x"]).network_precision
        == "bfloat16"
    )
    args = ["report", "--dataset", "tiny", "--root", str(tiny), "--episodes", "4", "--bootstrap", "100", "--quiet",
            "--run", str(REPO / "data" / "agents" / "proposed"), "--predictor", "none"]  # fmt: skip
    for given, recorded in ((None, "float32"), ("bfloat16", "bfloat16")):
        out = tmp_path / str(given)
        res = CliRunner().invoke(uavrl, [*args, "--out", str(out), *(["--network-precision", given] if given else [])])
        assert res.exit_code == 0, res.output
        assert json.loads((out / "report.json").read_text())["report_config"]["network_precision"] == recorded
    res = CliRunner().invoke(uavrl, [*args, "--out", str(tmp_path / "no"), "--network-precision", "half"])
    assert res.exit_code == 2 and "--network-precision" in res.output and not (tmp_path / "no").exists()


def test_levers_refuses_a_run_given_twice(tmp_path):
    """`uavrl levers RUN RUN` (or two runs of one folder name) is refused in one line before anything is played: the
    table would hold two methods of one name."""
    for name in ("a", "b"):
        (tmp_path / name / "r").mkdir(parents=True)
    res = CliRunner().invoke(uavrl, ["levers", str(tmp_path / "a" / "r"), str(tmp_path / "a" / "r")])
    assert res.exit_code == 2 and "is given twice" in res.output, res.output
    res = CliRunner().invoke(uavrl, ["levers", str(tmp_path / "a" / "r"), str(tmp_path / "b" / "r")])
    assert res.exit_code == 2 and "both named r" in res.output, res.output


def test_report_measure_and_map_error_set_what_every_method_reads(tiny, tmp_path):
    """``--measure NAME=VALUE`` sets the measurement of every method's env, ``--map-error NAME=VALUE`` its map's error
    (each recorded with the report); a value out of range, a name that is none, or either in the fleet task (which
    reads exactly on the traced map) ends the command before any episode is played."""
    from uavplace.eval.evaluate import ReportConfig, report_env
    from uavplace.rl.config import MapErrorSettings, MeasurementSettings

    out = tmp_path / "rep"
    args = ["report", "--dataset", "tiny", "--root", str(tiny), "--episodes", "4", "--bootstrap", "100", "--out", str(out),
            "--quiet", "--predictor", "none", "--measure", "sigma_db=4", "--measure", "shadow_sigma_db=2"]  # fmt: skip
    res = CliRunner().invoke(uavrl, args)
    assert res.exit_code == 0, res.output
    config = json.loads((out / "report.json").read_text())["report_config"]
    want = MeasurementSettings(sigma_db=4, shadow_sigma_db=2)
    assert config["measurement"] == want.model_dump(mode="json")
    assert report_env(ReportConfig.model_validate(config)).measurement == want
    for bad, says in (("sigma_db=-1", "sigma_db"), ("sigma=4", "NAME one of"), ("sigma_db=nan", "sigma_db")):
        res = CliRunner().invoke(uavrl, [*args[:-4], "--out", str(tmp_path / "no"), "--measure", bad])
        assert res.exit_code == 2 and "--measure" in res.output and says in res.output, res.output
        assert not (tmp_path / "no").exists()
    res = CliRunner().invoke(uavrl, ["report", "--task", "fleet", "--dataset", "tiny", "--root", str(tiny), "--measure",
                                     "sigma_db=2", "--out", str(tmp_path / "no")])  # fmt: skip
    assert res.exit_code == 2 and "reads every user's SINR exactly" in res.output, res.output
    erring = ["--map-error", "height_sigma_m=2", "--map-error", "shift_m=1", "--out", str(tmp_path / "m")]
    res = CliRunner().invoke(uavrl, [*args[:-4], *erring])  # the map's error: recorded, every method's env given it
    assert res.exit_code == 0, res.output
    config = json.loads((tmp_path / "m" / "report.json").read_text())["report_config"]
    assert report_env(ReportConfig.model_validate(config)).map_error == MapErrorSettings(height_sigma_m=2, shift_m=1)
    res = CliRunner().invoke(uavrl, ["report", "--task", "fleet", "--dataset", "tiny", "--root", str(tiny), "--map-error",
                                     "shift_m=1", "--out", str(tmp_path / "no")])  # fmt: skip
    assert res.exit_code == 2 and "plays on the traced city's map" in res.output, res.output

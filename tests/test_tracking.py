"""The tracking task (a user who moves): routes drawn on open ground, the routes table contract from export to
bundle, the env's time stepping, and the oracle against brute force."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
import shapely

from tests import scramble
from tests.conftest import REPO, write_grid_city
from uavplace.dataset.build import build_city
from uavplace.dataset.bundle import load_bundle
from uavplace.ingest.pipeline import ingest_city
from uavplace.rl.tasks.tracking import (
    STAY,
    TRACK_MOVES,
    Holding,
    MovesOnly,
    OraclePolicy,
    PlacementInTracking,
    ReplanningGenie,
    RouteSet,
    TrackingConfig,
    TrackingEnv,
    episode_metrics,
    oracle_path,
    run_tracking,
    user_point,
)
from uavplace.schemas import InputError
from uavplace.schemas.bundle import BuildConfig
from uavplace.simulate.routes import KINDS, MAX_STEP_M, draw_routes

#: Two routes on the synthetic grid city (x 8..32, y -22..-2): an L along open ground, and a short straight one.
ROUTES = [
    np.array([(12.0 + 2 * k, -14.0) for k in range(9)] + [(28.0, -14.0 + 2 * k) for k in range(1, 5)]),
    np.array([(14.0, -6.0 + 1.5 * k) for k in range(3)]),
]


def build_walk(tmp: Path, name: str = "walk", seed: int = 2) -> Path:
    """The grid city ``name`` (drawn by ``seed``) with the two ``ROUTES``, written under ``tmp``, ingested and built:
    its bundles' root."""
    raw = write_grid_city(tmp / f"raw-{name}", nx=6, ny=5, n_tx=3, seed=seed, dead_share=0.0, routes=ROUTES)
    ingest_city(raw, tmp / "p", name=name)
    build_city(name, BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-45.0), tmp / "p")
    return tmp / "p"


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return build_walk(tmp_path_factory.mktemp("tracking"))


def test_routes_keep_to_open_ground_and_their_sampling():
    """Drawn routes: the asked length, steps of at most 2 m, clear of every building, kinds in turn, the same
    routes for the same seed."""
    blocks = [shapely.box(20, 20, 60, 60), shapely.box(70, 10, 90, 80), shapely.box(10, 70, 50, 95)]
    routes = draw_routes(blocks, (0, 0, 100, 100), 4, 60.0, ("pedestrian", "vehicle"), np.random.default_rng(1))
    union = shapely.union_all(blocks)
    for k, r in enumerate(routes):
        steps = np.linalg.norm(np.diff(r.points_m, axis=0), axis=1)
        assert steps.max() <= MAX_STEP_M + 1e-9 and 55.0 < steps.sum() <= 60.0 + 1e-6  # chords of a 60 m line
        assert not shapely.intersects(shapely.LineString(r.points_m), shapely.buffer(union, 0.25))
        assert r.kind == ("pedestrian", "vehicle")[k % 2]
        np.testing.assert_allclose(r.times_s[-1], steps.sum() / KINDS[r.kind])
    again = draw_routes(blocks, (0, 0, 100, 100), 4, 60.0, ("pedestrian", "vehicle"), np.random.default_rng(1))
    assert all(np.array_equal(a.points_m, b.points_m) for a, b in zip(routes, again, strict=True))
    with pytest.raises(ValueError, match="no path of 500 m"):
        draw_routes(blocks, (0, 0, 100, 100), 1, 500.0, ("pedestrian",), np.random.default_rng(1))


def test_routes_travel_from_export_to_bundle(root):
    """The route points are traced as users but are not users of the bundle: placement sees the 3 users only; the
    bundle's routes table holds every point in route order with its map."""
    b = load_bundle("walk", root=root)
    assert b.num_users == 3 and b.manifest.num_route_points == sum(len(r) for r in ROUTES)
    assert b.routes["route"].tolist() == [0] * len(ROUTES[0]) + [1] * len(ROUTES[1])
    np.testing.assert_allclose(b.routes[["x_m", "y_m"]].to_numpy(), np.vstack(ROUTES))
    assert b.route_sinr_db.shape == (len(b.routes), *b.shape)
    # A point's map is brightest near the point (the synthetic path loss grows with distance).
    k = 5
    iy, ix = np.unravel_index(np.argmax(b.route_sinr_db[k]), b.shape)
    assert abs(b.x_m[ix] - b.routes["x_m"][k]) <= 6 and abs(b.y_m[iy] - b.routes["y_m"][k]) <= 6


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda rows: rows[:3] + rows[4:], "city.routes.csv:4: order: order 3 of route 0: expected 2"),
        (lambda rows: [*rows[:2], rows[2].replace(",1.4286,", ",9.0000,"), *rows[3:]], "city.routes.csv:3: time_s: time 9 s"),
        (
            lambda rows: [*rows[:2], rows[2].replace(",3,2,", ",3,99,"), *rows[3:]],
            "city.routes.csv:3: tx_point: no transmitter t099_03",
        ),
        (lambda rows: [*rows[:2], rows[2].replace("pedestrian", "horse"), *rows[3:]], "city.routes.csv:3: kind: 'horse'"),
        (
            lambda rows: [*rows[:2], rows[2] + "," + "9" * 200_000, *rows[3:]],
            "city.routes.csv:3: row: not a CSV row (field larger",
        ),
        (
            lambda rows: ["\ufeff" + rows[0], *rows[1:3], rows[3].replace("pedestrian", "horse"), *rows[4:]],
            "city.routes.csv:4: kind: 'horse'",
        ),  # a byte-order mark is read past, as in every export
        (
            lambda rows: [rows[0], *(r.replace(",pedestrian,1.4", ",pedestrian,100") for r in rows[1:])],
            "city.routes.csv:2: speed_mps: route 0: a pedestrian at 100 m/s",
        ),
    ],
    ids=["order-gap", "wrong-time", "unknown-point", "unknown-kind", "huge-field", "bom", "running-at-100"],
)
def test_bad_routes_are_refused_with_their_line(tmp_path, edit, message):
    """A routes file that breaks the contract is refused by ingest, naming the file, the line and the field."""
    folder = write_grid_city(tmp_path / "raw", nx=6, ny=5, n_tx=1, routes=ROUTES)
    path = folder / "city.routes.csv"
    path.write_text("\n".join(edit(path.read_text().splitlines())) + "\n")
    with pytest.raises(InputError) as err:
        ingest_city(folder, tmp_path / "p", name="bad")
    assert message in str(err.value)


def test_a_jump_a_moved_point_or_a_building_on_the_route_is_refused(tmp_path):
    """No jump longer than the sampling; every point where the .txrx puts its transmitter; no point inside a building
    (the .city's footprints)."""
    from uavplace.simulate.insite import write_city

    folder = write_grid_city(tmp_path / "m", nx=6, ny=5, n_tx=1, routes=ROUTES)
    txrx = folder / "city.txrx"
    txrx.write_text(txrx.read_text().replace("14.000000 -14.000000 1.500000", "14.500000 -14.000000 1.500000"))
    with pytest.raises(InputError, match=r"routes.csv:3: x_m: \(14, -14\), but the .txrx puts t002_03 at \(14.5, -14\)"):
        ingest_city(folder, tmp_path / "p", name="moved")

    far = [np.array([(12.0, -14.0), (16.0, -14.0)])]
    folder = write_grid_city(tmp_path / "a", nx=6, ny=5, n_tx=1, routes=far)
    with pytest.raises(InputError, match="routes.csv:3: x_m: a jump of 4.000 m"):
        ingest_city(folder, tmp_path / "p", name="jump")
    folder = write_grid_city(tmp_path / "b", nx=6, ny=5, n_tx=1, routes=ROUTES)
    write_city(folder / "city.city", [[(shapely.box(19.0, -16.0, 23.0, -12.0), 0.0, 30.0)]], name="city")
    with pytest.raises(InputError, match=r"routes.csv:6: x_m: point \(20, -14\) is inside a building"):
        ingest_city(folder, tmp_path / "p", name="inside")


def test_user_walks_the_route_and_back():
    """After t steps of step_s the user is at the point nearest in time, turning back at each end."""
    times = np.array([[0.0, 1.0, 2.0, 3.0, np.inf]])
    at = [int(user_point(times, np.array([0.5]), np.array([t]), np.array([0.5]))[0]) for t in range(14)]
    # s = 0.5, 1.0, ... 3.0 (the end) at t = 5, then back: 3.5 is 2.5, ... 6.0 is 0 (the start), 6.5 is 0.5 again;
    # a time halfway between two points takes the earlier one
    assert at == [0, 1, 1, 2, 2, 3, 2, 2, 1, 1, 0, 0, 0, 1]


def _brute_force(legal: np.ndarray, covered: np.ndarray, start: tuple[int, int]) -> int:
    h, ny, nx = covered.shape
    best = 0
    for actions in itertools.product(range(5), repeat=h):
        y, x, total = *start, 0
        for t, a in enumerate(actions):
            ty, tx = y + TRACK_MOVES[a][0], x + TRACK_MOVES[a][1]
            if 0 <= ty < ny and 0 <= tx < nx and legal[ty, tx]:
                y, x = ty, tx
            total += bool(covered[t, y, x])
        best = max(best, total)
    return best


@pytest.mark.parametrize("seed", range(6))
def test_oracle_equals_brute_force(seed):
    """The dynamic programme's covered count equals the best over every action sequence (5^5) on a small grid with
    blocked cells and a moving covered region, and its path is legal and scores what it claims."""
    rng = np.random.default_rng(seed)
    legal = rng.random((4, 5)) > 0.25
    start = tuple(int(v) for v in np.argwhere(legal)[0])
    covered = rng.random((5, 4, 5)) < 0.3
    path, value = oracle_path(legal, covered, start)
    assert value == _brute_force(legal, covered, start)
    assert legal[path[:, 0], path[:, 1]].all() and (np.abs(np.diff(path, axis=0)).sum(axis=1) <= 1).all()
    assert value == sum(bool(covered[t, path[t + 1][0], path[t + 1][1]]) for t in range(5))


def test_oracle_breaks_ties_by_staying_and_counts_past_int16():
    """Where every step is covered everywhere, the oracle stays where it starts (ties go to staying); a horizon
    longer than int16 can count is counted whole."""
    legal = np.array([[True, True, False], [True, True, True]])
    path, value = oracle_path(legal, np.ones((7, 2, 3), bool), (1, 1))
    assert value == 7 and (path == (1, 1)).all()
    covered = np.zeros((40_000, 1, 2), bool)
    covered[:, 0, 1] = True  # only the right cell covers: the first move goes there and stays
    path, value = oracle_path(np.ones((1, 2), bool), covered, (0, 0))
    assert value == 40_000 and (path[1:] == (0, 1)).all()


def test_env_steps_time_and_the_oracle_bounds_every_method(root):
    """The env moves the user by speed x step time, keeps the UAV in place on stay, truncates at the horizon; on the
    same episodes the oracle covers at least as much as the re-planning genie and a random walk, and exactly what
    its dynamic programme promised."""
    from uavplace.rl.tasks.placement.policies import RandomWalkPolicy

    config = TrackingConfig(horizon=20, window=9, p_t_db=5.0)
    routes = RouteSet([load_bundle("walk", root=root)], config)
    assert routes.num_routes == 2 and np.allclose(routes.step_s, 0.4)
    episodes = routes.sample_episodes(12, np.random.default_rng(0))
    env = TrackingEnv(routes, 3, queue=episodes)
    obs, info = env.reset()
    assert obs.shape == (3, 3, 9, 9) and info["action_mask"].shape == (3, 5) and info["action_mask"][:, STAY].all()
    pos = env.pos.copy()
    for t in range(1, 6):
        obs, reward, terminated, truncated, info = env.step(np.full(3, STAY))
        assert (env.pos == pos).all() and (env.t == t).all() and not truncated.any()
        expected = routes.first[env.route] + user_point(
            routes.times[env.route], env.start_s, np.full(3, t), routes.step_s[env.route]
        )
        assert (env.point() == expected).all()
        assert (obs[:, 1, 4, 4] == 0).all()  # the cell it stands in was measured just now
    for _ in range(15):
        obs, reward, terminated, truncated, info = env.step(np.full(3, STAY))
    assert truncated.all() and (env.t == 0).all()  # restarted at the horizon
    results = {
        p.name: run_tracking(routes, p, episodes)
        for p in (OraclePolicy(), ReplanningGenie(), MovesOnly(RandomWalkPolicy(seed=0)))
    }
    oracle = results["oracle"].table["covered_share"].to_numpy()
    for name, res in results.items():
        assert (oracle >= res.table["covered_share"].to_numpy() - 1e-12).all(), name
    assert oracle.mean() > results["steered random walk"].table["covered_share"].mean()
    m = episode_metrics(results["oracle"].covered)
    assert np.array_equal(m["covered_share"], oracle)


def test_episode_metrics_by_hand():
    covered = np.array([[0, 0, 1, 1, 0, 0, 0, 1], [0] * 8, [1] * 8], bool)
    m = episode_metrics(covered)
    assert m["first_reach"].tolist() == [3, np.inf, 1]
    np.testing.assert_allclose(m["coverage"], [3 / 6, 0, 1])
    assert m["longest_outage"].tolist() == [3, 8, 0]
    np.testing.assert_allclose(m["covered_share"], [3 / 8, 0, 1])


def test_gymnasium_tracking_env(root):
    """``gymnasium.make("uavplace/UavTracking-v0")`` passes Gymnasium's checker and ends at its horizon."""
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import uavplace.rl  # noqa: F401 - registers the envs

    env = gym.make("uavplace/UavTracking-v0", dataset="walk", root=str(root), horizon=7, window=9)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=1)
    assert env.action_space.n == 5 and info["action_mask"][STAY] == 1 and obs.shape == (3, 9, 9)
    for t in range(7):
        obs, reward, terminated, truncated, info = env.step(STAY)
        assert not terminated and truncated == (t == 6) and "covered" in info


def test_recorded_paths_replay_the_covered_steps(root):
    """run_tracking(record=True) gives the UAV's cells and the user's points at every step: moves of at most one cell,
    the episode's start cell first, and the covered steps are exactly those where the SINR of that cell to that point
    reaches P_T; recording changes nothing of the play."""
    config = TrackingConfig(horizon=15, window=9)
    routes = RouteSet([load_bundle("walk", root=root)], config)
    episodes = routes.sample_episodes(9, np.random.default_rng(3))
    plain = run_tracking(routes, ReplanningGenie(), episodes, num_envs=4)
    res = run_tracking(routes, ReplanningGenie(), episodes, num_envs=4, record=True)
    assert np.array_equal(plain.covered, res.covered) and res.path.shape == (9, 16, 2)
    assert (np.abs(np.diff(res.path, axis=1)).sum(axis=2) <= 1).all()
    assert np.array_equal(res.path[:, 0], episodes[:, 2:].astype(int))
    sinr = routes.sinr[res.points[:, 1:], res.path[:, 1:, 0], res.path[:, 1:, 1]]
    assert np.array_equal(sinr >= config.p_t_db, res.covered)


def test_holding_stays_exactly_while_its_own_measurement_covers(root):
    """``Holding`` stays on every step whose measurement reached P_T and otherwise makes the wrapped method's move; the
    wrapped method is called on every step (so a recurrent agent's state follows the episode), and what it would
    have done while holding is overridden."""
    from uavplace.rl.tasks.placement.policies import RandomWalkPolicy

    config = TrackingConfig(horizon=25, window=9, p_t_db=5.0)
    routes = RouteSet([load_bundle("walk", root=root)], config)
    episodes = routes.sample_episodes(16, np.random.default_rng(4))

    class Counting(MovesOnly):
        calls = 0

        def act(self, obs, mask, env):
            Counting.calls += 1
            return super().act(obs, mask, env)

    inner = Counting(RandomWalkPolicy(seed=0))
    held = run_tracking(routes, Holding(inner), episodes, num_envs=16, record=True)
    assert Counting.calls == config.horizon and held.covered.any() and (~held.covered).any()
    moved = np.abs(np.diff(held.path, axis=1)).sum(axis=2) > 0  # [K, H]: did step t + 1 leave the cell
    # the random walk always makes a legal move: the UAV stays exactly after the covered steps (covered[:, t - 1] is
    # the measurement after step t), and leaves the start cells, which are below P_T
    assert np.array_equal(moved[:, 1:], ~held.covered[:, :-1]) and moved[:, 0].all()
    assert Holding(inner).name == "steered random walk + hold"


def test_methods_that_read_no_observation_are_handed_none_and_play_the_same(root):
    """``run_tracking`` makes no observation for a policy that reads none (the oracle, the re-planning genie, a
    placement agent through its mirror, held or not): it is handed None, and every episode plays as when it is handed
    every step's observation."""
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.policies import RandomWalkPolicy

    config = TrackingConfig(horizon=25, window=9, p_t_db=5.0)
    routes = RouteSet([load_bundle("walk", root=root)], config)
    episodes = routes.sample_episodes(16, np.random.default_rng(4))

    class Handed:
        """``policy`` as it is, recording what it is handed; ``sees``: handed every observation."""

        def __init__(self, policy, sees: bool) -> None:  # noqa: ANN001
            self.policy, self.name, self.reads_observation = policy, policy.name, sees
            self.privileged, self.handed = getattr(policy, "privileged", False), set()

        def bind(self, routes):  # noqa: ANN001, ANN202
            if hasattr(self.policy, "bind"):
                self.policy.bind(routes)

        def reset(self, rows, num_envs):  # noqa: ANN001, ANN202
            self.policy.reset(rows, num_envs)

        def act(self, obs, mask, env):  # noqa: ANN001, ANN202
            self.handed.add(type(obs).__name__)
            return self.policy.act(obs, mask, env)

    def placement():  # noqa: ANN202
        return PlacementInTracking(RandomWalkPolicy(seed=0), EnvConfig(window=9), "walker")

    for make in (OraclePolicy, ReplanningGenie, placement, lambda: Holding(placement())):
        assert make().reads_observation is False
        blind, sees = Handed(make(), False), Handed(make(), True)
        played = [run_tracking(routes, p, episodes, num_envs=8, record=True) for p in (blind, sees)]
        assert blind.handed == {"NoneType"} and sees.handed == {"ndarray"}
        assert np.array_equal(played[0].covered, played[1].covered) and np.array_equal(played[0].path, played[1].path)
    assert Holding(MovesOnly(RandomWalkPolicy(seed=0))).reads_observation  # its greedy or random walk reads it


def test_tracking_table_intervals_resample_routes():
    """The tracking table's intervals: a method that covers everything has [1, 1]; the fraction of the oracle is the
    ratio of the means; routes that differ widen the interval of the route-level bootstrap."""
    import pandas as pd

    from uavplace.eval.reports.tracking.page import tracking_table
    from uavplace.rl.tasks.tracking import TrackingEpisodes

    rng = np.random.default_rng(0)
    k, h = 200, 10
    route = np.repeat(np.arange(4), k // 4)
    half = rng.random((k, h)) < np.where(route < 2, 0.9, 0.1)[:, None]  # two good routes, two bad

    def episodes(covered: np.ndarray) -> TrackingEpisodes:
        table = pd.DataFrame({"episode": np.arange(k), "route": route, "city": "c"} | episode_metrics(covered))
        return TrackingEpisodes(table, covered)

    never = episodes(np.zeros((k, h), bool))  # the reference (the re-planning genie) covers nothing
    t = tracking_table({"oracle": episodes(np.ones((k, h), bool)), "half": episodes(half), "re-planning genie": never},
                       n_boot=400, seed=1)  # fmt: skip
    o, m = t.set_index("method").loc["oracle"], t.set_index("method").loc["half"]
    assert o["covered_share"] == o["covered_share_lo"] == o["covered_share_hi"] == 1.0
    assert m["of_oracle"] == pytest.approx(half.mean())
    # the paired difference against the reference: all of the oracle's, exactly; half's mean, within its interval
    assert o["minus_reference"] == o["minus_reference_lo"] == o["minus_reference_hi"] == 1.0
    assert m["minus_reference"] == pytest.approx(half.mean())
    assert m["minus_reference_lo"] < half.mean() < m["minus_reference_hi"]
    assert np.isnan(t.set_index("method").loc["re-planning genie", "minus_reference"])
    assert m["covered_share_lo"] < half.mean() < m["covered_share_hi"]
    assert m["covered_share_hi"] - m["covered_share_lo"] > 0.3  # routes of 0.9 and 0.1: the route level dominates

    from uavplace.eval.reports.tracking.page import summary_rows

    other = t.assign(city="d", covered_share=t["covered_share"] / 2)[t["method"] == "half"]  # "oracle" not in d
    rows = summary_rows(pd.concat([t, other], ignore_index=True))
    assert rows[0] == ["method", "c", "d"] and [r[0] for r in rows[1:]] == ["oracle", "half", "re-planning genie"]
    assert rows[1][2] == "-" and rows[2][1].startswith(f"{m['covered_share']:.3f} ({half.mean():.2f} [")
    assert rows[2][2].startswith(f"{m['covered_share'] / 2:.3f} (")


def test_tracking_report_from_the_command_line(root, tmp_path):
    """`uavrl report --task tracking` writes the page, the table, the Markdown, the figures and tracking.json, and
    prints one table per city; a shipped placement agent plays unchanged beside the baselines; --group is refused."""
    import json

    from click.testing import CliRunner

    from uavplace.cli import uavrl

    out = tmp_path / "trk"
    args = ["report", "--task", "tracking", "--dataset", "walk", "--root", str(root), "--episodes", "12", "--horizon",
            "20", "--bootstrap", "100", "--out", str(out), "--markdown", str(tmp_path / "t.md"), "--run",
            str(REPO / "data" / "agents" / "proposed"), "--quiet"]  # fmt: skip
    result = CliRunner().invoke(uavrl, args)
    assert result.exit_code == 0, result.output
    table = (out / "tracking.md").read_text()
    assert all(m in table for m in ("oracle", "DQN (paper)", "re-planning genie", "greedy hill-climbing"))
    assert all(f"| {m} + hold |" in table for m in ("DQN (paper)", "steered random walk", "greedy hill-climbing"))
    assert "re-planning genie + hold" not in table and "oracle + hold" not in table
    for name in ("tracking.html", "tracking.csv", "tracking.md", "tracking.json", "walk-coverage.png", "walk-episodes.png"):
        assert (out / name).is_file(), name
    record = json.loads((out / "tracking.json").read_text())
    assert record["config"]["task"]["horizon"] == 20 and record["cities"][0]["city"] == "walk"
    assert record["config"]["search"]["reach_cells"] == 192.0  # the tracking searcher's own discount (tracking_search)
    assert (tmp_path / "t.md").read_text() == (out / "tracking.md").read_text()
    plain = CliRunner().invoke(uavrl, [str(tmp_path / "plain") if a == str(out) else a for a in args] + ["--no-hold"])
    assert plain.exit_code == 0 and "+ hold" not in (tmp_path / "plain" / "tracking.md").read_text()
    refused = CliRunner().invoke(uavrl, [*args[:-1], "--group", f"g={tmp_path}"])
    assert refused.exit_code == 2 and "takes no --group" in refused.output
    assert "tracking searcher" in table  # the shipped predictor's belief, carried through time (rl/tasks/tracking/searcher.py)
    for p_t in ("100", "-100"):  # P_T above or below every map: no episode can start; one line, no report
        odd = [str(tmp_path / f"odd{p_t}") if a == str(out) else a for a in args] + ["--p-t-db", p_t]
        refused = CliRunner().invoke(uavrl, odd)
        assert refused.exit_code == 2 and "--p-t-db" in refused.output and "internal error" not in refused.output
        assert not (tmp_path / f"odd{p_t}").exists()


@pytest.fixture(scope="module")
def val_root(root):
    """``root`` with a second routed city, ``walk-val``, built as a validation city (other routes on other paths)."""
    raw = root.parent / "raw-val"
    routes = [ROUTES[1], np.array([(10.0 + 2 * k, -10.0) for k in range(8)])]
    ingest_city(write_grid_city(raw, nx=6, ny=5, n_tx=2, seed=5, dead_share=0.0, routes=routes), root, name="walk-val")
    build_city("walk-val", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-45.0, role="val"), root)
    return root


def _tracking_config(**update):
    from uavplace.rl.agent.config import preset_config

    tiny = {"total_steps": 512, "num_envs": 8, "rollout_steps": 8, "batch_size": 32, "epochs": 2, "hidden": 16,
            "fovea": 5, "eval_every": 256, "eval_episodes": 16}  # fmt: skip
    return preset_config("best", task="tracking", tracking={"horizon": 24, "window": 9}, **(tiny | update))


def test_genie_moves_hold_the_replanning_genies_choice(root):
    """The tracking env's training aid: stay exactly where the cell covers the user's point now; elsewhere the moves
    that start a shortest path to its P_T region, among them the re-planning genie's own."""
    routes = RouteSet([load_bundle("walk", root=root)], TrackingConfig(horizon=30, window=9))
    env = TrackingEnv(routes, 16)
    env.reset(seed=4)
    genie, rng = ReplanningGenie(), np.random.default_rng(0)
    seen = 0
    for _ in range(20):
        moves, mask = env.genie_moves(), env.action_mask()
        here = routes.steps[env.point(), env.pos[:, 0], env.pos[:, 1]]
        assert np.array_equal(moves[:, STAY], here == 0) and not (moves[:, :STAY] & (here == 0)[:, None]).any()
        assert not (moves & ~mask).any()
        chosen = genie.act(None, mask, env)
        has = moves.any(axis=1)
        assert moves[np.flatnonzero(has), chosen[has]].all()
        seen += int(has.sum())
        env.step(rng.integers(0, 5, 16))
    assert seen > 100


def test_tracking_agent_trains_selects_on_validation_routes_and_reports(val_root, tmp_path):
    """`uavrl train --task tracking`: a 5-action network learnt by the `best` learner on the routes of the training
    city, evaluated on the validation city's (covered share in eval.parquet and metrics.parquet); stopped and resumed
    it ends where a straight run ends; `uavrl report --task tracking` plays it on its own observation (a 9-cell window
    in a report of 61) beside the baselines, and the placement report refuses it."""
    import json

    import pandas as pd
    import torch
    from click.testing import CliRunner

    from uavplace.cli import uavrl
    from uavplace.rl.agent.runs import load_policy, read_run_json
    from uavplace.rl.agent.train import Trainer

    args = ["train", "--task", "tracking", "--dataset", "walk", "--dataset", "walk-val", "--root", str(val_root),
            "--out", str(tmp_path), "--steps", "512", "--eval-every", "256", "--quiet"]  # fmt: skip
    sets = [f"--set={k}={v}" for k, v in _tracking_config().model_dump(include={"num_envs", "rollout_steps",
            "batch_size", "epochs", "hidden", "fovea", "eval_episodes"}).items()]  # fmt: skip
    sets += ["--set=tracking.horizon=24", "--set=tracking.window=9"]
    result = CliRunner().invoke(uavrl, [*args, "--name", "straight", *sets])
    assert result.exit_code == 0, result.output
    assert "of the horizon covered" in result.output
    run = tmp_path / "straight"
    record = read_run_json(run)
    assert record.config.task.kind == "tracking" and record.config.n_actions == 5 and record.config.train_revisit_penalty == 0
    assert set(record.datasets) == {"walk"} and set(record.val_datasets) == {"walk-val"}
    evals, metrics = pd.read_parquet(run / "eval.parquet"), pd.read_parquet(run / "metrics.parquet")
    assert evals["step"].tolist() == [256, 512] and evals["covered_share"].between(0, 1).all()
    assert len(metrics) and metrics["covered_share"].between(0, 1).all() and (metrics["length"] == 24).all()
    policy, config = load_policy(run / "checkpoints" / "best.pt")
    assert config.task.kind == "tracking" and policy.net.head(torch.zeros(1, 16)).shape == (1, 5)

    # Stopped at 200 and resumed: the same network as the straight run.
    half = tmp_path / "half"
    trainer = Trainer(_tracking_config(), ["walk", "walk-val"], val_root, half)
    trainer.run(stop_at=200)
    resumed = Trainer(_tracking_config(), ["walk", "walk-val"], val_root, half)
    resumed.run(resume=True)
    straight = Trainer(_tracking_config(), ["walk", "walk-val"], val_root, tmp_path / "again")
    straight.run()
    for a, b in zip(resumed.agent.online.state_dict().values(), straight.agent.online.state_dict().values(), strict=True):
        assert torch.equal(a, b)

    # A city it never saw: the validation city's export under another name.
    ingest_city(val_root.parent / "raw-val", val_root, name="walk-unseen")
    build_city("walk-unseen", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-45.0), val_root)
    out = tmp_path / "trk"
    report = ["report", "--task", "tracking", "--dataset", "walk-unseen", "--root", str(val_root), "--episodes", "12",
              "--horizon", "24", "--bootstrap", "100", "--out", str(out), "--run", str(run), "--quiet"]  # fmt: skip
    result = CliRunner().invoke(uavrl, report)
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out / "tracking.csv")
    mine = table[table["method"] == "PQN + GRU (best, tracking)"]
    assert len(mine) == 1 and (mine["covered_share"] <= table.loc[table["method"] == "oracle", "covered_share"].max()).all()
    assert json.loads((out / "tracking.json").read_text())["agents"]["PQN + GRU (best, tracking)"]
    # Shipped beside a placement agent: the placement report's default agents leave it out, the tracking report's not.
    import shutil

    from uavplace.eval.evaluate import default_agents

    shipped = tmp_path / "agents"
    shutil.copytree(run, shipped / "tracker")
    shutil.copytree(REPO / "data" / "agents" / "proposed", shipped / "proposed")
    assert default_agents(shipped) == [shipped / "proposed"]
    assert default_agents(shipped, None) == [shipped / "proposed", shipped / "tracker"]
    placement = CliRunner().invoke(uavrl, ["report", "--dataset", "walk-unseen", "--root", str(val_root), "--run", str(run),
                                           "--episodes", "5", "--out", str(tmp_path / "p"), "--quiet"])  # fmt: skip
    assert placement.exit_code == 2 and "a tracking agent" in placement.output


def test_tracking_runs_need_routes_and_validation_routes(val_root, tmp_path):
    """A tracking run refuses a city without routes and a run without a validation city with routes, naming them."""
    from uavplace.rl.agent.train import Trainer

    with pytest.raises(InputError, match="selects best.pt on validation cities with routes"):
        Trainer(_tracking_config(), ["walk"], val_root, tmp_path / "a")
    (tmp_path / "raw").mkdir()
    ingest_city(write_grid_city(tmp_path / "raw" / "plain", seed=1), val_root, name="plain")
    build_city("plain", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-45.0), val_root)
    with pytest.raises(InputError, match="plain has no routes"):
        Trainer(_tracking_config(), ["walk", "plain", "walk-val"], val_root, tmp_path / "b")


def test_an_agent_plays_the_same_episodes_on_its_own_observation(root):
    """A tracking agent trained with another window plays the report's episodes on a canvas of its own padding: the
    same starts, the same covered steps and the same path, shifted back, as on the report's canvas."""
    from uavplace.rl.tasks.tracking import TrackingAgent

    config = TrackingConfig(horizon=20, window=21)
    routes = RouteSet([load_bundle("walk", root=root)], config)
    episodes = routes.sample_episodes(10, np.random.default_rng(5))
    here = run_tracking(routes, ReplanningGenie(), episodes, record=True)
    narrow = TrackingAgent(ReplanningGenie(), TrackingConfig(window=9, blind=True), "genie on a 9-cell window")
    there = run_tracking(routes, narrow, episodes, record=True)
    assert np.array_equal(here.covered, there.covered) and np.array_equal(here.path, there.path)
    assert np.array_equal(there.path[:, 0], episodes[:, 2:].astype(int))


def test_tracking_agents_read_only_what_they_measured(root):
    """A tracking agent (a fresh network, and every shipped one) moves exactly as before when the user's maps are
    scrambled on every cell it never visited, at every route point, and the routes moved and renumbered
    (``tests.scramble.tracking``), replayed with the same draws; the re-planning
    genie, which reads those maps, changes somewhere (so that the test can fail)."""
    from uavplace.eval.evaluate import default_agents, load_agent
    from uavplace.rl.agent.dqn import DQNPolicy, make_network
    from uavplace.rl.tasks.tracking import TrackingAgent

    fresh = _tracking_config()
    torch_net = make_network(fresh, *fresh.observation())
    agents = [TrackingAgent(DQNPolicy.from_config(torch_net, fresh), fresh.task.playing(fresh), "fresh")]
    for folder in default_agents(REPO / "data" / "agents", "tracking"):
        a = load_agent(folder, 0.096, 0, task="tracking")
        agents.append(TrackingAgent(a.policy, a.config.task.playing(a.config), a.name))
    bundle = load_bundle("walk", root=root)

    def replay(policy, task: TrackingConfig) -> tuple[list[bool], list[bool]]:  # noqa: ANN001
        rng = np.random.default_rng(0)  # the same scrambles whichever agents are shipped
        routes = RouteSet([bundle], task)
        episodes = routes.sample_episodes(10, np.random.default_rng(1))
        return scramble.replay_tracking(routes, policy, episodes, rng)

    for agent in agents:
        same, _ = replay(agent, TrackingConfig(horizon=24).observed_as(agent.observation))
        assert all(same), f"{agent.name}: moves changed when cells it never visited changed ({same})"
    _, changed = replay(ReplanningGenie(), TrackingConfig(horizon=24, window=9))
    assert any(changed), "the re-planning genie reads the maps: scrambling them must change some episode"


def test_rotated_routes_are_their_citys_quarter_turns(root):
    """Training's rotate: each route also under the quarter turns of its city; the identity comes first and is the
    unrotated RouteSet (same maps, same keys: evaluation episodes do not move); each turn's maps are the turned maps
    on the turned canvas, and the oracle bounds the re-planning genie there too."""
    from uavplace.rl.world.maps import transform

    b = load_bundle("walk", root=root)
    config = TrackingConfig(horizon=20, window=9)
    plain, turned = RouteSet([b], config), RouteSet([b], config, rotate=True)
    n, p, S = len(b.routes), turned.maps.pad, turned.maps.symmetries
    assert turned.turns == S == 4 and turned.num_routes == S * plain.num_routes
    assert np.array_equal(turned.sinr[:n], plain.sinr) and np.array_equal(turned.route_keys[:2], plain.route_keys)
    canvases = turned.canvas[: turned.num_routes]  # a route's key is its canvas's public map: no route is named
    assert len(set(turned.route_keys.tolist())) == len(set(canvases.tolist())) == S
    for k in range(S):
        ny, nx = turned.maps.shapes[k]
        block = slice(k * n, (k + 1) * n)
        np.testing.assert_array_equal(turned.sinr[block, p : p + ny, p : p + nx], transform(b.route_sinr_db, k))
        assert np.array_equal(turned.canvas[2 * k : 2 * k + 2], [k, k])
    episodes = turned.sample_episodes(16, np.random.default_rng(2))
    assert len(set(turned.canvas[episodes[:, 0].astype(int)].tolist())) > 1
    oracle, genie = (run_tracking(turned, q, episodes, record=True) for q in (OraclePolicy(), ReplanningGenie()))
    assert (oracle.table["covered_share"] >= genie.table["covered_share"] - 1e-12).all()
    blocked = turned.maps.blocked[turned.canvas[episodes[:, 0].astype(int)]]
    for path, canvas in zip((oracle.path, genie.path), (blocked, blocked), strict=True):
        assert not canvas[np.arange(16)[:, None], path[:, :, 0], path[:, :, 1]].any()


def test_motion_update_is_the_brute_force_propagation():
    """The tracking searcher's motion step (a sparse transition per speed class) against a dense matrix built from
    every pair of candidates by their distance, propagated step by step: the same belief, and no mass lost."""
    from uavplace.rl.tasks.tracking import transition

    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:16:2, 0:16:2]
    cells = np.stack([yy.ravel(), xx.ravel()], axis=1)
    cells = cells[rng.random(len(cells)) < 0.7]  # candidates missing where buildings stand
    q, stride = 0.3, 2
    dense = np.zeros((len(cells), len(cells)))
    for i, j in itertools.product(range(len(cells)), repeat=2):
        if np.abs(cells[i] - cells[j]).sum() == stride and (cells[i] == cells[j]).any():
            dense[i, j] = q / 4
    dense[np.diag_indices(len(cells))] = 1 - dense.sum(axis=0)
    sparse_t = transition(cells, stride, q)
    b = rng.random(len(cells))
    b /= b.sum()
    want, got = b.copy(), b.copy()
    for _ in range(5):
        want, got = dense @ want, sparse_t @ got
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert got.sum() == pytest.approx(1.0)


def test_fit_motion_reads_the_routes_speeds(root):
    from uavplace.rl.tasks.tracking import fit_motion

    motion = fit_motion([load_bundle("walk", root=root)])
    speeds = load_bundle("walk", root=root).routes.groupby("route")["speed_mps"].first().round(1)
    assert set(motion.speeds_mps) == set(speeds) and sum(motion.weights) == pytest.approx(1.0)


def _walk_constants():  # noqa: ANN202 - a PhysicsConstants
    """A physics tier for the tracking searcher's tests on the walk cities (constants set by hand, no fit)."""
    from uavplace.rl.predictor import PhysicsConstants

    return PhysicsConstants(intercept_db=-20, log_d_db=-23, wall_db=-9, diffraction_weight=0.1,
                            dead_level_db=-13, dead_scale_db=4, error_db=10)  # fmt: skip


def test_tracking_searcher_reads_only_what_it_measures(root):
    """The tracking searcher (predicted maps, a belief carried through time) moves exactly as before when the user's
    maps are scrambled off its path at every route point and the routes moved (``tests.scramble.tracking``), and
    covers the user in some steps."""
    from uavplace.rl.config import SearchConfig
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
    from uavplace.rl.tasks.tracking import TrackingSearchPolicy, fit_motion

    bundle = load_bundle("walk", root=root)
    constants = _walk_constants()
    policy = TrackingSearchPolicy(MapSearchPolicy(constants, SearchConfig(stride=1)), fit_motion([bundle]))
    task = TrackingConfig(horizon=24, window=9)
    routes = RouteSet([bundle], task)
    episodes = routes.sample_episodes(10, np.random.default_rng(1))
    first = run_tracking(routes, policy, episodes, num_envs=5, record=True)
    assert first.covered.any()
    rng = np.random.default_rng(0)
    for k in range(len(episodes)):
        keep = scramble.visited(routes.sinr.shape[1:], first.path[k])
        again = run_tracking(scramble.tracking(routes, keep, rng), policy, episodes[k : k + 1], num_envs=1, record=True)
        assert np.array_equal(again.path[0], first.path[k]), f"episode {k}: moves changed off its path"


def test_motion_defaults_are_the_training_routes_fit(tmp_path):
    """The tracking searcher's default motion (``MotionModel()``) is ``fit_motion`` of the training cities with routes,
    trk-000 ... trk-003, as they are embedded."""
    from uavplace.rl.tasks.tracking import MotionModel, fit_motion

    bundles = []
    for city in (f"trk-00{i}" for i in range(4)):
        ingest_city(REPO / "data" / "raw" / city, tmp_path)
        build_city(city, BuildConfig(grid_m=4.0, altitude_m=10.0, crop=True), tmp_path)
        bundles.append(load_bundle(city, root=tmp_path))
    assert fit_motion(bundles) == MotionModel()
    with pytest.raises(ValueError):
        MotionModel(speeds_mps=(1.0,), weights=(0.5,))


def test_tracking_searcher_plays_one_city_after_another(root, tmp_path):
    """The report plays each city with the same searcher: a city whose canvas has the same number as the last one's
    but other candidates gets its own motion (the first report of three cities once failed on it)."""
    from uavplace.rl.config import SearchConfig
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
    from uavplace.rl.tasks.tracking import MotionModel, TrackingSearchPolicy

    other = tmp_path / "p"
    ingest_city(write_grid_city(tmp_path / "raw", nx=8, ny=6, n_tx=3, seed=5, dead_share=0.0, routes=ROUTES), other,
                name="walk2")  # fmt: skip
    build_city("walk2", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-45.0), other)
    constants = _walk_constants()
    policy = TrackingSearchPolicy(MapSearchPolicy(constants, SearchConfig(stride=1)), MotionModel())
    task = TrackingConfig(horizon=12, window=9)
    for bundle in (load_bundle("walk", root=root), load_bundle("walk2", root=other)):
        routes = RouteSet([bundle], task)
        played = run_tracking(routes, policy, routes.sample_episodes(6, np.random.default_rng(0)), num_envs=3)
        assert len(played.table) == 6


def test_tracking_searcher_moves_the_same_whatever_the_settings_it_does_not_read(root):
    """``TrackingSearchPolicy.unread_settings`` (which ``uavrl report --task tracking --search`` refuses) are unread:
    each changed from its default, the searcher moves exactly as before (where a setting it reads moves it)."""
    from uavplace.rl.config import SearchConfig
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
    from uavplace.rl.tasks.tracking import TrackingSearchPolicy, fit_motion

    bundle = load_bundle("walk", root=root)
    constants = _walk_constants()
    routes = RouteSet([bundle], TrackingConfig(horizon=24, window=9))
    episodes = routes.sample_episodes(6, np.random.default_rng(2))
    changed = {"planner": "info", "fleet_plan": "makespan", "info_weight": 0.9, "info_radius": 5, "info_bin_db": 2.0,
               "error_share": 0.8, "kriging": "both", "error_range_cells": 3.0, "error_reach": 4, "error_memory": 8,
               "lookahead_targets": 4}  # fmt: skip
    assert set(changed) == set(TrackingSearchPolicy.unread_settings)
    paths = []
    for config in (SearchConfig(stride=1), SearchConfig(stride=1, **changed), SearchConfig(stride=1, temper=1.0)):
        policy = TrackingSearchPolicy(MapSearchPolicy(constants, config), fit_motion([bundle]))
        paths.append(run_tracking(routes, policy, episodes, num_envs=3, record=True).path)
    np.testing.assert_array_equal(paths[0], paths[1])
    assert not np.array_equal(paths[0], paths[2])  # a setting it reads moves it


def test_planted_cheaters_fail_the_tracking_scramble_test(root):
    """The tracking scramble test (maps off the path, routes moved and renumbered: tests/scramble.py) catches a policy
    that reads where the user's route goes, where the user is or the user's map now (tests/cheaters.py, handed the
    env); unprivileged, they cannot run on the ``TrackingView`` they receive, which leads to neither the env nor its
    routes; a policy that writes its view's public maps never enters a building and leaves the env's maps alone."""
    from tests.cheaters import PublicWriter, TrackingMapPeeker, TrackingRouteReader, TrackingUserSeeker
    from uavplace.rl.tasks.tracking import TrackingEnv

    routes = RouteSet([load_bundle("walk", root=root)], TrackingConfig(horizon=24, window=9))
    episodes = routes.sample_episodes(10, np.random.default_rng(1))
    for cheater in (TrackingRouteReader(), TrackingUserSeeker(), TrackingMapPeeker()):
        _, changed = scramble.replay_tracking(routes, cheater, episodes, np.random.default_rng(0))
        assert any(changed), f"{cheater.name} passed the scramble test"
        cheater.privileged = False
        with pytest.raises(AttributeError):
            run_tracking(routes, cheater, episodes[:2])
    blocked, height = routes.maps.blocked.copy(), routes.maps.height.copy()
    played = run_tracking(routes, PublicWriter(), episodes, record=True)
    canvas = routes.canvas[episodes[:, 0].astype(int)]
    assert not routes.maps.blocked[canvas[:, None], played.path[:, :, 0], played.path[:, :, 1]].any()
    assert np.array_equal(routes.maps.blocked, blocked) and np.array_equal(routes.maps.height, height)
    env = TrackingEnv(routes, 2)
    env.reset(0)
    view = env.agent_view()
    seen, todo = set(), [view]  # everything the view holds, followed through attributes, containers and array bases
    while todo:
        obj = todo.pop()
        if id(obj) in seen or isinstance(obj, (str, bytes, int, float, type)):
            continue
        seen.add(id(obj))
        assert all(obj is not held for held in (env, routes, routes.maps, *routes.bundles)), f"a view reaches {obj!r}"
        assert not (isinstance(obj, np.ndarray) and np.shares_memory(obj, routes.sinr)), "a view reaches a user's map"
        if isinstance(obj, np.ndarray):
            todo += [obj.base] if obj.base is not None else []
        elif isinstance(obj, dict):
            todo += list(obj.values())
        elif isinstance(obj, (list, tuple)):
            todo += list(obj)
        elif hasattr(obj, "__dict__"):
            todo += list(vars(obj).values())
    assert len(seen) > 10  # the walk went through the view's arrays and public maps


def test_a_tracking_uav_reads_with_the_error_and_is_judged_on_the_truth(root):
    """With a measurement error (``TrackingConfig.measurement``), the UAV's memory holds the reading (true plus an
    error of about the declared spread at live cells) while coverage is judged on the true SINR: the re-planning
    genie, which reads the maps, covers the same steps with the error on as without."""
    from uavplace.rl.config import MeasurementSettings
    from uavplace.rl.tasks.tracking import TrackingEnv

    noisy = TrackingConfig(horizon=24, window=9, measurement=MeasurementSettings(sigma_db=4.0))
    exact = RouteSet([load_bundle("walk", root=root)], TrackingConfig(horizon=24, window=9))
    routes = RouteSet([load_bundle("walk", root=root)], noisy)
    episodes = routes.sample_episodes(10, np.random.default_rng(1))
    a, b = (run_tracking(r, ReplanningGenie(), episodes, record=True) for r in (exact, routes))
    np.testing.assert_array_equal(a.covered, b.covered)
    env = TrackingEnv(routes, 64)
    env.reset(0)
    errors = []
    for _ in range(20):
        y, x, point = env.pos[:, 0], env.pos[:, 1], env.point()
        live = ~routes.dead[point, y, x]
        errors.append((env.memory[np.arange(64), y, x] - routes.sinr[point, y, x])[live])
        env.step(np.full(64, 4))
    error = np.concatenate(errors)
    assert len(error) > 300 and 3.5 < error.std() < 4.5


def test_a_tracking_map_that_errs_reaches_the_canvas_and_never_the_genie(root):
    """A map error of the tracking task is its canvas's (the height channel and the public maps: the walk city is open
    ground, so its heights stay); the re-planning genie covers the same steps with it as without."""
    from uavplace.rl.config import MapErrorSettings

    error = MapErrorSettings(height_sigma_m=3.0, shift_m=2.0, seed=1)
    erring = TrackingConfig(horizon=24, window=9, map_error=error)
    exact = RouteSet([load_bundle("walk", root=root)], TrackingConfig(horizon=24, window=9))
    routes = RouteSet([load_bundle("walk", root=root)], erring)
    assert routes.maps.config.map_error == error and np.array_equal(exact.maps.blocked, routes.maps.blocked)
    episodes = routes.sample_episodes(10, np.random.default_rng(1))
    a, b = (run_tracking(r, ReplanningGenie(), episodes, record=True) for r in (exact, routes))
    np.testing.assert_array_equal(a.covered, b.covered)

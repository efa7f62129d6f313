"""The fleet task (rl/tasks/fleet/): its oracle against a search over the fleet's joint positions, its moves, its
shared measurements and its episode lists."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from tests import scramble
from uavplace.rl.tasks.fleet import FLEET_MOVES, BatchedFleet, FleetCity, FleetConfig, FleetMaps, FleetView, oracle_steps
from uavplace.rl.world.maps import MOVES


def _city(seed: int, side: int = 7, users: int = 4, walls: int = 6) -> FleetCity:
    """A small made-up city: a few blocked cells, each user's SINR falling off with distance from its position."""
    rng = np.random.default_rng(seed)
    legal = np.ones((side, side), bool)
    legal.ravel()[rng.choice(side * side, walls, replace=False)] = False
    yy, xx = np.mgrid[:side, :side]
    where = np.argwhere(legal)[rng.choice(int(legal.sum()), users, replace=False)]
    sinr = np.stack([12.0 - 4.0 * np.hypot(yy - y, xx - x) for y, x in where]).astype(np.float32)
    height = np.where(legal, -10.0, 10.0).astype(np.float32)
    return FleetCity(f"made-{seed}", f"v{seed}", legal, height, sinr, legal & (sinr >= 5.0))


def _joint_search(city: FleetCity, users: np.ndarray, starts: np.ndarray, p_t_db: float) -> int:
    """The fewest steps until every user is served, by breadth-first search over the fleet's joint positions with
    the task's move rules (written out again here, independently of ``BatchedFleet``)."""
    ny, nx = city.legal.shape
    k = len(starts)

    def served(state: tuple) -> bool:
        return all(any(city.sinr_db[u][y, x] >= p_t_db for y, x in state) for u in users)

    def moves(state: tuple):  # noqa: ANN202
        for actions in np.ndindex(*(len(FLEET_MOVES),) * k):
            new: list[tuple[int, int]] = []
            for i, a in enumerate(actions):
                y, x = state[i][0] + FLEET_MOVES[a][0], state[i][1] + FLEET_MOVES[a][1]
                ok = 0 <= y < ny and 0 <= x < nx and city.legal[y, x]
                ok = ok and all((y, x) != state[j] for j in range(k) if j != i) and (y, x) not in new[:i]
                new.append((int(y), int(x)) if ok else state[i])
            yield tuple(new)

    first = tuple((int(y), int(x)) for y, x in starts)
    seen, queue = {first: 0}, deque([first])
    while queue:
        state = queue.popleft()
        if served(state):
            return seen[state]
        for nxt in moves(state):
            if nxt not in seen:
                seen[nxt] = seen[state] + 1
                queue.append(nxt)
    raise AssertionError("no joint position serves every user")


@pytest.mark.parametrize("seed", range(4))
def test_oracle_is_the_joint_search(seed):
    config = FleetConfig(uavs=2, users=3, window=3)
    maps = FleetMaps([_city(seed)], config)
    episodes = maps.episode_list(6, seed)
    got = oracle_steps(maps, episodes)
    city, users, starts = maps.split(episodes)
    want = [_joint_search(maps.cities[0], users[e], starts[e], config.p_t_db) for e in range(len(episodes))]
    np.testing.assert_array_equal(got, want)
    assert (got > 0).all()


def test_moves_shared_measurements_and_the_end():
    config = FleetConfig(uavs=3, users=2, window=5, t_max=40)
    maps = FleetMaps([_city(7, side=9, users=3, walls=10)], config)
    episodes = maps.episode_list(8, 0)
    env = BatchedFleet(maps, 8)
    env.begin(np.arange(8), episodes, np.arange(8))
    rng = np.random.default_rng(0)
    best = oracle_steps(maps, episodes)
    ended = np.full(8, -1)
    for t in range(config.t_max):
        mask = env.action_mask()
        assert mask[..., 4].all()
        actions = np.array([[rng.choice(np.flatnonzero(m)) for m in row] for row in mask])
        running = ~env.done
        _, terminated, truncated = env.step(actions)
        ended[terminated] = t + 1
        for e in np.flatnonzero(running):  # never two UAVs on one cell, never on a blocked one
            cells = {tuple(c) for c in env.pos[e]}
            assert len(cells) == config.uavs
            assert not env.maps.blocked[0, env.pos[e, :, 0], env.pos[e, :, 1]].any()
        if env.done.all():
            break
    assert (ended[ended > 0] >= best[ended > 0]).all()  # nobody beats the oracle
    for e in range(8):  # every cell the fleet visited holds each user's SINR there, for every UAV's window alike
        p = maps.pad
        for n in range(config.users):
            seen = env.visits[e] > 0
            want = maps.sinr[0, env.users[e, n]][seen]
            np.testing.assert_array_equal(env.memory[e, n][seen], want)
        if ended[e] > 0:
            assert (env.served_at[e] >= 0).all() and env.served_at[e].max() <= ended[e]
    obs = env.observe()
    assert obs.shape == (8, 3, 4, 5, 5)
    h = config.window // 2
    y, x = env.pos[0, 0]
    np.testing.assert_array_equal(obs[0, 0, 2], env.memory[0, 0, y - h : y + h + 1, x - h : x + h + 1])
    assert p == h


def test_episode_lists_are_prefixes_and_keys_name_episodes():
    config = FleetConfig(uavs=2, users=2, window=3)
    maps = FleetMaps([_city(1), _city(2)], config)
    long, short = maps.episode_list(12, 5), maps.episode_list(4, 5)
    np.testing.assert_array_equal(long[:4], short)
    assert not np.array_equal(maps.episode_list(4, 6), short)
    keys = maps.episode_keys(long)
    city, _, starts = maps.split(long)
    named = [(int(c), *s.ravel().tolist()) for c, s in zip(city, starts, strict=True)]
    assert len(set(keys.tolist())) == len(set(named))  # named by the city and the starts: the users name nothing
    swapped = long.copy()
    swapped[:, 1 : 1 + config.users] = swapped[::-1, 1 : 1 + config.users]  # other users, the same starts
    np.testing.assert_array_equal(maps.episode_keys(swapped), keys)
    np.testing.assert_array_equal(maps.episode_keys(long[::-1]), keys[::-1])
    from uavplace.schemas import InputError

    with pytest.raises(InputError, match="made-1: users: fewer traced users"):
        FleetMaps([_city(1, users=2)], FleetConfig(users=3, window=3))
    c = _city(1)
    unserved = FleetCity(c.name, c.version, c.legal, c.height_m, c.sinr_db, np.zeros_like(c.target))  # no target cell
    with pytest.raises(InputError, match="p_t_db: no fleet episode of 2 users and 2 UAVs found in 1000 draws at P_T = 5"):
        FleetMaps([unserved], FleetConfig(users=2, window=3)).episode_list(1, 0)


def test_gymnasium_checker_passes(tiny):
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import uavplace.rl  # noqa: F401  (registers the environments)

    env = gym.make("uavplace/UavFleet-v0", dataset="tiny", root=str(tiny), uavs=2, users=2, window=9, t_max=20)
    check_env(env.unwrapped)
    obs, info = env.reset(seed=3)
    again, _ = env.reset(seed=3)
    np.testing.assert_array_equal(obs, again)
    assert obs.shape == (2, 4, 9, 9) and info["action_mask"].shape == (2, 5)
    for _ in range(20):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        if terminated or truncated:
            break
    assert terminated or truncated


def test_pettingzoo_parallel_api_test_passes(tiny):
    """The fleet as a PettingZoo parallel env (rl/tasks/fleet/zoo.py): PettingZoo's own API test, seeding, one agent a UAV, the
    shared reward and end, the per-agent action masks; an agent given no action stays."""
    pytest.importorskip("pettingzoo", reason="PettingZoo missing (pip install -e '.[zoo]')")
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    from uavplace.rl.tasks.fleet.zoo import parallel_env

    def make():  # noqa: ANN202
        return parallel_env("tiny", root=str(tiny), uavs=2, users=2, window=9, t_max=20)

    parallel_api_test(make(), num_cycles=40)
    parallel_seed_test(make, num_cycles=10)
    env = make()
    obs, infos = env.reset(seed=3)
    assert env.agents == ["uav_0", "uav_1"] and obs["uav_0"].shape == (4, 9, 9) and infos["uav_1"]["action_mask"].shape == (5,)
    before = infos["uav_1"]["position"].copy()
    obs, rewards, terms, truncs, infos = env.step({"uav_0": 0})
    np.testing.assert_array_equal(infos["uav_1"]["position"], before)  # no action: it stays
    assert len(set(rewards.values())) == 1 and len(set(terms.values())) == 1


def test_pettingzoo_env_refuses_what_is_not_in_its_spaces(tiny):
    """Overrides are validated as the command line's settings (an unknown one, uavs=99 or 0, users=0 refused before
    any map is read); an action outside the action space (-1, 5, 2.7, '3', 2**70, 1e300), an unknown agent, a step
    before reset() or after the episode ended: each one ValueError, never a numpy traceback or a coerced move."""
    pytest.importorskip("pettingzoo", reason="PettingZoo missing (pip install -e '.[zoo]')")
    from uavplace.rl.tasks.fleet.zoo import parallel_env

    for bad, field in (
        ({"uavs": 99}, "uavs"),
        ({"uavs": 0}, "uavs"),
        ({"users": 0}, "users"),
        ({"no_such_field": 1}, "no_such_field"),
    ):
        with pytest.raises(ValueError, match=rf"^FleetConfig\.{field}: "):  # one line naming the field
            parallel_env("tiny", root=str(tiny), **bad)
    env = parallel_env("tiny", root=str(tiny), uavs=2, users=2, window=9, t_max=3)
    with pytest.raises(ValueError, match="before reset"):
        env.step({"uav_0": 0})
    env.reset(seed=0)
    for action in (-1, 5, 2.7, -0.5, "3", 2**70, 1e300, None, np.float32(1)):
        with pytest.raises(ValueError, match="action space"):
            env.step({"uav_0": action})
    with pytest.raises(ValueError, match="not live agents"):
        env.step({"uav_7": 0})
    while env.agents:
        env.step({"uav_0": np.int64(4), "uav_1": 4})
    with pytest.raises(ValueError, match="after the episode ended"):
        env.step({"uav_0": 0})
    fleet = env.fleet  # the Gymnasium env beneath it
    fleet.reset(seed=1)
    for action in ([0], [0, 5], [0.5, 1], ["1", "2"]):
        with pytest.raises(ValueError, match="action space"):
            fleet.step(np.array(action))


def _moves_alike_scrambled(maps: FleetMaps, policy, episodes: np.ndarray, paths, rng: np.random.Generator) -> None:  # noqa: ANN001
    """Each episode's ``paths[e]`` (``tests.scramble.fleet_paths``) played again, alone, with its users' maps scrambled
    off the cells the fleet visited and its users moved (``tests.scramble.fleet``): the same path."""
    for e, path in enumerate(paths):
        keep = scramble.visited(maps.sinr.shape[2:], path)
        city, users, _ = maps.split(episodes[e : e + 1])
        other = scramble.fleet(maps, int(city[0]), users[0], keep, rng)
        np.testing.assert_array_equal(scramble.fleet_paths(other, policy, episodes[e : e + 1])[0], path, err_msg=policy.name)
    if hasattr(policy, "bind"):
        policy.bind(maps)  # the real maps again


def test_baselines_read_only_what_the_fleet_measured():
    """The fleet's random walk and greedy hill-climbing move the same when every user's map is scrambled off the
    cells the fleet visited; they play the same episodes alike in a batch and alone."""
    from uavplace.rl.tasks.fleet import FleetGreedy, FleetRandomWalk, run_fleet

    config = FleetConfig(uavs=2, users=2, window=5, t_max=60)
    maps = FleetMaps([_city(3, side=10, users=4, walls=12)], config)
    episodes = maps.episode_list(6, 1)
    rng = np.random.default_rng(0)
    for policy in (FleetRandomWalk(seed=2), FleetGreedy(seed=2)):
        first = scramble.fleet_paths(maps, policy, episodes)
        _moves_alike_scrambled(maps, policy, episodes, first, rng)
        table = run_fleet(maps, policy, episodes, num_envs=4)
        alone = [len(p) - 1 for p in first]
        won = table["success"].to_numpy()
        np.testing.assert_array_equal(table["steps"].to_numpy()[won], np.array(alone)[won])
        assert (table["steps"][won] >= table["oracle_steps"][won]).all() and (table["spl"] <= 1).all()


@pytest.mark.parametrize(
    ("plan", "planner"), [("makespan", "cover"), ("product", "cover"), ("union", "cover"), ("union", "info")]
)
def test_fleet_searcher_serves_the_tiny_city_from_what_it_measured(tiny, plan, planner):
    """The map searcher run for the fleet (one belief per user, physics tier) serves the tiny city's user sets, the
    same in a batch and alone, and moves the same when every user's map is scrambled off the cells the fleet visited,
    with every plan, and with the information of a measurement near the UAVs added (``planner`` info)."""
    from tests.conftest import REPO
    from uavplace.dataset.bundle import load_bundle
    from uavplace.rl.config import SearchConfig
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.fleet import FleetSearcher, run_fleet

    config = FleetConfig(uavs=2, users=2, window=9, t_max=60)
    maps = FleetMaps.of([load_bundle("tiny", root=str(tiny))], config)
    episodes = maps.episode_list(6, 0)
    predictor = load_predictor(REPO / "data" / "agents" / "searcher" / "predictor.json")
    policy = FleetSearcher(predictor, SearchConfig(fleet_plan=plan, planner=planner)).bind(maps)
    table = run_fleet(maps, policy, episodes, num_envs=3)
    assert table["success"].mean() >= 0.8
    alone = [run_fleet(maps, policy, episodes[e : e + 1], num_envs=1)["steps"][0] for e in range(len(episodes))]
    np.testing.assert_array_equal(table["steps"], alone)  # a batch whose rows end one by one plays each as alone
    _moves_alike_scrambled(maps, policy, episodes, scramble.fleet_paths(maps, policy, episodes[:3]), np.random.default_rng(1))
    with pytest.raises(ValueError, match="bundles"):
        FleetSearcher(predictor).bind(FleetMaps([_city(0)], FleetConfig(window=3)))


@pytest.mark.parametrize("seed", range(6))
def test_fleet_searchers_makespan_plan_is_the_best_by_brute_force(seed):
    """The makespan plan's assignment and cells score as much as the best of every assignment of the users to the UAVs
    and every cell of each UAV that has users, scored by brute force: the product of the UAVs' probabilities of
    serving their users times the discount of the longest of their paths."""
    import itertools

    from tests.conftest import REPO
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.fleet import FleetSearcher
    from uavplace.rl.tasks.fleet.maps import user_subsets

    rng = np.random.default_rng(seed)
    users, uavs, cells = 3, 2, 7
    cover = rng.choice([0.0, 0.1, 0.5, 0.9, 1.0], size=(users, cells)).astype(np.float32)
    moves = rng.integers(0, 9, size=(uavs, cells)).astype(np.float32)
    moves[:, rng.integers(cells)] = np.inf  # a cell neither UAV reaches
    policy = FleetSearcher(load_predictor(REPO / "data" / "agents" / "searcher" / "predictor.json"))
    paths = [(None, None, m) for m in moves]

    def score(plan: dict[int, int], owner: tuple[int, ...]) -> float:
        p = np.prod([cover[n, plan[owner[n]]] for n in range(users)])
        return float(p * policy.searcher.discount(np.float32(max(moves[u, c] for u, c in plan.items()))))

    best = 0.0
    for owner in itertools.product(range(uavs), repeat=users):
        mine = sorted(set(owner))
        for where in itertools.product(*(np.flatnonzero(np.isfinite(moves[u])) for u in mine)):
            best = max(best, score(dict(zip(mine, where, strict=True)), owner))
    served = {mine: np.prod(cover[list(mine)], axis=0) for mine in user_subsets(users)}
    plan = policy._makespan_plan(served, users, policy._reach(paths))
    assert np.isclose(max(score(plan, o) for o in itertools.product(sorted(plan), repeat=users)), best, rtol=1e-6)


@pytest.mark.parametrize("seed", range(6))
def test_fleet_searchers_union_plan_no_uav_can_raise_by_brute_force(seed):
    """The union plan's cells score, by brute force, the probability that every user is served by some UAV (the
    cells' covers independent) times the discount of the longest path; it scores at least its start, and no UAV
    moved alone to any reachable cell scores more (a coordinate-wise optimum); a UAV without users may move."""
    from tests.conftest import REPO
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.fleet import FleetSearcher

    rng = np.random.default_rng(seed)
    users, uavs, cells = 3, 2, 7
    cover = rng.choice([0.0, 0.1, 0.5, 0.9, 1.0], size=(users, cells)).astype(np.float32)
    moves = rng.integers(0, 9, size=(uavs, cells)).astype(np.float32)
    moves[:, rng.integers(cells)] = np.inf  # a cell neither UAV reaches
    moves[0, 0] = moves[1, 1] = 0  # where the UAVs stand
    policy = FleetSearcher(load_predictor(REPO / "data" / "agents" / "searcher" / "predictor.json"))

    def score(plan: dict[int, int]) -> float:
        served = [1 - np.prod([1 - float(cover[n, c]) for c in plan.values()]) for n in range(users)]
        return float(np.prod(served) * policy.searcher.discount(np.float32(max(moves[u, c] for u, c in plan.items()))))

    start = {0: 0, 1: 1}
    paths = [(None, None, m) for m in moves]
    plan = policy._union_plan(cover, paths, policy._reach(paths), start)
    assert set(plan) == {0, 1} and all(np.isfinite(moves[u, c]) for u, c in plan.items())
    assert score(plan) >= score(start) * (1 - 1e-6)
    for u in range(uavs):
        for c in np.flatnonzero(np.isfinite(moves[u])):
            assert score({**plan, u: int(c)}) <= score(plan) * (1 + 1e-6), (u, c)


def test_fleet_searchers_information_is_each_users_near_the_uavs(tiny):
    """With ``planner`` info, each user's cover gains ``info_weight`` times the information a measurement tells about
    that user's cell (``BeliefModel.information``, checked by hand in tests/test_searcher.py) at the unvisited cells
    within ``info_radius`` moves of some UAV, capped at 1, and nothing elsewhere."""
    from tests.conftest import REPO
    from uavplace.dataset.bundle import load_bundle
    from uavplace.rl.config import SearchConfig
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.fleet import FleetSearcher, FleetView

    config = FleetConfig(uavs=2, users=2, window=9, t_max=60)
    maps = FleetMaps.of([load_bundle("tiny", root=str(tiny))], config)
    predictor = load_predictor(REPO / "data" / "agents" / "searcher" / "predictor.json")
    policy = FleetSearcher(predictor, SearchConfig(planner="info", info_weight=0.5)).bind(maps)
    env = BatchedFleet(maps, 1)
    env.begin(np.array([0]), maps.episode_list(1, 3), np.array([0]))
    view = FleetView.of(env)
    policy.reset(np.arange(1), 1, config.uavs)
    policy.act(env.action_mask(), view)  # the beliefs after the first measurements
    cm = policy.searcher.canvas_maps(policy.public, policy.symmetries * int(view.city[0]))
    p = config.window // 2
    cols = cm.index[view.pos[0, :, 0] - p, view.pos[0, :, 1] - p]
    paths = [policy.searcher.paths_from(policy.public, policy.symmetries * int(view.city[0]), cm, int(c)) for c in cols]
    seen = view.visits[0, cm.legal[:, 0] + p, cm.legal[:, 1] + p] > 0
    cover = np.full((config.users, len(cm.legal)), 0.3, np.float32)
    got = policy._with_information(cm, cover, seen, paths, 0, view)
    near = (np.min([m for _, _, m in paths], axis=0) <= policy.searcher.config.info_radius) & ~seen
    assert near.any() and (~near).any()
    np.testing.assert_array_equal(got[:, ~near], cover[:, ~near])
    floor_db = float(policy.public.settings[int(view.city[0])]["floor_db"])
    for n in range(config.users):
        bits = policy.searcher.information(cm, policy.log_b[0][n], np.flatnonzero(near), floor_db, config.p_t_db)
        np.testing.assert_allclose(got[n, near], np.minimum(1.0, 0.3 + 0.5 * bits), rtol=1e-6)


def test_independent_agents_deal_users_and_read_only_what_the_fleet_measured(tiny):
    """Every UAV runs the shipped placement agent on the users dealt to it: a UAV keeps whom it serves, the others
    are dealt to the UAV holding the fewest, which takes the one it hears strongest; its agent moves the same when
    every user's map is scrambled off the cells the fleet visited, and alike in a batch and alone."""
    from tests.conftest import REPO
    from uavplace.dataset.bundle import load_bundle
    from uavplace.eval.evaluate import load_agent
    from uavplace.rl.tasks.fleet import FleetPlacement, FleetView, run_fleet

    agent = load_agent(REPO / "data" / "agents" / "best", 0.096, 0)
    config = FleetConfig(uavs=2, users=3, window=9, t_max=60)
    maps = FleetMaps.of([load_bundle("tiny", root=str(tiny))], config)
    policy = FleetPlacement(agent.policy, agent.config.env_config(evaluation=True), agent.name).bind(maps)
    assert policy.name == f"independent {agent.name}"
    episodes = maps.episode_list(6, 0)

    env = BatchedFleet(maps, len(episodes))  # the deal, written out again: at the starts, then after random moves
    env.begin(np.arange(len(episodes)), episodes, np.arange(len(episodes)))
    rng = np.random.default_rng(0)
    for _ in range(4):
        here = env.sinr_here(np.arange(len(episodes)))  # [E, K, N]
        groups, served = policy.deal(FleetView.of(env))
        np.testing.assert_array_equal(served, here >= config.p_t_db)
        for e in range(len(episodes)):
            want = np.zeros((2, 3), bool)
            for uav in range(2):
                for user in range(3):
                    want[uav, user] = here[e, uav, user] >= config.p_t_db and not want[:, user].any()
            while not want.any(axis=0).all():
                uav = min(range(2), key=lambda k: (want[k].sum(), k))
                left = [u for u in range(3) if not want[:, u].any()]
                want[uav, max(left, key=lambda u: here[e, uav, u])] = True
            np.testing.assert_array_equal(groups[e], want)
        env.step(np.where(env.action_mask(), rng.random((len(episodes), 2, 5)), -1).argmax(axis=2))

    table = run_fleet(maps, policy, episodes, num_envs=3)
    alone = scramble.fleet_paths(maps, policy, episodes)
    won = table["success"].to_numpy()
    assert won.any()
    np.testing.assert_array_equal(table["steps"].to_numpy()[won], np.array([len(p) - 1 for p in alone])[won])
    _moves_alike_scrambled(maps, policy, episodes, alone[:3], np.random.default_rng(2))
    with pytest.raises(ValueError, match="belief"):
        hybrid = load_agent(REPO / "data" / "agents" / "hybrid", 0.096, 0)
        FleetPlacement(hybrid.policy, hybrid.config.env_config(evaluation=True), hybrid.name)


def test_fleet_report_writes_its_tables_and_never_replaces_a_stranger(tiny, tmp_path):
    import re

    from click.testing import CliRunner

    from tests.conftest import REPO
    from uavplace.cli import uavrl

    out = tmp_path / "fleet"
    args = ["report", "--task", "fleet", "--dataset", "tiny", "--root", str(tiny), "--episodes", "12", "--users", "2",
            "--bootstrap", "200", "--predictor", str(REPO / "data" / "agents" / "searcher" / "predictor.json"), "--quiet"]  # fmt: skip
    res = CliRunner().invoke(uavrl, [a for a in args if a != "--quiet"] + ["--out", str(out)])
    assert res.exit_code == 0, res.output
    assert re.search(r"fleet report city 1 of 1: tiny, method 1 of \d+: map searcher", res.output)  # a log: plain lines
    import pandas as pd

    table = pd.read_csv(out / "results.csv")
    best = "independent PQN + GRU x 3 (best)"  # the shipped agents, run on every UAV by default
    fleet = "PQN + GRU (best, fleet)"
    assert list(table["method"]) == ["oracle", "map searcher", best, fleet, "steered random walk", "greedy hill-climbing"]
    assert table.loc[table.method == "oracle", "spl"].item() == 1.0
    assert f"success - {best}" in (out / "fleet.md").read_text()
    import json

    assert json.loads((out / "fleet.json").read_text())["config"]["search"]["fleet_plan"] == "union"  # what played
    from uavplace.eval.reports.fleet.page import summary_rows

    rows = summary_rows(table, pd.read_csv(out / "differences.csv"), 60)
    assert rows[0] == ["method", "tiny: success / median steps (x oracle)", f"tiny: minus {best}"]
    assert [r[0] for r in rows[1:]] == list(table["method"]) and rows[3][2] == "-"  # the reference against itself
    oracle = table[table.method == "oracle"].iloc[0]
    assert rows[1][1].startswith("100.0 % [100.0, 100.0 %] / ") and rows[1][1].endswith("(1.00)") and oracle.success == 1
    assert (out / "tiny-episodes.png").stat().st_size > 0 and "tiny-episodes.png" in (out / "fleet.md").read_text()
    page = (out / "fleet.html").read_text()  # the placement and tracking reports' style: self-contained
    assert page.count("<table") == 2 and page.count('src="data:image/png;base64,') == 1 and best in page
    assert 'content="uavplace fleet report"' in page and "Figure 1." in page and "<script" not in page
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("x")
    res = CliRunner().invoke(uavrl, [*args, "--out", str(mine)])
    assert res.exit_code != 0 and (mine / "thesis.tex").read_text() == "x"
    res = CliRunner().invoke(uavrl, [*args, "--out", str(out), "--split", "test"])
    assert res.exit_code != 0 and "--task fleet" in res.output
    res = CliRunner().invoke(uavrl, [*args, "--out", str(out), "--run", str(REPO / "data" / "agents" / "hybrid")])
    assert res.exit_code != 0 and "belief" in res.output


def _fleet_run_config(**update):
    from uavplace.rl.agent.config import preset_config

    tiny = {"total_steps": 256, "num_envs": 8, "rollout_steps": 8, "batch_size": 32, "epochs": 2, "hidden": 16,
            "fovea": 5, "eval_every": 128, "eval_episodes": 6}  # fmt: skip
    fleet = {"uavs": 2, "users": 2, "window": 9, "t_max": 30}
    env = {"window": 9} | update.pop("env", {})
    return preset_config("best", task="fleet", fleet=fleet, env=env, **(tiny | update))


def test_fleet_env_for_the_learner_rewards_each_uav_for_its_own_users(tiny):
    """``FleetTrainEnv``: a row per UAV, observed as ``FleetPlacement`` deals; a row's reward is placement's on its
    UAV's dealt users (their weakest SINR's change, c_e on a cell the fleet never visited, the bonus when it comes to
    serve them all), nothing when it stays; a UAV kept still stays whatever it chose; the genie's moves shorten the way
    to a cell serving all its users."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.rl.tasks.fleet import FleetTrainEnv

    config = _fleet_run_config()
    env_config = config.env_config()
    maps = FleetMaps.of([load_bundle("tiny", root=str(tiny))], config.task.fleet())
    env = FleetTrainEnv(maps, env_config, 8)
    obs, info = env.reset(seed=3)
    assert obs.shape[0] == 8 and info["action_mask"].shape == (8, 4)
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(25):
        f = env.fleet
        groups, idle = env.deal.groups.copy(), env._idle.copy()
        before = FleetView.of(f).at_uavs()
        pos, visits = f.pos.copy(), f.visits.copy()
        genie = env.genie_moves()
        actions = rng.integers(0, 4, 8)
        _, reward, term, trunc, info = env.step(actions)
        for e in np.flatnonzero(~(term | trunc)[::2]):
            for k in range(2):
                r = reward[2 * e + k]
                if idle[e, k]:
                    assert r == 0 and (f.pos[e, k] == pos[e, k]).all()
                    continue
                mine = groups[e, k]
                y, x = f.pos[e, k]
                after = f.memory[e, mine, y, x]
                fresh = visits[e, y, x] == 0
                served = (after >= config.task.p_t_db).all() and not (before[e, k, mine] >= config.task.p_t_db).all()
                want = after.min() - before[e, k, mine].min() + env_config.c_e * fresh + env_config.success_bonus * served
                assert r == pytest.approx(want, abs=1e-4)
                reach = maps.group_reach(int(f.city[e]), tuple(np.flatnonzero(mine)))
                py, px = pos[e, k] - maps.pad
                for a in np.flatnonzero(genie[2 * e + k]):
                    assert reach[py + MOVES[a, 0], px + MOVES[a, 1]] < reach[py, px]
                checked += 1
    assert checked > 50


def test_the_fleet_channel_marks_the_other_uavs_and_a_placement_agent_widened_to_it_acts_the_same(tiny):
    """``EnvConfig.fleet_channel``: each UAV's observation marks (p_h_db) the cells of the other UAVs inside its
    window and nothing else, the other channels as without it; a network started from one without the channel
    (``add_input_channel``, for both architectures) gives the same Q values whatever the channel holds; placement
    and tracking runs refuse it."""
    import torch

    from uavplace.dataset.bundle import load_bundle
    from uavplace.eval.evaluate import agent_name
    from uavplace.rl.agent.config import preset_config
    from uavplace.rl.agent.network import FoveaQNetwork, QNetwork, add_input_channel
    from uavplace.rl.tasks.fleet import FleetPlacement
    from uavplace.schemas import InputError

    config = _fleet_run_config()
    maps = FleetMaps.of([load_bundle("tiny", root=str(tiny))], FleetConfig(uavs=2, users=2, window=9, t_max=30))
    plain_env = config.env_config()
    env = plain_env.model_copy(update={"fleet_channel": True})
    assert env.num_channels == plain_env.num_channels + 1 and env.fleet_index == env.num_channels - 4
    episodes = maps.episode_list(5, 1)
    fleet = BatchedFleet(maps, len(episodes))
    fleet.begin(np.arange(len(episodes)), episodes, np.arange(len(episodes)))
    rng = np.random.default_rng(1)
    inside = []
    for _ in range(12):
        view, mask = FleetView.of(fleet), fleet.action_mask()
        obs = FleetPlacement(None, env, "f").bind(maps)
        obs.reset_deal(np.arange(len(episodes)), len(episodes), 2)
        seen = obs.dealt(mask, view)[0].reshape(len(episodes), 2, env.num_channels, 9, 9)
        plain = FleetPlacement(None, plain_env, "p").bind(maps)
        plain.reset_deal(np.arange(len(episodes)), len(episodes), 2)
        without = plain.dealt(mask, view)[0].reshape(len(episodes), 2, plain_env.num_channels, 9, 9)
        np.testing.assert_array_equal(np.delete(seen, env.fleet_index, axis=2), without)
        for e in range(len(episodes)):
            for k in range(2):
                want = np.zeros((9, 9), np.float32)
                for j in set(range(2)) - {k}:
                    dy, dx = fleet.pos[e, j] - fleet.pos[e, k] + 4
                    inside.append(0 <= dy < 9 and 0 <= dx < 9)
                    if inside[-1]:
                        want[dy, dx] = env.p_h_db
                np.testing.assert_array_equal(seen[e, k, env.fleet_index], want)
        fleet.step(np.where(fleet.action_mask(), rng.random((len(episodes), 2, 5)), -1).argmax(axis=2))
    assert any(inside) and not all(inside)  # other UAVs inside a window and beyond it

    torch.manual_seed(0)
    c = plain_env.num_channels
    for net, wide in (
        (QNetwork(c, window=21, hidden=16, channels=(4, 4, 4)), QNetwork(c + 1, window=21, hidden=16, channels=(4, 4, 4))),
        (FoveaQNetwork(c, window=21, hidden=16, fovea=5, middle=True), FoveaQNetwork(c + 1, 21, hidden=16, fovea=5, middle=True)),
    ):
        net.eval(), wide.eval()
        wide.load_state_dict(add_input_channel(net.state_dict(), wide, 2))
        x = torch.randn(6, c, 21, 21) * 30
        x_wide = torch.cat([x[:, :2], torch.randn(6, 1, 21, 21) * 50, x[:, 2:]], dim=1)
        torch.testing.assert_close(wide(x_wide), net(x), rtol=0, atol=1e-5)
    for task in ("placement", "tracking"):
        with pytest.raises(InputError, match="fleet_channel marks the fleet's other UAVs"):
            preset_config("best", task=task, env={"fleet_channel": True})
    seeing = preset_config("best", task="fleet", env={"fleet_channel": True})
    assert agent_name(seeing) == "PQN + GRU (best, fleet, sees the fleet)"


def test_fleet_agent_trains_resumes_exactly_and_reports(tiny, tmp_path):
    """`uavrl train --task fleet`: one network for every UAV, learnt on fleet episodes, chosen on fixed validation
    episodes of the fleet; started from a trained network's weights (`init`); stopped and resumed it ends where a
    straight run ends; the fleet report plays it as a fleet-trained agent."""
    import pandas as pd
    import torch
    from click.testing import CliRunner

    from uavplace.cli import uavrl
    from uavplace.rl.agent.runs import read_run_json
    from uavplace.rl.agent.train import Trainer
    from uavplace.schemas import InputError

    straight = Trainer(_fleet_run_config(), ["tiny"], tiny, tmp_path / "a")
    straight.run()
    evals = pd.read_parquet(tmp_path / "a" / "eval.parquet")
    assert evals["step"].tolist() == [128, 256] and evals["success"].between(0, 1).all()
    assert read_run_json(tmp_path / "a").config.task.kind == "fleet"
    half = Trainer(_fleet_run_config(), ["tiny"], tiny, tmp_path / "b")
    half.run(stop_at=96)
    resumed = Trainer(_fleet_run_config(), ["tiny"], tiny, tmp_path / "b")
    resumed.load()
    resumed.run(resume=True)
    for a, b in zip(straight.agent.online.state_dict().values(), resumed.agent.online.state_dict().values(), strict=True):
        assert torch.equal(a, b)

    started = Trainer(_fleet_run_config(init=str(tmp_path / "a")), ["tiny"], tiny, tmp_path / "c")
    best = torch.load(tmp_path / "a" / "checkpoints" / "best.pt", weights_only=True)["online"]
    for name, value in started.agent.online.state_dict().items():
        assert torch.equal(value, best[name])
    with pytest.raises(InputError, match="do not fit"):
        Trainer(_fleet_run_config(init=str(tmp_path / "a"), hidden=8), ["tiny"], tiny, tmp_path / "d")
    seeing = Trainer(_fleet_run_config(init=str(tmp_path / "a"), env={"fleet_channel": True}), ["tiny"], tiny, tmp_path / "e")
    index = seeing.config.env.fleet_index  # the fleet channel added at zero weight to what it started from
    first = seeing.agent.online.state_dict()["fc.1.weight"].reshape(16, 2, -1, 25)
    assert not first[:, :, index].any()
    assert torch.equal(torch.cat([first[:, :, :index], first[:, :, index + 1 :]], 2).reshape(16, -1), best["fc.1.weight"])
    seeing.run()  # trained, it moves the same when every user's map is scrambled off the cells the fleet visited
    from uavplace.dataset.bundle import load_bundle
    from uavplace.eval.evaluate import load_agent
    from uavplace.rl.tasks.fleet import FleetPlacement

    agent = load_agent(tmp_path / "e", 0.096, 0, task="fleet")
    maps = FleetMaps.of([load_bundle("tiny", root=str(tiny))], seeing.config.task.fleet())
    policy = FleetPlacement(agent.policy, agent.config.env_config(evaluation=True), agent.name, prefix="").bind(maps)
    episodes = maps.episode_list(4, 0)
    _moves_alike_scrambled(maps, policy, episodes, scramble.fleet_paths(maps, policy, episodes), np.random.default_rng(3))

    # A city it never saw: a synthetic grid city.
    from tests.conftest import write_grid_city
    from uavplace.dataset.build import build_city
    from uavplace.ingest.pipeline import ingest_city
    from uavplace.schemas.bundle import BuildConfig

    root = tmp_path / "root"
    ingest_city(write_grid_city(tmp_path / "raw", nx=8, ny=7, n_tx=3, seed=5, dead_share=0.0), root, name="unseen")
    build_city("unseen", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-45.0), root)
    out = tmp_path / "report"
    args = ["report", "--task", "fleet", "--dataset", "unseen", "--root", str(root), "--run", str(tmp_path / "a"), "--uavs",
            "2", "--users", "2", "--episodes", "6", "--t-max", "30", "--bootstrap", "100", "--out", str(out), "--quiet"]  # fmt: skip
    result = CliRunner().invoke(uavrl, args)
    assert result.exit_code == 0, result.output
    assert "PQN + GRU (best, fleet)" in result.output


def test_fleet_searcher_moves_the_same_whatever_the_settings_it_does_not_read(tiny):
    """``FleetSearcher.unread_settings`` (which ``uavrl report --task fleet --search`` refuses) are unread: changed
    from their defaults, the fleet searcher makes the same moves (where a setting it reads, ``reach_cells``, moves it)."""
    from tests.conftest import REPO
    from uavplace.dataset.bundle import load_bundle
    from uavplace.rl.config import SearchConfig
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.fleet import FleetSearcher

    config = FleetConfig(uavs=2, users=2, window=9, t_max=60)
    maps = FleetMaps.of([load_bundle("tiny", root=str(tiny))], config)
    episodes = maps.episode_list(8, 0)
    predictor = load_predictor(REPO / "data" / "agents" / "searcher" / "predictor.json")
    changed = {"error_share": 0.8, "kriging": "both", "error_range_cells": 3.0, "error_reach": 4, "error_memory": 8,
               "lookahead_targets": 4}  # fmt: skip
    assert set(changed) == set(FleetSearcher.unread_settings)
    paths = [scramble.fleet_paths(maps, FleetSearcher(predictor, c).bind(maps), episodes)
             for c in (SearchConfig(), SearchConfig(**changed), SearchConfig(reach_cells=2.0))]  # fmt: skip
    assert all(np.array_equal(a, b) for a, b in zip(paths[0], paths[1], strict=True))
    assert not all(np.array_equal(a, b) for a, b in zip(paths[0], paths[2], strict=True))


def test_planted_cheaters_fail_the_fleet_scramble_test(tiny):
    """The fleet's scramble test (its users' maps off the fleet's cells, every user of the city moved:
    tests/scramble.py) catches a policy bound to the maps that reads where the users are or their maps
    (tests/cheaters.py), as the fleet searcher and the independent agents are bound."""
    from tests.cheaters import FleetMapPeeker, FleetUserSeeker
    from uavplace.dataset.bundle import load_bundle

    config = FleetConfig(uavs=2, users=2, window=9, t_max=40)
    maps = FleetMaps.of([load_bundle("tiny", root=str(tiny))], config)
    episodes = maps.episode_list(6, 0)
    rng = np.random.default_rng(4)
    for cheater in (FleetUserSeeker(), FleetMapPeeker()):
        paths = scramble.fleet_paths(maps, cheater, episodes)
        changed = []
        for e, path in enumerate(paths):
            city, users, _ = maps.split(episodes[e : e + 1])
            other = scramble.fleet(maps, int(city[0]), users[0], scramble.visited(maps.sinr.shape[2:], path), rng)
            again = scramble.fleet_paths(other, cheater, episodes[e : e + 1])[0]
            changed.append(again.shape != path.shape or not np.array_equal(again, path))
        assert any(changed), f"{cheater.name} passed the scramble test"
    env = BatchedFleet(maps, 1)  # a policy that writes its view's public maps writes a copy: the env's are as they were
    env.begin(np.array([0]), episodes[:1], np.array([0]))
    blocked, mask, view = maps.blocked.copy(), env.action_mask(), FleetView.of(env)
    for a in (view.blocked, view.height):
        a.flags.writeable = True
        a[...] = 0
    assert np.array_equal(maps.blocked, blocked) and np.array_equal(mask, env.action_mask())

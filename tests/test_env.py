"""The RL environment over bundles: spaces, reward, masks, rotation, memory, blind variant, seeding, genie, baselines."""

from __future__ import annotations

import json
from collections import deque

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st

import uavplace.rl  # noqa: F401  (registers the environments)
from tests.conftest import write_grid_city
from uavplace.dataset.build import build_city
from uavplace.dataset.difficulty import UNREACHABLE, steps_to_target
from uavplace.ingest.pipeline import ingest_city
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.tasks.placement.gym import UavPlacementEnv
from uavplace.rl.tasks.placement.policies import GeniePolicy, GreedyPolicy, RandomWalkPolicy
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.world.maps import MOVES, MapSet
from uavplace.rl.world.rows import decode_obs, encode_obs
from uavplace.schemas.bundle import BuildConfig


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """A 14 x 11 city, 3 users, two buildings (one above the 10 m altitude, one below), SINR spread around P_T."""
    tmp = tmp_path_factory.mktemp("env")
    raw = write_grid_city(tmp / "raw", nx=14, ny=11, n_tx=3, outputs=("power",), dead_share=0.1, seed=2)
    tall = [[26, -10], [38, -10], [38, -2], [26, -2], [26, -10]]
    low = [[46, 6], [58, 6], [58, 14], [46, 14], [46, 6]]
    fc = {
        "type": "FeatureCollection",
        "features": [
            {"type": "Feature", "properties": {"height_m": h}, "geometry": {"type": "Polygon", "coordinates": [ring]}}
            for ring, h in ((tall, 30.0), (low, 6.0))
        ],
    }
    (raw / "b.geojson").write_text(json.dumps(fc))
    ingest_city(raw, tmp / "p", name="tiny")
    build_city("tiny", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-58.0), tmp / "p")
    return tmp / "p"


@pytest.fixture
def maps(root):
    return MapSet.load("tiny", EnvConfig(t_max=60), root=str(root))


def test_check_env_and_registration(root):
    for env_id, channels in (("uavplace/UavPlacement-v0", 2), ("uavplace/BlindUavPlacement-v0", 1)):
        env = gym.make(env_id, dataset="tiny", root=str(root))
        check_env(env.unwrapped)
        assert env.observation_space.shape == (channels, 61, 61)
        obs, info = env.reset(seed=1)
        assert obs.shape == (channels, 61, 61) and info["action_mask"].shape == (4,)
        assert set(info) == {"action_mask", "sinr_db", "position"}  # nothing read off the user's map
        assert set(env.step(0)[4]) == {"action_mask", "sinr_db", "position", "illegal"}
    scored = gym.make("uavplace/UavPlacement-v0", dataset="tiny", root=str(root), evaluation_info=True)
    assert {"genie_steps", "view"} <= set(scored.reset(seed=1)[1])


def test_visit_counts_and_revisit_cost(root):
    """The env counts each cell's visits (the start once); ``revisit_cost`` takes that many times it off a move into
    a cell already visited, on top of the forgone new-cell bonus; ``neighbour_visits`` reads the counts."""
    maps = MapSet.load("tiny", EnvConfig(t_max=60, revisit_cost=2.0, rotate=False), root=str(root))
    env = BatchedEnv(maps, 1, autoreset=False)
    env.reset(seed=0)
    start = tuple(env.pos[0])
    a = int(np.flatnonzero(env.action_mask()[0])[0])
    b = (a + 2) % 4  # its opposite
    assert np.all(MOVES[a] == -MOVES[b])
    rewards = []
    for move in (a, b, a, b):
        before = env.sinr_here()[0]
        _, r, term, _, _ = env.step(np.array([move]))
        if term[0]:
            pytest.skip("the shuttle reached P_T")  # (not with this seed)
        rewards.append(float(r[0] - (env.sinr_here()[0] - before)))
    # Into the second cell (new: +c_E), back to the start (1 earlier visit), the second cell (1), the start (2).
    assert rewards == pytest.approx([1.2, -2.0, -2.0, -4.0])
    assert env.visits[0][start] == 3 and env.visits[0].sum() == 5 and env.visited[0].sum() == 2
    assert env.neighbour_visits()[0, a] == 2 and env.neighbour_visits()[0, b] == 0


def test_scenarios_have_starts_below_target(maps):
    assert len(maps.startable) == 3
    eps = maps.sample_episodes(500, np.random.default_rng(0))
    v, y, x = eps.T
    assert np.all(maps.sinr[v, y, x] < 5.0) and not maps.dead[v, y, x].any()
    assert not maps.blocked[maps.view_map[v], y, x].any()


def test_reward_termination_and_memory(maps):
    env = BatchedEnv(maps, 8, autoreset=False)
    env.reset(seed=4)
    cfg = maps.config
    rng = np.random.default_rng(0)
    for _ in range(40):
        mask = env.action_mask()
        a = np.argmax(rng.random(mask.shape) * mask, axis=1)
        before = env.sinr_here().copy()
        target = env.pos + MOVES[a]
        fresh = ~env.visited[np.arange(8), target[:, 0], target[:, 1]]
        _, r, term, trunc, info = env.step(a)
        assert not info["illegal"].any()
        np.testing.assert_array_equal(env.pos, target)
        now = env.sinr_here()
        np.testing.assert_allclose(r, now - before + cfg.c_e * fresh, atol=1e-5)
        np.testing.assert_array_equal(term, now >= cfg.p_t_db)
        assert not (term & trunc).any()
    # Memory channel: measured SINR where visited, P_H elsewhere on legal cells, P_L on blocked and beyond the edge.
    i = 0
    mem, vis, view = env.memory[i], env.visited[i], env.view[i]
    np.testing.assert_allclose(mem[vis], maps.sinr[view][vis])
    blocked = maps.blocked[maps.view_map[view]]
    assert np.all(mem[~vis & ~blocked] == cfg.p_h_db) and np.all(mem[~vis & blocked] == cfg.p_l_db)
    obs = env.observe()
    c = cfg.window // 2
    assert obs[i, 1, c, c] == pytest.approx(env.sinr_here()[i])
    # The map is 14 x 11 cells: most of a 61-cell window lies beyond the edge (height 100 m, memory P_L).
    assert obs[i, 0, 0, 0] == cfg.edge_height_m and obs[i, 1, 0, 0] == cfg.p_l_db


def test_masks_and_illegal_moves(maps):
    env = BatchedEnv(maps, 16)
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    for _ in range(200):
        mask = env.action_mask()
        nb = env.pos[:, None, :] + MOVES[None]
        blocked = maps.blocked[maps.view_map[env.view][:, None], nb[..., 0], nb[..., 1]]
        np.testing.assert_array_equal(mask, ~blocked)
        a = rng.integers(0, 4, 16)  # unmasked: some moves are illegal
        before = env.pos.copy()
        _, _, term, trunc, info = env.step(a)
        stay = info["illegal"] & ~(term | trunc)
        np.testing.assert_array_equal(env.pos[stay], before[stay])
        assert not maps.blocked[maps.view_map[env.view], env.pos[:, 0], env.pos[:, 1]].any()


@pytest.mark.parametrize("symmetries", [4, 8])
def test_rotation_consistency(root, symmetries):
    maps = MapSet.load("tiny", EnvConfig(rotate=True, symmetries=symmetries), root=str(root))
    b = maps.bundles[0]
    eps = maps.sample_episodes(800, np.random.default_rng(3))
    v, y, x = eps.T
    assert set(maps.symmetry_of(v)) == set(range(symmetries))
    r, c = maps.unrotate(v, y, x)
    users = np.array([maps.scenarios[i].user for i in maps.scenario_of(v)])
    np.testing.assert_allclose(maps.sinr[v, y, x], b.sinr_db[users, r, c])
    unrotated = maps.steps[v - maps.symmetry_of(v), r + maps.pad, c + maps.pad]
    np.testing.assert_array_equal(maps.steps[v, y, x], unrotated)
    if symmetries == 8:  # the mirrors are new views: a transposed map, not a turn of the original
        ny, nx = b.shape
        assert tuple(maps.shapes[4]) == (nx, ny) and not np.array_equal(maps.blocked[4], maps.blocked[1])


def test_symmetry_moves_map_to_moves(root):
    """A move in any view is a move to a neighbouring cell of the untransformed map (legal moves are preserved)."""
    maps = MapSet.load("tiny", EnvConfig(rotate=True, symmetries=8), root=str(root))
    v, y, x = maps.sample_episodes(300, np.random.default_rng(4)).T
    r0, c0 = maps.unrotate(v, y, x)
    for move in MOVES:
        ny, nx = y + move[0], x + move[1]
        inside = ~maps.blocked[maps.view_map[v], ny, nx]
        r1, c1 = maps.unrotate(v[inside], ny[inside], nx[inside])
        assert (np.abs(r1 - r0[inside]) + np.abs(c1 - c0[inside]) == 1).all()


def test_shaping_is_potential_based(root):
    """The shaping term is k * (gamma * phi' - phi), phi = -genie moves: it telescopes over an episode."""
    plain = MapSet.load("tiny", EnvConfig(t_max=60), root=str(root))
    k, gamma = 0.7, 1.0
    shaped = MapSet(plain.bundles, plain.config.model_copy(update={"shaping": k, "shaping_gamma": gamma}))
    a, b = BatchedEnv(plain, 16, autoreset=False), BatchedEnv(shaped, 16, autoreset=False)
    a.reset(seed=5), b.reset(seed=5)
    start = b.genie_steps().astype(float)
    done = np.zeros(16, bool)
    extra = np.zeros(16)
    genie = GeniePolicy()
    for _ in range(40):
        actions = genie.act(a.observe(), a.action_mask(), a)
        before = b.genie_steps()
        _, ra, ta, _, _ = a.step(actions)
        _, rb, tb, _, _ = b.step(actions)
        np.testing.assert_array_equal(ta, tb)
        after = np.where(tb, 0, b.genie_steps())
        np.testing.assert_allclose(rb - ra, k * (before - gamma * after), atol=1e-4)
        extra += np.where(done, 0, rb - ra)
        done |= tb
    assert done.all()  # the genie reaches a target in every episode; the shaping summed to k * (its start distance)
    np.testing.assert_allclose(extra, k * start, atol=1e-3)


def test_genie_moves_start_shortest_paths(root):
    """Every move ``genie_moves`` marks is legal and brings the genie's distance down by one, the genie's own move is
    among them, and a move not marked never does (rotated views included)."""
    maps = MapSet.load("tiny", EnvConfig(t_max=60, rotate=True), root=str(root))
    env = BatchedEnv(maps, 32, autoreset=False)
    env.reset(seed=3)
    genie = GeniePolicy()
    playing = np.ones(32, bool)  # a finished episode stays on its target, where no move shortens anything
    for _ in range(10):
        marked = env.genie_moves()
        assert (marked <= env.action_mask()).all() and marked[playing].any(axis=1).all()
        ny, nx = env.neighbours()
        after = maps.steps[env.view[:, None], ny, nx]
        here = env.genie_steps()[:, None]
        np.testing.assert_array_equal(marked, env.action_mask() & (after == here - 1))
        actions = genie.act(env.observe(), env.action_mask(), env)
        assert marked[playing, actions[playing]].all()
        _, _, term, _, _ = env.step(actions)
        playing &= ~term
        if not playing.any():
            break


def test_step_cost_reward_scale_and_visited_channel(root):
    plain = MapSet.load("tiny", EnvConfig(t_max=60), root=str(root))
    cfg = plain.config.model_copy(update={"step_cost": 0.5, "reward_scale": 0.1, "visited_channel": True})
    other = MapSet(plain.bundles, cfg)
    a, b = BatchedEnv(plain, 8), BatchedEnv(other, 8)
    oa, _ = a.reset(seed=2)
    ob, _ = b.reset(seed=2)
    assert ob.shape[1] == 3 and cfg.num_channels == 3
    np.testing.assert_array_equal(ob[:, 0], oa[:, 0])  # height first, SINR memory last, as without the channel
    np.testing.assert_array_equal(ob[:, -1], oa[:, -1])
    c = cfg.window // 2
    assert (ob[:, 1, c, c] == cfg.p_h_db).all() and ob[:, 1].sum() == 8 * cfg.p_h_db  # only the start is visited
    actions = GreedyPolicy(cfg.p_h_db, seed=0).act(oa, a.action_mask(), a)
    _, ra, *_ = a.step(actions)
    ob, rb, *_ = b.step(actions)
    np.testing.assert_allclose(rb, 0.1 * (ra - 0.5), atol=1e-5)
    assert (ob[:, 1, c, c] == cfg.p_h_db).all()  # the cell the UAV is on (the window's centre) is visited


def test_homing_channel_is_a_cone_from_the_best_measured_cell(root):
    """The homing channel (before the SINR memory; the other channels as without it) holds, at each window cell, the
    best SINR measured so far less ``homing_slope_db`` per cell of distance from the first cell it was measured at,
    clipped at P_L; in the views the symmetries turn too, and after the episodes restart."""
    base = EnvConfig(t_max=15, window=21, visited_channel=True, rotate=True, symmetries=8)
    cfg = base.model_copy(update={"homing_channel": True, "homing_slope_db": 2.5})
    plain, homing = (
        BatchedEnv(MapSet.load("tiny", base, root=str(root)), 6),
        BatchedEnv(MapSet.load("tiny", cfg, root=str(root)), 6),
    )
    assert cfg.num_channels == base.num_channels + 1 == 4
    op, info = plain.reset(seed=4)
    oh, _ = homing.reset(seed=4)
    walk = RandomWalkPolicy(p_repeat=0.0, seed=1)
    measured = [[(homing.sinr_here()[i], tuple(homing.pos[i]))] for i in range(6)]  # each episode's route so far
    half = cfg.window // 2
    for _ in range(40):
        np.testing.assert_array_equal(np.delete(oh, 2, axis=1), op)
        for i in range(6):
            best = max(v for v, _ in measured[i])
            by, bx = next(cell for v, cell in measured[i] if v == best)  # the first cell where it was measured
            y, x = np.mgrid[-half : half + 1, -half : half + 1] + homing.pos[i, :, None, None]
            cone = np.maximum(best - 2.5 * np.hypot(y - by, x - bx), cfg.p_l_db)
            np.testing.assert_allclose(oh[i, 2], cone, rtol=1e-6, atol=1e-4)
        actions = walk.act(oh, info["action_mask"], homing)
        op, *_ = plain.step(actions)
        oh, _, term, trunc, info = homing.step(actions)
        for i in range(6):
            measured[i] = [] if term[i] or trunc[i] else measured[i]
            measured[i].append((homing.sinr_here()[i], tuple(homing.pos[i])))
    assert "best_sinr" in homing.state_arrays and "best_sinr" not in plain.state_arrays


def _context_by_hand(env: BatchedEnv, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Env ``i``'s context channels (mean height, best SINR) computed cell by cell from the fine canvases."""
    maps, cfg = env.maps, env.config
    z, w, L = cfg.context_zoom, cfg.window, maps.side
    view = env.view[i]
    height, memory0 = maps.height[maps.view_map[view]], maps.memory0[view]
    cy, cx = env.pos[i] // z  # block of the UAV, counted from the canvas origin
    out_h, out_m = np.empty((w, w)), np.empty((w, w))
    for r in range(w):
        for c in range(w):
            by, bx = cy + r - w // 2, cx + c - w // 2
            ys, xs = np.arange(by * z, by * z + z), np.arange(bx * z, bx * z + z)
            on = (ys[:, None] >= 0) & (ys[:, None] < L) & (xs[None] >= 0) & (xs[None] < L)
            yy, xx = np.clip(ys, 0, L - 1)[:, None], np.clip(xs, 0, L - 1)[None]
            out_h[r, c] = np.where(on, height[yy, xx], cfg.edge_height_m).mean()
            seen = on & env.visited[i][yy, xx]
            if seen.any():
                out_m[r, c] = env.memory[i][yy, xx][seen].max()
            else:
                out_m[r, c] = cfg.p_h_db if (on & (memory0[yy, xx] == cfg.p_h_db)).any() else cfg.p_l_db
    return out_h, out_m


@pytest.mark.parametrize("blind", [False, True])
def test_context_channels_hold_the_window_in_blocks(root, blind):
    """context_zoom 3: blocks of 3 x 3 cells (mean height; best SINR measured, else P_H or P_L), the other channels
    as without them, through steps and restarts."""
    base = EnvConfig(t_max=12, window=21, visited_channel=True, blind=blind, rotate=True)
    plain = MapSet.load("tiny", base, root=str(root))
    cfg = base.model_copy(update={"context_zoom": 3})
    assert cfg.num_channels == base.num_channels + (1 if blind else 2)
    a, b = BatchedEnv(plain, 6), BatchedEnv(MapSet(plain.bundles, cfg), 6)
    oa, _ = a.reset(seed=5)
    ob, _ = b.reset(seed=5)
    rng = np.random.default_rng(0)
    for t in range(30):  # t_max 12: every env restarts at least twice
        first = 0 if blind else 1
        np.testing.assert_array_equal(ob[:, :first], oa[:, :first])  # height first
        np.testing.assert_array_equal(ob[:, -2:], oa[:, -2:])  # visited, then SINR memory last
        for i in range(6):
            h, m = _context_by_hand(b, i)
            if not blind:
                np.testing.assert_allclose(ob[i, 1], h, atol=1e-4)
            np.testing.assert_allclose(ob[i, -3], m, atol=1e-4)
        if t == 0:
            w = cfg.window // 2
            assert (
                (ob[:, -3, w, w] == b.sinr_here()).all() and (ob[:, -3] == cfg.p_h_db).any() and (ob[:, -3] == cfg.p_l_db).any()
            )
        actions = np.array([rng.choice(np.flatnonzero(m)) for m in a.action_mask()])
        oa, *_ = a.step(actions)
        ob, *_ = b.step(actions)
    with pytest.raises(ValueError, match="context_zoom 1"):
        EnvConfig(context_zoom=1)


def test_far_starts_oversample_distant_starts(root):
    base = MapSet.load("tiny", EnvConfig(), root=str(root))
    far = MapSet(base.bundles, base.config.model_copy(update={"far_starts": 1.0}))
    rng = np.random.default_rng

    def mean_steps(maps):
        v, y, x = maps.sample_episodes(4000, rng(0)).T
        return maps.steps[v, y, x].mean()

    assert mean_steps(far) > mean_steps(base) + 0.2
    v, y, x = far.sample_episodes(4000, rng(1)).T  # still valid starts: below P_T, reachable
    assert (far.sinr[v, y, x] < far.config.p_t_db).all() and (far.steps[v, y, x] < UNREACHABLE).all()


def test_blind_variant(root):
    maps = MapSet.load("tiny", EnvConfig(blind=True), root=str(root))
    env = BatchedEnv(maps, 4)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (4, 1, 61, 61)
    p = maps.pad
    blocked_inside = maps.blocked[0, p : p + 11, p : p + 14]
    assert blocked_inside.any()
    np.testing.assert_array_equal(maps.memory0[0, p : p + 11, p : p + 14][blocked_inside], maps.config.p_h_db)
    assert maps.memory0[0, 0, 0] == maps.config.p_l_db


def test_seeding_gives_the_same_episodes(root):
    a = UavPlacementEnv("tiny", root=str(root), rotate=True, evaluation_info=True)
    b = UavPlacementEnv("tiny", root=str(root), rotate=True, evaluation_info=True)
    for seed in (0, 5):
        oa, ia = a.reset(seed=seed)
        ob, ib = b.reset(seed=seed)
        np.testing.assert_array_equal(oa, ob)
        assert ia["view"] == ib["view"] and np.array_equal(ia["position"], ib["position"])
    for act in (0, 1, 2, 3, 1):
        assert a.step(act)[1] == b.step(act)[1]


def test_compact_observations_round_trip(maps):
    env = BatchedEnv(maps, 2, compact=True)
    obs, _ = env.reset(seed=0)
    assert obs.dtype == np.uint8
    full = BatchedEnv(maps, 2)
    ref, _ = full.reset(seed=0)
    np.testing.assert_allclose(decode_obs(obs), np.clip(np.rint(ref), -150, 105))
    assert encode_obs(np.array([-150.0, 50.0, 105.0])).tolist() == [0, 200, 255]


def _bfs_brute(legal: np.ndarray, target: np.ndarray) -> np.ndarray:
    ny, nx = legal.shape
    out = np.full((ny, nx), UNREACHABLE, np.int32)
    for sy in range(ny):
        for sx in range(nx):
            if not legal[sy, sx]:
                continue
            seen, q = {(sy, sx)}, deque([(sy, sx, 0)])
            while q:
                y, x, d = q.popleft()
                if target[y, x]:
                    out[sy, sx] = d
                    break
                for dy, dx in MOVES:
                    yy, xx = y + dy, x + dx
                    if 0 <= yy < ny and 0 <= xx < nx and legal[yy, xx] and (yy, xx) not in seen:
                        seen.add((yy, xx))
                        q.append((yy, xx, d + 1))
    return out


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 9), st.integers(2, 9), st.integers(0, 2**31 - 1), st.floats(0.0, 0.5), st.floats(0.02, 0.3))
def test_genie_bfs_matches_brute_force(ny, nx, seed, p_block, p_target):
    rng = np.random.default_rng(seed)
    legal = rng.random((ny, nx)) >= p_block
    target = legal & (rng.random((ny, nx)) < p_target)
    np.testing.assert_array_equal(steps_to_target(legal, target), _bfs_brute(legal, target))


def test_baselines_on_the_same_episodes(maps):
    eps = maps.sample_episodes(120, np.random.default_rng(9))
    genie = run_episodes(maps, GeniePolicy(), eps, num_envs=32)
    walk = run_episodes(maps, RandomWalkPolicy(seed=1), eps, num_envs=32)
    greedy = run_episodes(maps, GreedyPolicy(maps.config.p_h_db, seed=1), eps, num_envs=32)
    assert genie.success.all() and np.array_equal(genie.steps, genie.genie_steps)
    for other in (walk, greedy):
        assert np.array_equal(other.genie_steps, genie.genie_steps)  # same episodes
        assert np.all(genie.steps <= np.where(other.success, other.steps, np.iinfo(np.int64).max))
    assert walk.success.mean() < 1.0 or walk.steps.mean() > genie.steps.mean()


def test_summary_counts_failures_as_infinite():
    import pandas as pd

    from uavplace.rl.cli import summarise

    df = pd.DataFrame(
        {"success": [True, True, False, False, True], "steps": [4, 10, 500, 500, 2], "genie_steps": [2, 5, 3, 3, 2]}
    )
    s = summarise(df)
    assert s["success"] == 0.6 and s["median_steps"] == 10 and s["p75_steps"] == float("inf")
    assert s["mean_steps_success"] == pytest.approx(16 / 3) and s["steps_over_genie"] == 2.0


def test_uavrl_baselines_cli(root):
    from click.testing import CliRunner

    from uavplace.cli import uavrl

    res = CliRunner().invoke(uavrl, ["baselines", "--dataset", "tiny", "--root", str(root), "--episodes", "40", "--t-max", "60"])
    assert res.exit_code == 0, res.output
    assert "tiny: 40 episodes, t_max 60, P_T 5 dB" in res.output  # each city's table says what it is
    twice = CliRunner().invoke(uavrl, ["baselines", "--dataset", "tiny", "--dataset", "tiny", "--root", str(root),
                                       "--episodes", "40", "--t-max", "60"])  # fmt: skip
    assert twice.exit_code == 0 and twice.output.count("tiny: 40 episodes") == 2  # one table per city, never pooled
    assert (
        "genie" in res.output
        and "100.0 %" in res.output
        and "steered random walk" in res.output
        and "greedy hill-climbing" in res.output
    )
    res = CliRunner().invoke(uavrl, ["datasets", "--root", str(root)])
    assert res.exit_code == 0 and "tiny" in res.output


def test_starts_must_reach_a_target():
    """A courtyard closed by buildings above the altitude holds no start: every start is solvable."""
    from uavplace.dataset.difficulty import difficulty, valid_starts

    blocked = np.zeros((12, 12), bool)
    blocked[2:7, 2:7] = True
    blocked[3:6, 3:6] = False  # a 3 x 3 courtyard, closed on all sides
    sinr = np.full((1, 12, 12), -10.0, np.float32)
    sinr[0, 11, 11] = 10.0  # the one target, outside the courtyard
    dead = np.zeros((1, 12, 12), bool)
    starts = valid_starts(blocked, dead, sinr, 5.0)
    assert not starts[0, 3:6, 3:6].any() and starts[0, 0, 0] and not starts[0, 11, 11]
    legal_below = (~blocked).sum() - 1
    d = difficulty(blocked, dead, sinr, 5.0)
    assert d["num_starts"] == legal_below - 9 and d["excluded_start_share"] == pytest.approx(9 / legal_below)
    assert np.isfinite(d["bfs_median_steps"])


def test_an_episode_plays_the_same_whatever_else_is_played(maps):
    """Random choices are drawn per episode and step (rl.randomness): the same episodes give the same moves at any batch
    size, after other episodes played by the same policy object, and (a network's) at 1 or 2 torch threads."""
    import torch

    from uavplace.rl.agent.dqn import DQNPolicy
    from uavplace.rl.agent.network import FoveaQNetwork

    eps = maps.sample_episodes(60, np.random.default_rng(3))
    other = maps.sample_episodes(40, np.random.default_rng(4))
    torch.manual_seed(0)
    net = FoveaQNetwork(maps.config.num_channels, maps.config.window, hidden=8, fovea=7, recurrent=True)
    makers = {
        "walk": lambda: RandomWalkPolicy(seed=1),
        "greedy": lambda: GreedyPolicy(maps.config.p_h_db, seed=1),
        "dqn": lambda: DQNPolicy(net, epsilon=0.3, seed=1),
    }
    threads = torch.get_num_threads()
    try:
        for name, make in makers.items():
            alone = run_episodes(maps, make(), eps, num_envs=7)
            policy = make()
            run_episodes(maps, policy, other, num_envs=32)
            after = run_episodes(maps, policy, eps, num_envs=32)
            torch.set_num_threads(1 if threads > 1 else 2)
            other_threads = run_episodes(maps, make(), eps, num_envs=13)
            torch.set_num_threads(threads)
            for df in (after, other_threads):
                assert df.steps.tolist() == alone.steps.tolist(), name
                assert df.success.tolist() == alone.success.tolist() and np.allclose(df.return_, alone.return_), name
    finally:
        torch.set_num_threads(threads)
    other_seed = run_episodes(maps, RandomWalkPolicy(seed=2), eps, num_envs=7)
    assert other_seed.steps.tolist() != run_episodes(maps, RandomWalkPolicy(seed=1), eps, num_envs=7).steps.tolist()


def test_placement_env_overrides_are_validated_as_the_command_line_settings(tiny):
    """``UavPlacementEnv(..., **overrides)``: an unknown setting or a value out of its range is one ValueError naming
    the field (``model_copy(update=...)`` had taken ``colour=1`` without a word and a window of 2)."""
    from uavplace.rl.tasks.placement.gym import UavPlacementEnv

    for bad, field in (({"colour": 1}, "colour"), ({"window": 2}, "window"), ({"p_t_db": float("nan")}, "p_t_db")):
        with pytest.raises(ValueError, match=rf"^EnvConfig\.{field}: "):
            UavPlacementEnv("tiny", root=str(tiny), **bad)
    env = UavPlacementEnv("tiny", root=str(tiny), window=31)
    assert env.config.window == 31


class _Keys:
    """A random walk that records the keys its draws are made from, at each episode's first step."""

    name = "keys"

    def __init__(self) -> None:
        self.walk, self.first = RandomWalkPolicy(seed=0), {}

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        self.walk.reset(rows, num_envs)

    def act(self, obs: np.ndarray, mask: np.ndarray, env) -> np.ndarray:  # noqa: ANN001 - an AgentView
        keys = env.episode_keys()
        for r in np.flatnonzero(env.t == 0):
            self.first.setdefault(int(r), []).append(int(keys[r]))
        return self.walk.act(obs, mask, env)


def test_a_policys_random_stream_names_no_user(tiny):
    """The keys a policy's draws are made from name the canvas (the city's public map under a symmetry) and the start,
    never the user: every user of a city started at one cell draws alike, each key is made from the public map's digest
    and the start alone,
    scrambling which user a view holds changes no key, and a rebuild whose maps are byte-identical under another
    bundle version keeps every key (it had kept 104 of 300 of the random walk's outcomes)."""
    import dataclasses

    from uavplace.dataset.bundle import load_bundle
    from uavplace.rl.randomness import canvas_key, combine

    bundle = load_bundle("tiny", root=tiny)
    config = EnvConfig(rotate=False)
    maps = MapSet([bundle], config)
    S = maps.symmetries
    starts = {}  # start cell -> the views (users, symmetry 0) that may start there
    for v in range(0, len(maps.scenarios) * S, S):
        for cell in maps.start_cells[maps.start_offset[v] : maps.start_offset[v] + maps.start_count[v]].tolist():
            starts.setdefault(cell, []).append(v)
    shared = sorted((c, vs) for c, vs in starts.items() if len(vs) >= 2)[:4]
    assert shared, "no start cell that two users share"
    episodes = np.array([[v, *divmod(c, maps.side)] for c, vs in shared for v in vs])
    groups = np.repeat(np.arange(len(shared)), [len(vs) for _, vs in shared])

    def keys_of(m: MapSet) -> np.ndarray:
        rec = _Keys()
        run_episodes(m, rec, episodes, num_envs=len(episodes))
        return np.array([rec.first[r][0] for r in range(len(episodes))], np.uint64)

    keys = keys_of(maps)
    for g in range(len(shared)):
        assert len(set(keys[groups == g].tolist())) == 1, "two users of one canvas and start drew differently"
    assert len(set(keys.tolist())) == len(shared)  # the start still tells episodes apart
    # each key is made from what the UAV knows alone: the public map's digest (grid and buildings) and the start
    starts = (episodes[:, 1] - maps.pad) * maps.side + (episodes[:, 2] - maps.pad)
    np.testing.assert_array_equal(keys, combine(canvas_key(bundle.public_digest, 0), starts))
    scrambled = dataclasses.replace(bundle, sinr_db=bundle.sinr_db[::-1].copy(), dead=bundle.dead[::-1].copy())
    np.testing.assert_array_equal(keys_of(MapSet([scrambled], config)), keys)
    manifest = bundle.manifest.model_copy(update={"version": "0" * 12})
    rebuilt = dataclasses.replace(bundle, manifest=manifest)
    assert rebuilt.version != bundle.version
    np.testing.assert_array_equal(keys_of(MapSet([rebuilt], config)), keys)


class _Vandal(_Keys):
    """A random walk that, at every step, tries to write the public maps it is handed: blocks every cell, raises every
    building; it makes a sealed copy writable again first, as a determined policy could."""

    name = "vandal"

    def act(self, obs: np.ndarray, mask: np.ndarray, env) -> np.ndarray:  # noqa: ANN001 - an AgentView
        if env.public.blocked.flags.writeable is False:  # as handed over: read-only
            with pytest.raises(ValueError, match="read-only"):
                env.public.blocked[...] = True
            self.refused = True
        for a in (env.public.blocked, env.public.height, *env.public.bundle_heights):
            a.flags.writeable = True  # a copy the view owns: allowed, and harmless
            a[...] = 1
        return super().act(obs, mask, env)


def test_a_policy_that_writes_the_public_maps_changes_nothing_the_env_reads(tiny):
    """The view's public arrays are read-only copies: a policy that writes them (even after making them writable)
    plays the same episodes, legal moves and outcomes as one that does not, and the env's maps are untouched."""
    from uavplace.dataset.bundle import load_bundle

    maps = MapSet([load_bundle("tiny", root=tiny)], EnvConfig(rotate=False))
    before = maps.blocked.copy(), maps.height.copy()
    episodes = maps.sample_episodes(12, np.random.default_rng(0))
    plain = run_episodes(maps, _Keys(), episodes, num_envs=6)
    vandal = _Vandal()
    played = run_episodes(maps, vandal, episodes, num_envs=6)
    assert vandal.refused and plain.equals(played)
    np.testing.assert_array_equal(maps.blocked, before[0])
    np.testing.assert_array_equal(maps.height, before[1])

"""The map searcher: its predictor against a closed-form knife edge, its belief against Bayes by brute force, the
episodes named by what they are, and SPL."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.special import fresnel

from tests.conftest import REPO
from uavplace.rl.config import SearchConfig
from uavplace.rl.predictor import PhysicsConstants, Scene, fresnel_nu, knife_edge_db, load_constants, path_features
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.policies import RandomWalkPolicy
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.stats import episode_stats
from uavplace.rl.world.view import PublicMaps
from uavplace.schemas import InputError


def exact_knife_edge_db(nu: float) -> float:
    """The knife edge's loss from the Fresnel integrals: -20 log10 |F(nu)|, |F| = |(1 + j) / 2 int_nu^inf
    exp(-j pi t^2 / 2) dt| (ITU-R P.526-15, eq. 27)."""
    s, c = fresnel(nu)
    return -20 * math.log10(math.sqrt(0.5) * math.hypot(0.5 - c, 0.5 - s))


@pytest.mark.parametrize("nu", [-0.5, 0.0, 0.7, 2.0, 5.0])
def test_knife_edge_approximation_is_the_fresnel_integral(nu):
    assert abs(float(knife_edge_db(np.array([nu]))[0]) - exact_knife_edge_db(nu)) < 0.6


def test_one_screen_costs_its_knife_edge():
    """A wall across open ground between the user and the UAV: the profile's loss is that one edge's, from the
    geometry in closed form (height above the straight path, distances to the ends)."""
    ny, nx, spacing = 5, 41, 4.0
    heights = np.zeros((ny, nx), np.float32)
    heights[:, 20] = 14.0  # a 14 m wall at x = 80 m
    scene = Scene(heights, spacing, 10.0, 8e8, 20.0, -75.0, -40.0)
    f = path_features(scene, (2, 0), 1.5, np.array([[2, 40]]))
    length = math.hypot(40 * spacing, 8.5)
    s = 20 / 40  # the wall's cell is halfway
    h = 14.0 - (1.5 + s * 8.5)
    nu = float(fresnel_nu(np.float32(h), np.float32(s * length), np.float32((1 - s) * length), scene.wavelength_m))
    assert f["walls"][0] == 1
    assert f["diffraction_db"][0] == pytest.approx(exact_knife_edge_db(nu), abs=1.0)
    open_ground = path_features(Scene(np.zeros_like(heights), spacing, 10.0, 8e8, 20.0, -75.0, -40.0), (2, 0), 1.5,
                                np.array([[2, 40]]))  # fmt: skip
    assert open_ground["walls"][0] == 0 and open_ground["diffraction_db"][0] == 0


def _constants() -> PhysicsConstants:
    return PhysicsConstants(intercept_db=-20, log_d_db=-23, wall_db=-9, diffraction_weight=0.1, dead_level_db=-13,
                            dead_scale_db=4, error_db=10)  # fmt: skip


def _one_path(scene: Scene, user: tuple[int, int], cell: tuple[int, int], hu: float) -> tuple[int, float]:
    """(walls, Deygout's loss) of one path, a sample at a time in float64: the reference for ``path_features``."""
    h, lam = scene.ground_height_m.astype(np.float64), scene.wavelength_m
    (uy, ux), (cy, cx) = user, cell
    horiz = math.hypot(cy - uy, cx - ux)
    rise = scene.altitude_m - hu
    length = math.hypot(horiz * scene.spacing_m, rise)
    k = max(math.ceil(horiz - 1e-4), 1)
    prof = []  # (s, sample cell, roof, height of the straight path)
    for i in range(k):
        s = (i + 0.5) / k
        y = int(np.clip(np.rint(uy + s * (cy - uy)), 0, h.shape[0] - 1))
        x = int(np.clip(np.rint(ux + s * (cx - ux)), 0, h.shape[1] - 1))
        roof = 0.0 if (y, x) in ((uy, ux), (cy, cx)) else float(h[y, x])
        prof.append((s, (y, x), roof, hu + s * rise))
    inside = [roof > line for _, _, roof, line in prof]
    walls = sum(1 for i, v in enumerate(inside) if v and (i == 0 or not inside[i - 1]))

    def nu(height: float, d1: float, d2: float) -> float:
        return height * math.sqrt(2 / lam * (1 / max(d1, 1e-3) + 1 / max(d2, 1e-3)))

    def loss(v: float) -> float:
        return 0.0 if v <= -0.78 else 6.9 + 20 * math.log10(math.sqrt((v - 0.1) ** 2 + 1) + v - 0.1)

    nus = [nu(roof - line, s * length, (1 - s) * length) for s, _, roof, line in prof]
    m = int(np.argmax(nus))
    if nus[m] <= -0.78:
        return walls, 0.0
    sm, cm, roof_m, _ = prof[m]
    a = [nu(roof - (hu + s / sm * (roof_m - hu)), s * length, (sm - s) * length) for s, c, roof, _ in prof
         if s < sm and c != cm]  # fmt: skip
    b = [nu(roof - (roof_m + (s - sm) / (1 - sm) * (scene.altitude_m - roof_m)), (s - sm) * length, (1 - s) * length)
         for s, c, roof, _ in prof if s > sm and c != cm]  # fmt: skip
    return walls, loss(nus[m]) + loss(max(a, default=-9.0)) + loss(max(b, default=-9.0))


def test_path_features_are_each_path_sampled_by_itself(tiny):
    """The vectorised profiles (chunked by length, padded) equal a sample-by-sample walk of each path."""
    from uavplace.dataset.bundle import load_bundle

    scene = Scene.of(load_bundle("tiny", root=tiny))
    rng = np.random.default_rng(5)
    ny, nx = scene.ground_height_m.shape
    for _ in range(4):
        user = (int(rng.integers(ny)), int(rng.integers(nx)))
        cells = np.stack([rng.integers(ny, size=300), rng.integers(nx, size=300)], axis=1)
        f = path_features(scene, user, 1.5, cells)
        for j, (cy, cx) in enumerate(cells):
            walls, diffraction = _one_path(scene, user, (int(cy), int(cx)), 1.5)
            assert f["walls"][j] == walls
            assert f["diffraction_db"][j] == pytest.approx(diffraction, abs=0.05)
    whole = path_features(scene, user, 1.5)
    np.testing.assert_array_equal(whole["walls"][cells[:, 0], cells[:, 1]], f["walls"])


def test_a_paths_features_do_not_depend_on_the_paths_beside_it():
    """A map's paths computed in many chunks (by length, each padded to its longest) give each path the features it
    has when computed among a few others, to the bit: the chunking is a matter of time only."""
    rng = np.random.default_rng(11)
    heights = np.where(rng.random((72, 64)) < 0.3, rng.uniform(4, 40, (72, 64)), 0).astype(np.float32)
    scene = Scene(heights, 4.0, 10.0, 8e8, 20.0, -75.0, -40.0)
    user = (30, 21)
    whole = path_features(scene, user, 1.5)
    for _ in range(3):
        cells = np.stack([rng.integers(72, size=50), rng.integers(64, size=50)], axis=1)
        few = path_features(scene, user, 1.5, cells)  # one chunk
        for name, values in few.items():
            np.testing.assert_array_equal(whole[name][cells[:, 0], cells[:, 1]], values)
    assert whole["diffraction_db"].max() > 0 and whole["walls"].max() > 1


def test_belief_is_bayes_by_brute_force(tiny):
    """The searcher's belief after a few measurements, one update at a time, equals the posterior computed at once:
    the product over measurements of each candidate's likelihood (censored at the floor), tempered, normalised."""
    maps = MapSet.load("tiny", EnvConfig(t_max=50), root=str(tiny))
    policy = MapSearchPolicy(_constants(), SearchConfig(stride=1, temper=0.7, outlier=0.05))
    public = PublicMaps.of(maps)
    cm = policy.canvas_maps(public, 0)
    rng = np.random.default_rng(0)
    columns = rng.choice(len(cm.legal), 6, replace=False)
    floor = public.settings[0]["floor_db"]
    measured = [floor, 12.0, -3.5, floor, 30.0, 0.0]
    log_b = np.zeros(len(cm.cells), np.float32)
    for col, m in zip(columns, measured, strict=True):
        log_b = policy.update(cm, log_b, int(col), m, floor)
    got = np.exp(log_b - log_b.max())
    got /= got.sum()
    sigma, eps = policy.predictor.error_db, 0.05
    total = np.zeros(len(cm.cells))
    for col, m in zip(columns, measured, strict=True):
        for c in range(len(cm.cells)):
            mu = float(cm.mu[c, col])
            dead = 1 / (1 + math.exp((mu + 13) / 4))
            if m <= floor:
                like = dead + (1 - dead) * 0.5 * math.erfc(-(floor - mu) / sigma / math.sqrt(2))
                like = (1 - eps) * like + eps
            else:
                density = math.exp(-0.5 * ((m - mu) / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
                like = (1 - eps) * (1 - dead) * density + eps / 100.0
            total[c] += 0.7 * math.log(like)
    want = np.exp(total - total.max())
    want /= want.sum()
    np.testing.assert_allclose(got, want, atol=2e-4)


def test_searcher_finds_users_of_the_tiny_city(tiny):
    maps = MapSet.load("tiny", EnvConfig(t_max=100), root=str(tiny))
    episodes = maps.episode_list(20, 0)
    df = run_episodes(maps, MapSearchPolicy(_constants()), episodes, num_envs=8)
    assert df["success"].mean() >= 0.9


class _CheckedSeen(MapSearchPolicy):
    """The searcher, checking after every step that the cells it keeps as visited are the env's visited cells."""

    checked = 0

    def act(self, obs, mask, env):  # noqa: ANN001, ANN201 - Policy's
        actions = super().act(obs, mask, env)
        p = env.public.pad
        for r in np.flatnonzero(~env.exhausted & mask.any(axis=1)):
            legal = self.canvas_maps(env.public, int(env.canvas[r])).legal
            np.testing.assert_array_equal(self.seen[r], env.visits[r, legal[:, 0] + p, legal[:, 1] + p] > 0)
            self.checked += 1
        return actions


def test_searcher_keeps_the_visited_cells_of_every_row(tiny):
    """The searcher adds the cell a step stands in to its row's visited cells instead of reading the whole visit map
    again: the same cells as the env's at every step, through episodes that end and rows that start again."""
    maps = MapSet.load("tiny", EnvConfig(t_max=60), root=str(tiny))
    for buildings in (True, False):
        policy = _CheckedSeen(_constants(), SearchConfig(buildings=buildings))
        run_episodes(maps, policy, maps.episode_list(40, 5), num_envs=5)
        assert policy.checked > 80


def test_paths_fetched_together_are_the_paths_one_at_a_time(tiny):
    """A step's missing shortest paths are searched in one call (``prefetch_paths``): the same discounts,
    predecessors and moves as a search from one cell."""
    from scipy.sparse.csgraph import shortest_path

    maps = MapSet.load("tiny", EnvConfig(t_max=60), root=str(tiny))
    public = PublicMaps.of(maps)
    policy = MapSearchPolicy(_constants())
    cm = policy.canvas_maps(public, 0)
    cells = np.random.default_rng(1).choice(len(cm.legal), 12, replace=False)
    policy.prefetch_paths(public, 0, cm, np.concatenate([cells, cells[:3]]))  # repeats fetched once
    assert len(policy._paths) == 12
    graph = policy._graph(public, 0, cm)
    for c in cells:
        d, pred = shortest_path(graph, unweighted=True, indices=int(c), return_predecessors=True)
        d = d.astype(np.float32)
        alone = (np.where(np.isfinite(d), policy.discount(d), np.float32(-1.0)), pred.astype(np.int32), d)
        for a, b in zip(alone, policy.paths_from(public, 0, cm, int(c)), strict=True):
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)


def test_a_measurement_reads_the_same_numbers_from_column_major_maps(tiny):
    """The belief update reads a cell of every candidate's predicted map: held column-major (``canvas_maps``) or
    row-major, the same posterior to the bit."""
    maps = MapSet.load("tiny", EnvConfig(t_max=60), root=str(tiny))
    policy = MapSearchPolicy(_constants())
    cm = policy.canvas_maps(PublicMaps.of(maps), 0)
    assert cm.mu.flags.f_contiguous and cm.p_dead.flags.f_contiguous and cm.cover.flags.c_contiguous
    rows = dataclasses.replace(cm, mu=np.ascontiguousarray(cm.mu), p_dead=np.ascontiguousarray(cm.p_dead))
    rng = np.random.default_rng(0)
    log_b = rng.normal(size=(6, len(cm.cells))).astype(np.float32)
    at = rng.integers(0, len(cm.legal), 6)
    measured = np.array([-200.0, -3.0, 0.5, 7.0, 12.0, 30.0])
    for floor_db in (-10.0, 5.0):
        np.testing.assert_array_equal(
            policy.update_rows(cm, log_b, at, measured, floor_db), policy.update_rows(rows, log_b, at, measured, floor_db)
        )


def test_episode_lists_are_prefixes_and_episodes_play_alike_anywhere(tiny):
    maps = MapSet.load("tiny", EnvConfig(t_max=40), root=str(tiny))
    long, short = maps.episode_list(30, 3), maps.episode_list(10, 3)
    np.testing.assert_array_equal(long[:10], short)
    assert not np.array_equal(maps.episode_list(10, 4), short)
    for policy in (RandomWalkPolicy(seed=1), MapSearchPolicy(_constants())):  # the searcher plans rows in batches
        ahead = run_episodes(maps, policy, long, num_envs=7, record=np.arange(30))
        back = run_episodes(maps, policy, long[::-1].copy(), num_envs=3, record=np.arange(30))
        for k in range(30):  # episode k of one list is episode 29 - k of the other: the same moves
            np.testing.assert_array_equal(ahead.attrs["paths"][k], back.attrs["paths"][29 - k])


def test_spl_known_answer():
    steps = np.array([10, 30, 500, 4])
    success = np.array([True, True, False, True])
    genie = np.array([10, 10, 7, 8])  # the last one: reached in fewer steps than the genie's count (a start on a target)
    stats = episode_stats(steps, success, genie)
    assert stats["spl"] == pytest.approx((1 + 1 / 3 + 0 + 1) / 4)


def test_bad_predictor_file_is_refused(tmp_path):
    bad = tmp_path / "predictor.json"
    bad.write_text('{"intercept_db": "high"}')
    with pytest.raises(InputError, match="predictor.json"):
        load_constants(bad)
    assert load_constants(REPO / "data" / "agents" / "searcher" / "predictor.json").error_db > 0


def test_predicted_maps_are_bounded_by_the_limits(tiny, monkeypatch):
    from uavplace.infra import limits

    monkeypatch.setenv(limits.ENV, "prediction_bytes=1000")
    monkeypatch.setattr(limits, "_current", None)
    maps = MapSet.load("tiny", EnvConfig(t_max=50), root=str(tiny))
    with pytest.raises(InputError, match="prediction_bytes"):
        MapSearchPolicy(_constants()).canvas_maps(PublicMaps.of(maps), 0)


def test_belief_channel_is_the_searchers_belief_turned_with_the_map(tiny):
    """The hybrid's channel (``BeliefTracker``): the belief after a few measurements is the searcher's own, and a
    canvas turned by a quarter turn, measured at the turned cells, shows the same cover canvas turned."""
    from uavplace.rl.belief import BeliefTracker, PredictionCache
    from uavplace.rl.predictor import PhysicsPredictor
    from uavplace.rl.world.maps import transform

    maps = MapSet.load("tiny", EnvConfig(t_max=50, rotate=True, symmetries=4), root=str(tiny))
    policy = MapSearchPolicy(_constants())
    tracker = BeliefTracker(maps, 2, PhysicsPredictor(_constants()), SearchConfig(), PredictionCache(None))
    cm = policy.canvas_maps(PublicMaps.of(maps), 0)
    rng = np.random.default_rng(0)
    cells = cm.legal[rng.choice(len(cm.legal), 5, replace=False)]
    floor = float(PublicMaps.of(maps).settings[0]["floor_db"])
    values = np.array([floor, 8.0, -2.0, 20.0, floor], np.float32)
    ny, nx = cm.index.shape
    turned = transform(np.arange(ny * nx).reshape(ny, nx), 1)  # where each cell of the map lies once turned
    where = {int(v): divmod(int(i), turned.shape[1]) for i, v in enumerate(turned.ravel())}
    cells1 = np.array([where[int(y) * nx + int(x)] for y, x in cells])
    tracker.start(np.array([0, 1]), np.array([0, 1]), np.array([cells[0, 0], cells1[0, 0]]),
                  np.array([cells[0, 1], cells1[0, 1]]), values[:1].repeat(2))  # fmt: skip
    for (y, x), (y1, x1), v in zip(cells[1:], cells1[1:], values[1:], strict=True):
        tracker.measure(np.array([0, 1]), np.array([y, y1]), np.array([x, x1]), np.array([v, v]))
    log_b = np.zeros(len(cm.cells), np.float32)
    for (y, x), v in zip(cells, values, strict=True):
        log_b = policy.update(cm, log_b, int(cm.index[y, x]), float(v), floor)
    np.testing.assert_allclose(tracker.log_b[0], log_b, atol=1e-5)
    np.testing.assert_allclose(tracker.log_b[1], log_b, atol=1e-5)
    p = maps.pad
    plain = tracker.cover[0, p : p + ny, p : p + nx]
    assert plain.max() > 1.0 and (plain[~maps_legal(cm)] == 0).all()
    np.testing.assert_allclose(tracker.cover[1, p : p + nx, p : p + ny], transform(plain, 1), atol=1e-3)


def maps_legal(cm) -> np.ndarray:  # noqa: ANN001
    return cm.index >= 0


def test_belief_channel_in_the_observation(tiny):
    """``EnvConfig.belief_channel`` adds the tracker's cover window before the SINR memory; blanking the buildings
    (the ablation) changes it, as it changes the predicted maps."""
    from uavplace.rl.tasks.placement.env import BatchedEnv

    constants = str(REPO / "data" / "agents" / "searcher" / "predictor.json")
    cfg = EnvConfig(t_max=50, homing_channel=True, belief_channel=True, belief_predictor=constants)
    maps = MapSet.load("tiny", cfg, root=str(tiny))
    env = BatchedEnv(maps, 3)
    obs, info = env.reset(seed=0)
    assert obs.shape[1] == cfg.num_channels == EnvConfig(homing_channel=True).num_channels + 1
    for _ in range(5):
        obs, *_, info = env.step(np.argmax(info["action_mask"], axis=1))
    w = cfg.window // 2
    y, x = env.pos[:, 0], env.pos[:, 1]
    for r in range(3):
        np.testing.assert_array_equal(obs[r, -2], env.belief.cover[r, y[r] - w : y[r] + w + 1, x[r] - w : x[r] + w + 1])
    assert 0 <= obs[:, -2].min() and obs[:, -2].max() <= 100 and obs[:, -2].max() > 0
    blank = MapSet.load("tiny", cfg, root=str(tiny))
    blank.show_buildings(None)
    other = BatchedEnv(blank, 3)
    again, info = other.reset(seed=0)
    for _ in range(5):
        again, *_, info = other.step(np.argmax(info["action_mask"], axis=1))
    assert not np.allclose(again[:, -2], obs[:, -2])


def test_belief_channel_paints_what_the_whole_canvas_shows(tiny):
    """The channel is painted only in the window an observation reads, and not for a played-out queue's placeholders:
    every observation of a row still playing is, to the bit, the one of the canvas painted whole for every row (lone
    restarts and the last rows of a queue included), and the episodes are the same."""
    from uavplace.rl.tasks.placement.env import BatchedEnv

    constants = str(REPO / "data" / "agents" / "searcher" / "predictor.json")
    cfg = EnvConfig(t_max=30, homing_channel=True, belief_channel=True, belief_predictor=constants)
    maps = MapSet.load("tiny", cfg, root=str(tiny))
    queue = maps.episode_list(17, 2)
    envs = [BatchedEnv(maps, 5, queue=queue) for _ in range(2)]
    whole = envs[1].belief
    whole.window = None
    for name, given in (("start", 5), ("measure", 4)):  # every row painted whole, as if someone read them all
        method = getattr(whole, name)
        setattr(whole, name, lambda *args, unread=None, _m=method, _n=given: _m(*args[:_n]))
    (obs, info), (ref, _) = envs[0].reset(), envs[1].reset()
    rng = np.random.default_rng(0)
    played = 0
    while not envs[0].exhausted.all():
        live = ~envs[0].exhausted
        np.testing.assert_array_equal(obs[live], ref[live])
        actions = np.array([rng.choice(np.flatnonzero(m)) for m in info["action_mask"]])
        obs, _, term, trunc, info = envs[0].step(actions)
        ref, _, term1, trunc1, _ = envs[1].step(actions)
        np.testing.assert_array_equal(term, term1)
        played += int(((term | trunc) & live).sum())
    assert played == len(queue)


def _cache_entry(tmp_path):  # noqa: ANN001, ANN202
    """(cache, key, mu, p_dead): one entry saved, as the searcher saves it."""
    from uavplace.rl.belief import PredictionCache

    cache = PredictionCache(tmp_path / "cache")
    rng = np.random.default_rng(0)
    mu, p_dead = rng.normal(0, 20, (6, 9)).astype(np.float32), rng.random((6, 9)).astype(np.float32)
    cache.save("k1", mu, p_dead)
    return cache, "k1", mu, p_dead


def test_prediction_cache_uses_only_whole_entries_of_its_own_key(tmp_path):
    """A cache entry is data: altered values (a valid archive of the right shape), NaN, dead probabilities out of
    [0, 1], another key's entry, a truncated file, a link or a FIFO are all predicted again, never used."""
    import io
    import os
    import time

    from tests.conftest import sparse_file
    from uavplace.rl.belief.cache import _entry_meta

    cache, key, mu, p_dead = _cache_entry(tmp_path)
    hit = cache.load(key, mu.shape)
    assert hit is not None
    np.testing.assert_array_equal(hit[0], mu.astype(np.float16).astype(np.float32))
    path = cache.path(key)
    good = path.read_bytes()

    def forged(mu_: np.ndarray, p_: np.ndarray, meta_key: str = key, meta: bytes | None = None) -> bytes:
        """A valid archive of ``mu_`` and ``p_``, recording ``meta`` (default: their own key and hash)."""
        m16, p16 = mu_.astype(np.float16), p_.astype(np.float16)
        meta = _entry_meta(meta_key, m16, p16) if meta is None else meta
        buf = io.BytesIO()
        np.savez(buf, mu=m16, p_dead=p16, meta=np.frombuffer(meta, np.uint8))
        return buf.getvalue()

    cases = {
        "every SINR +30 dB, the entry's own hash kept": forged(
            mu + 30, p_dead, meta=_entry_meta(key, mu.astype(np.float16), p_dead.astype(np.float16))
        ),
        "NaN": forged(np.full_like(mu, np.nan), p_dead),
        "dead probability 2": forged(mu, p_dead + 2),
        "SINR 1000 dB": forged(mu + 1000, p_dead),
        "another key's entry": forged(mu, p_dead, "k2"),
        "truncated": good[: len(good) // 2],
        "not a zip": b"hello",
    }
    for what, data in cases.items():
        path.write_bytes(data)
        assert cache.load(key, mu.shape) is None, what
    path.write_bytes(good)
    assert cache.load(key, (6, 8)) is None  # another shape
    outside = tmp_path / "outside.npz"
    outside.write_bytes(good)
    path.unlink()
    path.symlink_to(outside)  # a link, even to a whole entry, is not followed
    assert cache.load(key, mu.shape) is None
    cache.save(key, mu, p_dead)  # and never replaced: the link stays, the target unchanged
    assert path.is_symlink() and outside.read_bytes() == good
    path.unlink()
    os.mkfifo(path)
    assert cache.load(key, mu.shape) is None  # refused at once, not waited on
    sparse_file(path)  # 2 GB, within prediction_bytes: refused by its size, never read
    cpu = time.process_time()
    assert cache.load(key, mu.shape) is None
    assert time.process_time() - cpu < 1.0


def test_predictor_versions_name_the_code_they_loaded(tmp_path):
    """The prediction cache's key holds the code a prediction depends on, as this process loaded it: an edit to the
    engine that hands the predictor its heights (rl/world/view.py, outside the predictor's folder) changes the digest
    in the next process; a file edited after the process imported the family does not change its digest (its maps
    are the old code's); an edit to a command's module changes nothing. The test edits real code, in a copy of the
    package run as ``uavplace``."""
    import os
    import shutil
    import subprocess
    import sys

    from tests.test_packaging import STAGES
    from uavplace.rl import predictor

    copy = tmp_path / "uavplace"
    for stage in STAGES:
        shutil.copytree(REPO / stage, copy / stage, ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    probe = (
        "import uavplace.rl.predictor.base as b, sys\n"
        "assert b.__file__.startswith(sys.argv[1]), b.__file__\n"
        "print(b.code_digest())\n"
        "open(sys.argv[1] + '/rl/world/view.py', 'a').write(sys.argv[2])\n"
        "print(b.code_digest(), b._digest_of(b._PACKAGE))\n"
    )

    def run(edit: str = "") -> list[str]:
        out = subprocess.run([sys.executable, "-c", probe, str(copy), edit], env=env, capture_output=True, text=True)
        assert out.returncode == 0, out.stderr
        return out.stdout.split()

    first, loaded, _ = run()
    assert first == loaded == predictor.code_digest() and len(first) == 64  # the copy is the code this process runs
    before, kept, on_disk = run("\n\ndef _edited_while_running() -> int:\n    return 1\n")
    assert before == first and kept == before and on_disk != before  # edited after import: the loaded code's key
    assert run()[0] == on_disk  # the next process loads the edit: a new key
    (copy / "rl" / "predictor" / "cli.py").write_text((copy / "rl" / "predictor" / "cli.py").read_text() + "\n# a note\n")
    assert run()[0] == on_disk


def _hand_maps(p_dead: list[list[float]], mu: list[list[float]]):  # noqa: ANN202
    """CandidateMaps of two candidates over ``len(mu[0])`` legal cells, by hand."""
    from uavplace.rl.belief import CandidateMaps

    mu_, p_ = np.array(mu, np.float32), np.array(p_dead, np.float32)
    m = mu_.shape[1]
    return CandidateMaps(np.zeros((2, 2), np.int64), np.zeros((m, 2), np.int64), np.zeros((1, m), np.int64), mu_, p_, p_)


def test_information_of_a_measurement_by_hand():
    """Two candidates, three cells: where one is surely dead and the other far above the floor a measurement tells
    them apart (the belief's entropy: 1 bit for even odds, H(0.9) = 0.469 bits for 9 to 1); where both predict the
    same it tells nothing; where one is dead half the time and the other never, H(1/4) + 3/4 H(G) - 1/2 (1 + 1/2
    H(G)) - 1/2 H(G) = H(1/4) - 1/2 = 0.311 bits, whatever the spread H(G) of the live value."""
    searcher = MapSearchPolicy(_constants(), SearchConfig(outlier=0.0))  # sigma: the constants' 10 dB
    maps = _hand_maps([[1.0, 0.3, 0.5], [0.0, 0.3, 0.0]], [[30.0, 0.0, 30.0], [30.0, 0.0, 30.0]])
    floor = -40.0
    even = searcher.information(maps, np.log(np.array([0.5, 0.5])), np.arange(3), floor, 5.0)
    np.testing.assert_allclose(even, [1.0, 0.0, 0.8112781 - 0.5], atol=1e-6)
    skewed = searcher.information(maps, np.log(np.array([0.9, 0.1])), np.array([0]), floor, 5.0)
    np.testing.assert_allclose(skewed, [-(0.9 * math.log2(0.9) + 0.1 * math.log2(0.1))], atol=1e-6)
    probs = searcher.outcome_probabilities(maps, np.arange(3), floor, 5.0)
    np.testing.assert_allclose(probs.sum(axis=-1), 1.0, atol=1e-9)
    assert probs[0, 0, 0] == pytest.approx(1.0) and probs[1, 0, 0] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("planner", ["info", "lookahead"])
def test_other_planners_find_the_tiny_users(tiny, planner):
    maps = MapSet.load("tiny", EnvConfig(t_max=100), root=str(tiny))
    constants = load_constants(REPO / "data" / "agents" / "searcher" / "predictor.json")
    policy = MapSearchPolicy(constants, SearchConfig(planner=planner, info_weight=0.5))
    df = run_episodes(maps, policy, maps.episode_list(16, 0), num_envs=8)
    assert df["success"].mean() >= 0.9


def test_kriged_cover_by_hand():
    """One measurement at cell 0, the chance of reaching P_T at cells 1 and 3 cells away: each candidate's error latent
    there, Phi^-1 of its predicted probability of a value at or below the measurement, pulls its chance by the
    correlation rho = share * exp(-d / range): Phi((rho * eps + Phi^-1(cover)) / sqrt(1 - rho^2)); at the floor the
    latent is the normal's mean below the floor's; no correlation leaves the predicted chance."""
    from scipy.special import ndtr, ndtri
    from scipy.stats import norm

    from uavplace.rl.belief import CandidateMaps

    mu = np.array([[10.0, 12.0, 0.0, 8.0], [-5.0, 3.0, 6.0, 20.0]], np.float32)
    p_dead = np.array([[0.1, 0.2, 0.5, 0.0], [0.3, 0.05, 0.1, 0.4]], np.float32)
    legal = np.array([[0, 0], [0, 1], [0, 2], [0, 3]])
    config = SearchConfig(error_share=0.8, error_range_cells=4.0, outlier=0.0)
    searcher = MapSearchPolicy(_constants(), config)  # sigma: the constants' 10 dB
    maps = CandidateMaps(np.zeros((2, 2), np.int64), legal, np.arange(4)[None], mu, p_dead, searcher.cover(mu, p_dead, 5.0))
    b = np.array([0.3, 0.7])
    floor = -20.0
    for measured in (-2.0, floor):
        got = searcher.kriged_cover(maps, np.log(b), np.array([0]), np.array([measured]), floor, np.array([1, 3]))
        want = np.zeros(2)
        for c in range(2):
            level = max(measured, floor)
            k = ndtri(p_dead[c, 0] + (1 - p_dead[c, 0]) * ndtr((level - mu[c, 0]) / 10.0))
            eps = -norm.pdf(k) / ndtr(k) if measured <= floor else k
            for j, (cell, d) in enumerate(((1, 1.0), (3, 3.0))):
                rho = 0.8 * math.exp(-d / 4.0)
                want[j] += b[c] * ndtr((rho * eps + ndtri(maps.cover[c, cell])) / math.sqrt(1 - rho**2))
        np.testing.assert_allclose(got, want, rtol=1e-6)
    faint = MapSearchPolicy(_constants(), config.model_copy(update={"error_share": 1e-9}))
    got = faint.kriged_cover(maps, np.log(b), np.array([0, 2]), np.array([-2.0, floor]), floor, np.array([1, 3]))
    np.testing.assert_allclose(got, b @ maps.cover[:, [1, 3]], rtol=1e-5)


def test_correlated_belief_is_bayes_by_brute_force(tiny):
    """The belief updated one measurement at a time, each given those before it (``kriging="belief"``), equals the posterior
    computed at once from the joint Gaussian copula of the values above the floor: each candidate's predicted densities
    times the joint normal density of its error latents over the product of their marginal normal densities."""
    from scipy.special import ndtr, ndtri

    maps = MapSet.load("tiny", EnvConfig(t_max=50), root=str(tiny))
    config = SearchConfig(stride=1, temper=1.0, outlier=0.0, error_share=0.7, error_range_cells=3.0, kriging="belief")
    policy = MapSearchPolicy(_constants(), config)
    public = PublicMaps.of(maps)
    cm = policy.canvas_maps(public, 0)
    floor = public.settings[0]["floor_db"]
    columns = np.random.default_rng(1).choice(len(cm.legal), 5, replace=False)
    measured = np.array([12.0, -3.5, 30.0, 0.0, 7.0])
    log_b, before = np.zeros(len(cm.cells), np.float32), {}
    for col, m in zip(columns, measured, strict=True):
        log_b = policy.update(cm, log_b, int(col), float(m), floor, before)
        before[int(col)] = float(m)
    got = np.exp(log_b - log_b.max())
    got /= got.sum()
    sigma = policy.predictor.error_db
    at = cm.legal[columns].astype(float)
    cov = 0.7 * np.exp(-np.linalg.norm(at[:, None] - at[None], axis=-1) / 3.0)
    np.fill_diagonal(cov, 1.0)
    inverse, (_, log_det) = np.linalg.inv(cov), np.linalg.slogdet(cov)
    total = np.zeros(len(cm.cells))
    for c in range(len(cm.cells)):
        mu = cm.mu[c, columns].astype(float)
        dead = cm.p_dead[c, columns].astype(float)
        z = (measured - mu) / sigma
        latent = ndtri(np.clip(dead + (1 - dead) * ndtr(z), 1e-6, 1 - 1e-6))
        density = np.log(1 - dead) - 0.5 * z * z - math.log(sigma * math.sqrt(2 * math.pi))
        total[c] = density.sum() - 0.5 * latent @ inverse @ latent - 0.5 * log_det + 0.5 * latent @ latent
    want = np.exp(total - total.max())
    want /= want.sum()
    np.testing.assert_allclose(got, want, atol=2e-4)
    independent = MapSearchPolicy(_constants(), config.model_copy(update={"error_share": 0.0}))
    log_i = np.zeros(len(cm.cells), np.float32)
    for col, m in zip(columns, measured, strict=True):
        log_i = independent.update(cm, log_i, int(col), float(m), floor, before)
    assert np.abs(np.exp(log_i - log_i.max()) / np.exp(log_i - log_i.max()).sum() - want).max() > 1e-2


def test_kriging_searcher_finds_the_tiny_users(tiny):
    maps = MapSet.load("tiny", EnvConfig(t_max=100), root=str(tiny))
    for kriging, memory in (("planner", 96), ("belief", 96), ("both", 96), ("both", 3)):
        policy = MapSearchPolicy(_constants(), SearchConfig(error_share=0.85, kriging=kriging, error_memory=memory))
        df = run_episodes(maps, policy, maps.episode_list(20, 0), num_envs=8)
        assert df["success"].mean() >= 0.9


def test_a_belief_reads_the_cover_in_its_own_precision_and_a_float64_one_casts_it_once():
    """``CandidateMaps.cover64`` is made once per canvas's maps, and a float64 belief's product with it is the product
    with the float32 ``cover`` to the bit (numpy casts that one at every call), whatever the number of rows; a float32
    belief's product stays the float32 one."""
    from uavplace.rl.belief import CandidateMaps, posterior_cover

    rng = np.random.default_rng(11)
    cover = rng.random((333, 1201)).astype(np.float32)
    maps = CandidateMaps(np.zeros((333, 2), np.int64), np.zeros((1201, 2), np.int64), np.zeros((1, 1), np.int64),
                         cover, cover, cover)  # fmt: skip
    assert maps.cover64 is maps.cover64 and maps.cover64.dtype == np.float64
    for rows in (1, 2, 7, 64, 257):
        log_b = rng.normal(0, 20, (rows, 333))
        b = np.exp(log_b - log_b.max(axis=1, keepdims=True))
        b /= b.sum(axis=1, keepdims=True)
        assert np.array_equal(posterior_cover(log_b, maps), b @ cover), rows  # numpy's cast at every product
        single = log_b.astype(np.float32)  # a float32 belief stays in float32, over the float32 cover
        b = np.exp(single - single.max(axis=1, keepdims=True))
        b /= b.sum(axis=1, keepdims=True)
        assert posterior_cover(single, maps).dtype == np.float32 and np.array_equal(posterior_cover(single, maps), b @ cover)

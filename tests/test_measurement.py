"""What the UAV reads (rl/world/measurement.py, ``MeasurementSettings`` of every task): the exact measurement by
default, an i.i.d. Gaussian error and correlated shadowing when asked; success judged on the true SINR; every draw
keyed by the episode, so a subset of a run reads as in the run; the scramble test holds with the error on."""

from __future__ import annotations

import numpy as np
import pytest

from tests import scramble
from uavplace.rl.config import MeasurementSettings, SearchConfig
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.tasks.placement.policies import GreedyPolicy, RandomWalkPolicy
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.measurement import measurement_error, shadowing

NOISY = MeasurementSettings(sigma_db=4.0, shadow_sigma_db=3.0, shadow_distance_m=20.0)


def _maps(tiny, measurement: MeasurementSettings = MeasurementSettings()) -> MapSet:  # noqa: B008 - a frozen model
    return MapSet.load("tiny", EnvConfig(t_max=60, rotate=False, measurement=measurement), root=str(tiny))


def _readings(maps: MapSet, steps: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(read, true, dead) at every cell the rows of a random walk stood in, ``steps`` steps of 64 rows."""
    env = BatchedEnv(maps, 64, autoreset=False)
    env.reset(0)
    policy, rows = RandomWalkPolicy(seed=1), np.arange(64)
    policy.reset(rows, 64)
    read, true, dead = [], [], []
    for _ in range(steps):
        y, x = env.pos[:, 0], env.pos[:, 1]
        read.append(env.memory[rows, y, x].copy())
        true.append(maps.sinr[env.view, y, x])
        dead.append(maps.dead[env.view, y, x])
        env.step(policy.act(None, env.action_mask(), env.agent_view()))
    return np.concatenate(read), np.concatenate(true), np.concatenate(dead)


def test_the_exact_measurement_reads_the_true_map(tiny):
    """The default (the paper's): every cell the UAV stood in holds its true SINR in the memory, to the bit."""
    assert EnvConfig().measurement.exact
    read, true, _ = _readings(_maps(tiny))
    np.testing.assert_array_equal(read, true)


def test_the_error_is_the_declared_spread_and_a_dead_cell_reads_dead(tiny):
    """With an i.i.d. error of 4 dB, a live cell reads its true SINR plus an error of mean 0 and spread 4 dB; a dead
    cell reads the floor, as it is."""
    read, true, dead = _readings(_maps(tiny, MeasurementSettings(sigma_db=4.0)))
    error = (read - true)[~dead]
    assert len(error) > 500 and abs(error.mean()) < 0.5 and 3.6 < error.std() < 4.4
    np.testing.assert_array_equal(read[dead], true[dead])


def test_shadowing_has_the_exponential_correlation_of_its_distance():
    """Over 20,000 episodes' fields, the correlation of two points d metres apart is exp(-d / 20 m) within 0.03, the
    spread 1; the i.i.d. error draws anew each step."""
    keys = np.arange(20_000, dtype=np.uint64) * np.uint64(7919) + np.uint64(3)
    zero = np.zeros(len(keys))
    here = shadowing(keys, zero, zero, 1.0, 20.0)
    assert abs(here.std() - 1.0) < 0.03
    for d in (10.0, 20.0, 40.0):
        there = shadowing(keys, zero + d * 0.6, zero + d * 0.8, 1.0, 20.0)
        assert abs(np.mean(here * there) - np.exp(-d / 20.0)) < 0.03
    first, second = (
        measurement_error(MeasurementSettings(sigma_db=1.0), keys, np.full(len(keys), t), zero, zero) for t in (1, 2)
    )
    assert abs(np.corrcoef(first, second)[0, 1]) < 0.03


def test_an_episode_reads_the_same_errors_in_any_list_and_success_is_judged_on_the_truth(tiny):
    """The errors are drawn from the episode's key: each episode of a subset (and each played alone) moves as in the
    whole run; an episode ends when the true SINR, not the reading, reaches P_T."""
    maps = _maps(tiny, NOISY)
    episodes = maps.episode_list(24, 0)
    policy = GreedyPolicy(maps.config.p_h_db, seed=0)
    whole = run_episodes(maps, policy, episodes, num_envs=8, record=np.arange(24))
    part = run_episodes(maps, policy, episodes[[3, 11, 17]], num_envs=2, record=np.arange(3))
    for k, e in enumerate((3, 11, 17)):
        np.testing.assert_array_equal(part.attrs["paths"][k], whole.attrs["paths"][e])
    exact = run_episodes(_maps(tiny), policy, episodes, num_envs=8, record=np.arange(24))
    assert any(not np.array_equal(exact.attrs["paths"][k], whole.attrs["paths"][k]) for k in range(24))
    for k in np.flatnonzero(whole["success"].to_numpy()):  # the last cell's true SINR reaches P_T
        y, x = scramble.to_canvas(maps, int(episodes[k, 0]), whole.attrs["paths"][k][-1:])
        assert maps.config.reaches(maps.sinr[int(episodes[k, 0]), y, x]).all()


def test_policies_read_only_what_they_measured_with_the_error_on(tiny):
    """The scramble test with the error on: the world keeps each episode's errors at the cells it visited (drawn by
    its key, not by the maps), so the random walk, greedy and the map searcher assuming 4 dB move the same."""
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

    maps = _maps(tiny, NOISY)
    episodes = maps.episode_list(8, 1)
    searcher = MapSearchPolicy(load_predictor(), SearchConfig(measurement_sigma_db=4.0), name="map searcher, 4 dB")
    for policy in (RandomWalkPolicy(seed=2), GreedyPolicy(maps.config.p_h_db, seed=2), searcher):
        same, _ = scramble.replay_placement(maps, policy, episodes, np.random.default_rng(6))
        assert all(same), f"{policy.name}: moves changed off its path with the error on ({same})"


def test_the_scramble_test_holds_with_the_measurement_and_the_map_errors_both_on(tiny):
    """Both errors at once (the robustness report's target condition, with shadowing): the users moved and their maps
    scrambled, the random walk and the map searcher assuming 4 dB move the same on the erring map."""
    from uavplace.eval.robustness import MODERATE
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

    config = EnvConfig(t_max=60, rotate=False, measurement=NOISY, map_error=MODERATE)
    maps = MapSet.load("tiny", config, root=str(tiny))
    episodes = maps.episode_list(8, 3)
    searcher = MapSearchPolicy(load_predictor(), SearchConfig(measurement_sigma_db=4.0), name="map searcher, 4 dB")
    for policy in (RandomWalkPolicy(seed=4), searcher):
        same, _ = scramble.replay_placement(maps, policy, episodes, np.random.default_rng(9))
        assert all(same), f"{policy.name}: moves changed off its path with both errors on ({same})"


def test_the_searcher_adds_its_declared_spread_to_the_likelihood():
    """``SearchConfig.measurement_sigma_db`` adds to the predictor's spread in quadrature in the likelihood of a
    reading, never in the chance that a cell reaches P_T; 0 leaves the spread as it was, to the bit."""
    from uavplace.rl.belief.model import BeliefModel
    from uavplace.rl.predictor import load_predictor

    predictor = load_predictor()
    plain, noisy = (BeliefModel(predictor, SearchConfig(measurement_sigma_db=s)) for s in (0.0, 4.0))
    assert plain.read_sigma == plain.sigma
    assert noisy.read_sigma == pytest.approx(np.hypot(noisy.sigma, 4.0)) and noisy.sigma == plain.sigma


def test_the_fleet_refuses_an_error_it_does_not_play():
    from uavplace.rl.tasks.fleet import BatchedFleet, FleetCity, FleetConfig, FleetMaps

    legal = np.ones((5, 5), bool)
    city = FleetCity("c", "v", legal, np.zeros((5, 5), np.float32), np.zeros((2, 5, 5), np.float32), np.zeros((2, 5, 5), bool))
    maps = FleetMaps([city], FleetConfig(uavs=1, users=2, window=3, measurement=MeasurementSettings(sigma_db=2)))
    with pytest.raises(ValueError, match="measurement and map errors are played in the placement and tracking tasks"):
        BatchedFleet(maps, 1)

"""A peer library on the same env: Stable-Baselines3 trains on ``uavplace/UavPlacement-v0`` as it is, and its models
play through the report's evaluation beside uavplace's agents (eval/peer.py, docs/peer.md)."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest

from tests.conftest import write_grid_city
from uavplace.dataset.build import build_city
from uavplace.ingest.pipeline import ingest_city
from uavplace.schemas import InputError
from uavplace.schemas.bundle import BuildConfig

pytest.importorskip("stable_baselines3", reason="Stable-Baselines3 missing (pip install -e '.[peer]')")


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("peer")
    ingest_city(write_grid_city(tmp / "raw", nx=12, ny=10, n_tx=4, outputs=("power",), seed=5), tmp / "p", name="tiny")
    build_city("tiny", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-58.0), tmp / "p")
    return tmp / "p"


def test_env_passes_sb3_checker_with_scaled_observations(root):
    """SB3's env checker accepts the env; ``obs_scale`` divides the observations and their bounds, nothing else."""
    from stable_baselines3.common.env_checker import check_env

    import uavplace.rl  # noqa: F401 - registers the envs

    plain = gym.make("uavplace/UavPlacement-v0", dataset="tiny", root=str(root)).unwrapped
    scaled = gym.make("uavplace/UavPlacement-v0", dataset="tiny", root=str(root), obs_scale=50.0).unwrapped
    check_env(scaled)
    assert scaled.observation_space.high.max() == pytest.approx(plain.observation_space.high.max() / 50)
    a, _ = plain.reset(seed=3)
    b, _ = scaled.reset(seed=3)
    np.testing.assert_allclose(b, a / 50, rtol=1e-6)
    assert scaled.observation_space.contains(b)
    for action in (0, 1, 2, 3):
        a, ra, *_ = plain.step(action)
        b, rb, *_ = scaled.step(action)
        np.testing.assert_allclose(b, a / 50, rtol=1e-6)
        assert ra == rb  # the rewards are the env's own
    with pytest.raises(ValueError, match="obs_scale"):
        gym.make("uavplace/UavPlacement-v0", dataset="tiny", root=str(root), obs_scale=0.0)


@pytest.mark.parametrize("algo", ["dqn", "ppo"])
def test_sb3_trains_and_plays_in_the_report_evaluation(tmp_path, root, algo):
    """A few hundred steps of SB3 on the env, saved as weights only, loaded back as a Policy that plays the report's
    episodes beside the genie, the same moves each time (its random moves drawn per episode); a file that holds Python
    objects is refused, not unpickled."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.eval.evaluate import ReportConfig, evaluate
    from uavplace.eval.peer import load_peer, train_sb3
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.policies import GeniePolicy
    from uavplace.rl.world.maps import MapSet

    bundle = load_bundle("tiny", root=root)
    maps = MapSet([bundle], EnvConfig(t_max=30))
    record = train_sb3(algo, maps, tmp_path / algo, cpu_seconds=120, max_steps=256, n_envs=2, seed=1)
    assert 256 <= record["steps"] < 256 + 256 and record["cities"] == ["tiny"] and record["obs_scale"] == 50.0
    config = ReportConfig(dataset="tiny", episodes=24, t_max=40, trajectories=0)
    eval_maps = MapSet([bundle], EnvConfig(t_max=40, rotate=False))
    runs = [evaluate(config, bundle, [], baselines=[GeniePolicy(), load_peer(tmp_path / algo, eval_maps)]) for _ in range(2)]
    name = f"SB3 {algo.upper()} ({algo})"
    assert set(runs[0]) == {"genie", name}
    assert runs[0][name].equals(runs[1][name]) and len(runs[0][name]) == 24
    assert (runs[0][name]["steps"] >= runs[0]["genie"]["steps"]).all()  # nobody beats the shortest path
    (tmp_path / algo / "policy.pt").write_bytes(pickle.dumps(print))
    with pytest.raises(InputError, match="not the weights of SB3"):
        load_peer(tmp_path / algo, eval_maps)

"""Stable-Baselines3 on uavplace's Gymnasium env: a peer trained on the same cities, played by the report's evaluation.

``train_sb3`` trains SB3's DQN or PPO with its CNN policy (``CnnPolicy``, the Nature CNN) on
``uavplace/UavPlacement-v0`` (several envs sharing one ``MapSet``; observations scaled by ``OBS_SCALE``,
the env's ``obs_scale``) until a budget of CPU seconds of this process, or of steps, is spent; the
policy's weights are saved as a weights-only torch file (never SB3's zip, whose ``load`` unpickles).
``SB3Policy`` plays a model as a ``rl.tasks.placement.policies.Policy``, with the test-epsilon random legal moves of
uavplace's agents drawn per episode, so that ``eval.evaluate.evaluate`` scores it beside them on the
same episodes. ``peer_table`` plays a `best` run, the peers and the genie on the same episodes of validation cities.
``uavrl peer train`` and ``uavrl peer table`` are the commands; docs/peer.md has the worked example and the results.
"""

from __future__ import annotations

import io
import json
import pickle  # only for the error a refused (non-weights) file raises: nothing is unpickled
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
import torch

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import ReportConfig, evaluate, load_agent
from uavplace.eval.metrics import bootstrap_table
from uavplace.infra.files import atomic_write_bytes, atomic_write_text
from uavplace.rl.randomness import stream_key
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.tasks.placement.policies import GeniePolicy, episode_draws, pick_legal
from uavplace.rl.world.cities import plan_cities
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.rows import decode_obs
from uavplace.rl.world.stats import format_stat
from uavplace.schemas import InputError

#: What the env's observations are divided by for SB3 (uavplace's own networks divide by the same).
OBS_SCALE = 50.0

#: SB3 hyperparameters: its Atari settings (rl-baselines3-zoo), with the replay's warm-up and size cut to what a
#: budget of minutes on a CPU can fill. ``policy_kwargs`` ``normalize_images=False``: the observations are floats of
#: order 1 already, not 0-255 pixels.
HYPERPARAMETERS: dict[str, dict] = {
    "ppo": {
        "n_steps": 128,
        "batch_size": 256,
        "n_epochs": 4,
        "learning_rate": 2.5e-4,
        "clip_range": 0.1,
        "ent_coef": 0.01,
        "vf_coef": 0.5,
    },
    "dqn": {
        "buffer_size": 50_000,
        "learning_starts": 5_000,
        "batch_size": 32,
        "learning_rate": 1e-4,
        "target_update_interval": 1_000,
        "train_freq": 4,
        "gradient_steps": 1,
        "exploration_fraction": 0.1,
        "exploration_final_eps": 0.01,
        "optimize_memory_usage": True,
        "replay_buffer_kwargs": {"handle_timeout_termination": False},
    },
}
#: The weights file and its record in a peer's folder.
WEIGHTS, RECORD = "policy.pt", "peer.json"


def _sb3():  # noqa: ANN202 - the module
    try:
        import stable_baselines3
    except ImportError:
        raise RuntimeError("Stable-Baselines3 is not installed: pip install -e '.[peer]'") from None
    return stable_baselines3


def make_model(algo: Literal["dqn", "ppo"], maps: MapSet, n_envs: int, seed: int):  # noqa: ANN201 - an SB3 model
    """An untrained SB3 ``algo`` with its CNN policy on ``n_envs`` envs over ``maps`` (shared, not copied)."""
    sb3 = _sb3()
    from stable_baselines3.common.vec_env import DummyVecEnv

    from uavplace.rl.tasks.placement.gym import UavPlacementEnv

    venv = DummyVecEnv([lambda: UavPlacementEnv(maps, obs_scale=OBS_SCALE) for _ in range(n_envs)])
    venv.seed(seed)
    cls = {"dqn": sb3.DQN, "ppo": sb3.PPO}[algo]
    return cls(
        "CnnPolicy", venv, seed=seed, device="cpu", verbose=0, policy_kwargs={"normalize_images": False}, **HYPERPARAMETERS[algo]
    )


def train_sb3(
    algo: Literal["dqn", "ppo"],
    maps: MapSet,
    out: Path,
    *,
    cpu_seconds: float,
    max_steps: int = 300_000,
    n_envs: int = 8,
    seed: int = 0,
    on_progress: Callable[[int, float], None] | None = None,
) -> dict:
    """Train until this process has used ``cpu_seconds`` of CPU time (or ``max_steps`` env steps; the schedules
    anneal over ``max_steps``); write ``out/policy.pt`` (weights only) and ``out/peer.json``; return the record."""
    from stable_baselines3.common.callbacks import BaseCallback

    model = make_model(algo, maps, n_envs, seed)
    cpu0, wall0 = time.process_time(), time.perf_counter()

    class Budget(BaseCallback):
        def _on_step(self) -> bool:
            spent = time.process_time() - cpu0
            if on_progress is not None and self.num_timesteps % 1000 < n_envs:
                on_progress(self.num_timesteps, spent)
            return spent < cpu_seconds

    model.learn(max_steps, callback=Budget())
    record = {
        "algo": algo,
        "policy": "CnnPolicy",
        "hyperparameters": HYPERPARAMETERS[algo],
        "n_envs": n_envs,
        "seed": seed,
        "obs_scale": OBS_SCALE,
        "env": maps.config.model_dump(mode="json"),
        "cities": [b.city for b in maps.bundles],
        "bundle_versions": {b.city: b.version for b in maps.bundles},
        "steps": int(model.num_timesteps),
        "max_steps": max_steps,
        "cpu_seconds": round(time.process_time() - cpu0, 1),
        "cpu_budget_s": cpu_seconds,
        "wall_seconds": round(time.perf_counter() - wall0, 1),
        "torch_threads": torch.get_num_threads(),
        "stable_baselines3": _sb3().__version__,
    }
    out.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    torch.save(model.policy.state_dict(), buffer)
    atomic_write_bytes(out / WEIGHTS, buffer.getvalue())
    atomic_write_text(out / RECORD, json.dumps(record, indent=2) + "\n")
    return record


def load_peer(folder: Path, maps: MapSet, epsilon: float = 0.096, seed: int = 0) -> SB3Policy:
    """A peer folder of ``train_sb3`` as a ``Policy`` named ``SB3 <ALGO> (<folder>)``: its record and weights-only
    state, loaded into a fresh model of the same algorithm (``InputError`` naming the file otherwise)."""
    try:
        record = json.loads((folder / RECORD).read_text(encoding="utf-8"))
        algo = record["algo"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(folder / RECORD, f"not a peer record of `uavrl peer train` ({str(exc)[:120]})") from None
    if algo not in HYPERPARAMETERS:
        raise InputError(folder / RECORD, f"unknown algorithm {algo!r}", field="algo")
    with warnings.catch_warnings():  # PPO's batch-size advice is for training, which this model never does
        warnings.simplefilter("ignore", UserWarning)
        model = make_model(algo, maps, 1, seed)
    try:
        state = torch.load(folder / WEIGHTS, map_location="cpu", weights_only=True)
        model.policy.load_state_dict(state)
    except (OSError, RuntimeError, ValueError, pickle.UnpicklingError) as exc:
        raise InputError(folder / WEIGHTS, f"not the weights of SB3's {algo.upper()} CnnPolicy ({str(exc)[:160]})") from None
    return SB3Policy(model, f"SB3 {algo.upper()} ({folder.name})", epsilon=epsilon, seed=seed)


class SB3Policy:
    """An SB3 model acting on the batched env: its deterministic action on the scaled observation, a random legal move
    w.p. ``epsilon`` (drawn per episode and step, as ``DQNPolicy`` draws it). SB3 ignores the legal-move mask: an
    illegal move leaves the UAV in place, as in the env it trained in."""

    def __init__(self, model, name: str, epsilon: float = 0.096, seed: int = 0) -> None:  # noqa: ANN001 - an SB3 model
        self.model, self.name, self.epsilon = model, name, epsilon
        self.stream = stream_key(name, seed)

    def reset(self, rows: np.ndarray, num_envs: int) -> None:
        pass

    def act(self, obs: np.ndarray, mask: np.ndarray, env: BatchedEnv) -> np.ndarray:
        x = decode_obs(obs) if obs.dtype == np.uint8 else obs
        greedy, _ = self.model.predict(x / np.float32(OBS_SCALE), deterministic=True)
        u = episode_draws(env, self.stream, 5)
        return np.where(u[:, 0] < self.epsilon, pick_legal(mask, u[:, 1:]), np.asarray(greedy, np.int64))


def training_maps(cities: list[str], root: str | Path) -> MapSet:
    """The maps a `best` run trains on in ``cities`` (their training users; the paper's env: t_max 800)."""
    plan = plan_cities([load_bundle(c, root=root) for c in cities], [], None)
    return MapSet(plan.train, EnvConfig(split=plan.train_split), plan.train_users)


def peer_table(
    best: Path, peers: list[Path], cities: list[str], root: str | Path, episodes: int = 1000, seed: int = 0
) -> list[list[str]]:
    """The `best` run ``best``, the peers and the genie on the same ``episodes`` of each city (``evaluate``: t_max 500,
    test epsilon 0.096 for every learner): text rows (header first) of success and median steps with 95 % intervals over
    users then episodes, and the ratios best / peer (success) and peer / best (median steps)."""
    agent = load_agent(best, 0.096, seed)
    agent.name = agent.policy.name = f"{agent.name} [{best.name}]"
    bundles = {city: load_bundle(city, root=root) for city in cities}
    # The peers once: a model is made with an env, but its weights and its moves do not depend on which city's.
    maps = MapSet([bundles[cities[0]]], EnvConfig(t_max=500, rotate=False))
    players = [load_peer(folder, maps, seed=seed) for folder in peers]
    rows = [["city", "method", "success", "median steps", "best / it: success", "it / best: median steps"]]
    for city, bundle in bundles.items():
        config = ReportConfig(dataset=city, episodes=episodes, t_max=500, seed=seed, trajectories=0)
        t = bootstrap_table(evaluate(config, bundle, [agent], baselines=[GeniePolicy(), *players]), seed=seed)
        t = t.set_index("method")
        ref = t.loc[agent.name]
        for name in [agent.name, *(p.name for p in players), GeniePolicy.name]:
            r = t.loc[name]
            first = name == agent.name
            ratio_s = "-" if first or r.success == 0 else f"{ref.success / r.success:.2f}"
            ratio_m = "-" if first else ("inf" if not np.isfinite(r.median_steps) else f"{r.median_steps / ref.median_steps:.2f}")
            rows.append(
                [
                    city,
                    name,
                    format_stat("success", r.success, r.success_lo, r.success_hi),
                    format_stat("median_steps", r.median_steps, r.median_steps_lo, r.median_steps_hi, 500),
                    ratio_s,
                    ratio_m,
                ]
            )
    return rows


def run_wall_seconds(run: Path) -> float:
    """The wall seconds a training run took (its last evaluation's ``wall_s``): a peer's CPU budget."""
    try:
        return float(pd.read_parquet(run / "eval.parquet")["wall_s"].iloc[-1])
    except (OSError, ValueError, KeyError, IndexError) as exc:
        raise InputError(run / "eval.parquet", f"no wall time of a finished run ({str(exc)[:120]})", field="wall_s") from None

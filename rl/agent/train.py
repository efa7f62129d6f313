"""`uavrl train`: the training loop, its run folder and exact resumption.

``runs/<run-id>/``: ``run.json`` (the ``DQNConfig``, datasets and bundle versions, the command),
``metrics.parquet`` (one row per finished training episode), ``eval.parquet`` (one row per
evaluation), ``checkpoints/last.pt`` (everything needed to continue exactly: networks,
optimiser, step counters, every random state, the environments' state) with
``checkpoints/replay.npz``, and ``checkpoints/best.pt`` (the network of the best evaluation).
"""

from __future__ import annotations

import datetime as dt
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from dataset.bundle import Bundle, load_bundle
from rl.agent.dqn import DQN, DQNConfig, DQNPolicy, make_network
from rl.agent.replay import ReplayBuffer
from rl.maps import MapSet
from rl.rollout import run_episodes, summarise
from rl.vec_env import BatchedEnv
from schemas.base import uavplace_version

_ENV_STATE = ("view", "pos", "t", "episode_id", "memory", "visited", "_episodes_started")


@dataclass
class Progress:
    step: int
    total: int
    episodes: int
    gain_mean100: float
    success100: float
    epsilon: float
    loss: float
    best: float | None


@dataclass
class RunState:
    """What changes while training (and is saved for resuming)."""

    step: int = 0
    last_action: np.ndarray | None = None
    start_sinr: np.ndarray | None = None
    episodes: list[dict] = field(default_factory=list)
    evals: list[dict] = field(default_factory=list)
    best_score: tuple[float, float] | None = None
    synced_at: int = 0
    losses: list[float] = field(default_factory=list)


def linear(start: float, end: float, frac: float) -> float:
    return start + (end - start) * min(max(frac, 0.0), 1.0)


def _split_or_none(bundles: list[Bundle], wanted: str | None) -> str | None:
    """``wanted`` if some bundle user is in that split, else None (all users)."""
    if wanted is None:
        return None
    return wanted if any(len(b.user_indices(wanted)) for b in bundles) else None


def _atomic_torch_save(obj: object, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def _atomic_parquet(df: pd.DataFrame, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    df.to_parquet(tmp, index=False)
    os.replace(tmp, path)


class Trainer:
    """One training run over built cities; ``run()`` trains to ``config.total_steps`` (or resumes)."""

    def __init__(self, config: DQNConfig, datasets: list[str], root: str | Path, run_dir: Path, command: str = "") -> None:
        self.config, self.datasets, self.root, self.run_dir = config, list(datasets), str(root), Path(run_dir)
        torch.manual_seed(config.seed)
        if "OMP_NUM_THREADS" not in os.environ:  # both cores of the reference machine, unless told otherwise
            torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))
        bundles = [load_bundle(name, root=self.root) for name in self.datasets]
        train_split = _split_or_none(bundles, "train")
        self.maps = MapSet(bundles, config.env_config().model_copy(update={"split": train_split}))
        eval_cfg = config.env_config(evaluation=True)
        self.eval_split = _split_or_none(bundles, config.eval_split)
        self.eval_maps = MapSet(bundles, eval_cfg.model_copy(update={"split": self.eval_split}))
        self.eval_episodes = self.eval_maps.sample_episodes(config.eval_episodes, np.random.default_rng([config.seed, 2]))
        self.env = BatchedEnv(self.maps, config.num_envs, compact=True)
        c, w = self.maps.config.num_channels, self.maps.config.window
        self.agent = DQN(config, c, w)
        self.replay = ReplayBuffer(config.buffer_size, config.num_envs, (c, w, w), config.env.t_max, config.n_step, config.gamma)
        self.rng = np.random.default_rng([config.seed, 1])
        self.state = RunState()
        self.command = command

    # -- run folder ---------------------------------------------------------------------------------
    @property
    def checkpoints(self) -> Path:
        return self.run_dir / "checkpoints"

    def write_run_json(self) -> None:
        doc = {
            "config": json.loads(self.config.model_dump_json()),
            "datasets": {b.city: b.version for b in self.maps.bundles},
            "train_split": self.maps.config.split,
            "eval_split": self.eval_split,
            "command": self.command,
            "uavplace_version": uavplace_version(),
            "torch_version": torch.__version__,
            "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        }
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / "run.json").write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")

    def save(self) -> None:
        self.checkpoints.mkdir(parents=True, exist_ok=True)
        s = self.state
        env_state = {k: getattr(self.env, k) for k in _ENV_STATE} | {"rng": self.env.rng.bit_generator.state}
        _atomic_torch_save(
            {
                "online": self.agent.online.state_dict(),
                "target": self.agent.target.state_dict(),
                "optimizer": self.agent.optimizer.state_dict(),
                "updates": self.agent.updates,
                "state": {k: getattr(s, k) for k in ("step", "last_action", "start_sinr", "best_score", "synced_at")},
                "rng": self.rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(),
                "cuda_rng": torch.cuda.get_rng_state_all() if self.agent.device.type == "cuda" else None,
                "env": env_state,
            },
            self.checkpoints / "last.pt",
        )
        tmp = self.checkpoints / "replay.tmp.npz"
        self.replay.save(tmp)
        os.replace(tmp, self.checkpoints / "replay.npz")
        _atomic_parquet(with_running_means(pd.DataFrame(s.episodes)), self.run_dir / "metrics.parquet")
        _atomic_parquet(pd.DataFrame(s.evals), self.run_dir / "eval.parquet")

    def load(self) -> None:
        ck = torch.load(self.checkpoints / "last.pt", weights_only=False, map_location=self.agent.device)
        self.agent.online.load_state_dict(ck["online"])
        self.agent.target.load_state_dict(ck["target"])
        self.agent.optimizer.load_state_dict(ck["optimizer"])
        self.agent.updates = ck["updates"]
        for k, v in ck["state"].items():
            setattr(self.state, k, v)
        self.rng.bit_generator.state = ck["rng"]
        torch.set_rng_state(ck["torch_rng"].cpu())
        if ck.get("cuda_rng") is not None:
            torch.cuda.set_rng_state_all([t.cpu() for t in ck["cuda_rng"]])
        for k in _ENV_STATE:
            value = ck["env"][k]
            if isinstance(value, np.ndarray):
                getattr(self.env, k)[...] = value
            else:
                setattr(self.env, k, value)
        self.env.rng.bit_generator.state = ck["env"]["rng"]
        self.replay.load(self.checkpoints / "replay.npz")
        metrics = pd.read_parquet(self.run_dir / "metrics.parquet")
        self.state.episodes = metrics.drop(columns=["sinr_gain_mean100_db", "success_mean100"], errors="ignore").to_dict(
            "records"
        )
        self.state.evals = pd.read_parquet(self.run_dir / "eval.parquet").to_dict("records")

    # -- evaluation ---------------------------------------------------------------------------------
    def evaluate(self) -> dict:
        policy = DQNPolicy(self.agent.online, self.config.test_epsilon, seed=self.config.seed)
        df = run_episodes(self.eval_maps, policy, self.eval_episodes, num_envs=min(256, len(self.eval_episodes)))
        summary = summarise(df)
        row = {
            "step": self.state.step,
            "success": summary["success"],
            "median_steps": summary["median_steps"],
            "mean_return": float(df.return_.mean()),
        }
        score = (row["success"], -row["median_steps"])
        if self.state.best_score is None or score > tuple(self.state.best_score):
            self.state.best_score = score
            self.checkpoints.mkdir(parents=True, exist_ok=True)
            _atomic_torch_save(
                {"online": self.agent.online.state_dict(), "config": self.config.model_dump(mode="json"), "eval": row},
                self.checkpoints / "best.pt",
            )
            row["best"] = True
        else:
            row["best"] = False
        self.state.evals.append(row)
        return row

    # -- the loop -----------------------------------------------------------------------------------
    def run(
        self, resume: bool = False, on_progress: Callable[[Progress], None] | None = None, stop_at: int | None = None
    ) -> Path:
        """Train to ``total_steps`` (from the last checkpoint if ``resume``). ``stop_at`` stops at that
        step (the first multiple of ``num_envs`` at or past it) and checkpoints there."""
        cfg, env, s = self.config, self.env, self.state
        n = cfg.num_envs
        if resume:
            self.load()
            obs, mask = env.observe(), env.action_mask()
        else:
            self.write_run_json()
            obs, info = env.reset(seed=cfg.seed)
            mask = info["action_mask"]
            s.last_action = np.full(n, -1, np.int64)
            s.start_sinr = env.sinr_here().copy()
        next_eval = (s.step // cfg.eval_every + 1) * cfg.eval_every
        while s.step < cfg.total_steps and (stop_at is None or s.step < stop_at):
            frac = s.step / cfg.total_steps
            eps = linear(cfg.eps_start, cfg.eps_end, s.step / (cfg.eps_fraction * cfg.total_steps))
            actions = self.agent.act(obs, mask, eps, s.last_action, self.rng)
            next_obs, reward, term, trunc, info = env.step(actions)
            final_obs = final_mask = np.zeros((0,))
            if trunc.any():
                pick = np.isin(info["final_index"], np.flatnonzero(trunc))
                final_obs, final_mask = info["final_obs"][pick], info["final_mask"][pick]
            self.replay.add(obs, mask, actions, reward, term, trunc, final_obs, final_mask)
            s.step += n
            done = term | trunc
            s.last_action = np.where(done, -1, actions)
            if done.any():
                rows = np.flatnonzero(done)
                for r in rows:
                    s.episodes.append(
                        {
                            "step": s.step,
                            "episode": len(s.episodes),
                            "sinr_gain_db": float(info["sinr"][r] - s.start_sinr[r]),
                            "success": bool(term[r]),
                            "length": int(info["steps"][r]),
                            "epsilon": eps,
                            "lr": linear(cfg.lr_start, cfg.lr_end, frac),
                            "loss": float(np.mean(s.losses[-50:])) if s.losses else float("nan"),
                        }
                    )
                s.start_sinr[rows] = env.sinr_here()[rows]
            obs, mask = next_obs, info["action_mask"]
            if s.step >= cfg.learning_starts and self.replay.can_sample():
                # One gradient step per train_every env steps since learning started.
                owed = (s.step - cfg.learning_starts) // cfg.train_every - self.agent.updates
                for _ in range(max(0, owed)):
                    batch = self.replay.sample(cfg.batch_size, self.rng)
                    s.losses.append(self.agent.update(batch, linear(cfg.lr_start, cfg.lr_end, frac)))
                s.losses = s.losses[-200:]
            if s.step - s.synced_at >= cfg.target_update:
                self.agent.sync_target()
                s.synced_at = s.step
            if s.step >= next_eval or s.step >= cfg.total_steps:
                self.evaluate()
                self.save()
                next_eval += cfg.eval_every
            if on_progress is not None:
                last = s.episodes[-100:]
                on_progress(
                    Progress(
                        step=s.step,
                        total=cfg.total_steps,
                        episodes=len(s.episodes),
                        gain_mean100=float(np.mean([e["sinr_gain_db"] for e in last])) if last else float("nan"),
                        success100=float(np.mean([e["success"] for e in last])) if last else float("nan"),
                        epsilon=eps,
                        loss=float(np.mean(s.losses[-50:])) if s.losses else float("nan"),
                        best=s.best_score[0] if s.best_score else None,
                    )
                )
        if stop_at is not None and stop_at <= s.step < cfg.total_steps:
            self.save()  # a planned stop (`--until`): resumable from here
        return self.run_dir


def with_running_means(df: pd.DataFrame) -> pd.DataFrame:
    """Per-episode metrics plus their means over the last 100 episodes (the paper's training curve)."""
    if len(df):
        df = df.assign(
            sinr_gain_mean100_db=df["sinr_gain_db"].rolling(100, min_periods=1).mean(),
            success_mean100=df["success"].astype(float).rolling(100, min_periods=1).mean(),
        )
    return df


def new_run_dir(runs: str | Path, config: DQNConfig) -> Path:
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    return Path(runs) / f"{stamp}-{config.preset}-{config.agent}-s{config.seed}"


def load_policy(path: str | Path, epsilon: float = 0.096, seed: int = 0, name: str | None = None) -> tuple[DQNPolicy, DQNConfig]:
    """A checkpoint (``best.pt`` or ``last.pt``) as a ``Policy``, with the config it was trained with."""
    ck = torch.load(path, weights_only=False, map_location="cpu")
    config = DQNConfig.model_validate(ck["config"]) if "config" in ck else None
    if config is None:
        raise ValueError(f"{path}: no config in the checkpoint")
    env = config.env_config()
    net = make_network(config, env.num_channels, env.window)
    net.load_state_dict(ck["online"])
    return DQNPolicy(net, epsilon, seed, name or config.agent), config

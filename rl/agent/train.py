"""`uavrl train`: the training loop, its run folder and exact resumption.

``runs/<run-id>/``: ``run.json`` (the ``DQNConfig``, datasets and bundle versions, the command),
``metrics.parquet`` (one row per finished training episode), ``eval.parquet`` (one row per
evaluation, with ``wall_s``: the seconds of training and evaluation up to it, summed over the
run's starts and resumes; the time since the last checkpoint of a killed part is lost with it), ``checkpoints/last/`` (everything needed to continue exactly: networks, optimiser,
step counters, every random state, the environments' state, the replay or PQN's rollout so far,
the metrics up to its step; one folder renamed into place, see ``rl.agent.checkpoint``), and
``checkpoints/best.pt`` (the network of the best evaluation). No checkpoint is a pickle of Python
objects: they load with ``weights_only=True``. A run of any task (``DQNConfig.task``, ``uavrl train --task``) is
the same loop, learner and folder; the task gives its env and validation (its learner hook, ``rl.tasks.entry``).
"""

from __future__ import annotations

import datetime as dt
import io
import json
import os
import stat
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from uavplace.dataset.bundle import load_bundle
from uavplace.infra.files import (
    ARCHIVE_ERRORS,
    atomic_directory,
    atomic_write_bytes,
    atomic_write_text,
    recover_directory,
    write_model_json,
)
from uavplace.infra.tensors import load_tensors, save_tensors
from uavplace.rl.agent.checkpoint import CHECKPOINT_JSON, require
from uavplace.rl.agent.config import DQNConfig
from uavplace.rl.agent.dqn import DQN, DQNPolicy
from uavplace.rl.agent.pqn import Rollout, pqn_round
from uavplace.rl.agent.replay import ReplayBuffer
from uavplace.rl.agent.resume import Interrupted, RunState, interrupts, read_state, start_from
from uavplace.rl.agent.runs import LAST, RUN_JSON, RunRecord, read_run_json
from uavplace.rl.tasks.registry import task_of
from uavplace.rl.world.cities import plan_cities
from uavplace.schemas import InputError
from uavplace.schemas.base import uavplace_version
from uavplace.schemas.bundle import BundleSettings


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


def linear(start: float, end: float, frac: float) -> float:
    return start + (end - start) * min(max(frac, 0.0), 1.0)


def _atomic_parquet(df: pd.DataFrame, path: Path) -> None:
    buffer = io.BytesIO()
    df.to_parquet(buffer, index=False)
    atomic_write_bytes(path, buffer.getvalue())


class Trainer:
    """One training run over built cities; ``run()`` trains to ``config.total_steps`` (or resumes)."""

    def __init__(
        self,
        config: DQNConfig,
        datasets: list[str],
        root: str | Path,
        run_dir: Path,
        command: str = "",
        val_datasets: list[str] | None = None,
        fast: bool = True,
    ) -> None:
        """``fast``: ``DQN``'s (the same computation, arranged for speed; False only to measure it)."""
        self.config, self.datasets, self.root, self.run_dir = config, list(datasets), str(root), Path(run_dir)
        if config.ensemble != 1:
            raise InputError(
                None, "a run trains one network: build an ensemble from finished runs with `uavrl ensemble`", field="ensemble"
            )
        torch.manual_seed(config.seed)
        if "OMP_NUM_THREADS" not in os.environ:  # both cores of the reference machine, unless told otherwise
            torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))
        bundles = [load_bundle(name, root=self.root) for name in self.datasets]
        cities = plan_cities(bundles, [load_bundle(n, root=self.root) for n in val_datasets or []], config.eval_split)
        self.train_split, self.eval_split = cities.train_split, cities.val_split
        self.learning = task_of(config.task).learn(config, cities)
        self.env, self.train_bundles, self.val_bundles = self.learning.env, self.learning.train_bundles, self.learning.val_bundles
        c, w = config.observation()
        a = config.n_actions
        self.agent = DQN(config, c, w, fast=fast)
        if config.init is not None:
            start_from(self.agent, config)
        # What the learner learns from, saved with every checkpoint: the replay, or PQN's rollout so far.
        self.replay: ReplayBuffer | None = None
        self.rollout: Rollout | None = None
        if config.learner == "pqn":
            hidden = config.hidden if config.recurrent else 0
            self.rollout = self.memory = Rollout(config.rollout_steps, config.num_envs, (c, w, w), hidden, a)
            self.memory_file = "rollout.npz"
        else:
            self.replay = self.memory = ReplayBuffer(
                config.buffer_size, config.num_envs, (c, w, w), self.t_max, config.n_step, config.gamma, a
            )
            self.memory_file = "replay.npz"
        self.rng = np.random.default_rng([config.seed, 1])
        self.state = RunState()
        self.command = command
        self.loaded = False  # True once ``load()`` restored a checkpoint
        self._began = time.perf_counter()  # when this start began (``run``)

    # -- the task: its learner hook's (rl/tasks/<task>/learner.py) --------------------------------------
    @property
    def t_max(self) -> int:
        """The training episodes' step budget."""
        return self.learning.t_max

    def validate(self, policy: DQNPolicy) -> tuple[dict, tuple[float, float]]:
        """``policy`` on the task's fixed validation episodes: the evaluation row's values, and its score (higher is
        better: ``best.pt`` keeps the best)."""
        return self.learning.validate(policy)

    def episode_values(self, info: dict, row: int, terminated: bool) -> dict:
        """A finished training episode's task values for ``metrics.parquet``."""
        return self.learning.episode_values(info, row, terminated)

    # -- run folder ---------------------------------------------------------------------------------
    @property
    def checkpoints(self) -> Path:
        return self.run_dir / "checkpoints"

    def write_run_json(self) -> None:
        trained = {b.city: b.version for b in self.train_bundles}
        record = RunRecord(
            config=self.config,
            datasets=trained,
            bundle_settings={b.city: BundleSettings.of(b.manifest) for b in self.train_bundles},
            val_datasets={b.city: b.version for b in self.val_bundles if b.city not in trained},
            train_split=self.train_split,
            eval_split=self.eval_split,
            command=self.command,
            uavplace_version=uavplace_version(),
            torch_version=torch.__version__,
            created_utc=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        )
        self.run_dir.mkdir(parents=True, exist_ok=True)
        write_model_json(record, self.run_dir / RUN_JSON)

    def record_resume(self, step: int) -> None:
        """Append this command, resumed from ``step``, to ``run.json``'s ``resumed`` (atomically)."""
        record = read_run_json(self.run_dir)
        record.resumed.append(f"{self.command} (from step {step})")
        atomic_write_text(self.run_dir / RUN_JSON, record.model_dump_json(indent=2) + "\n")

    def wall_s(self) -> float | None:
        """Seconds this run has trained and evaluated, over all its starts (``None`` if a checkpoint lacked them)."""
        before = self.state.wall_s
        return None if before is None else before + time.perf_counter() - self._began

    def save(self, resumed_from: int | None = None) -> None:
        """Write ``checkpoints/last/`` as one unit (a folder renamed into place), then publish the metrics;
        ``resumed_from``: record this command's resume from that step in ``run.json`` first (``record_resume``)."""
        if resumed_from is not None:
            self.record_resume(resumed_from)
        s = self.state
        metrics = with_running_means(pd.DataFrame(s.episodes))
        evals = pd.DataFrame(s.evals)
        with atomic_directory(self.checkpoints / LAST, marker=CHECKPOINT_JSON, what="training checkpoint") as tmp:
            networks = {
                "online": self.agent.online.state_dict(),
                "target": self.agent.target.state_dict(),
                "optimizer": self.agent.optimizer.state_dict(),
                "torch_rng": torch.get_rng_state(),
            }
            if self.agent.device.type == "cuda":
                networks["cuda_rng"] = torch.cuda.get_rng_state_all()
            if self.agent.hidden is not None:
                networks["hidden"] = self.agent.hidden
            save_tensors(networks, tmp / "networks.pt")
            arrays = {k: getattr(self.env, k) for k in self.env.state_arrays}
            np.savez(tmp / "env.npz", **arrays, last_action=s.last_action, start_sinr=s.start_sinr)
            self.memory.save(tmp / self.memory_file)
            metrics.to_parquet(tmp / "metrics.parquet", index=False)
            evals.to_parquet(tmp / "eval.parquet", index=False)
            doc = {
                "step": s.step,
                "updates": self.agent.updates,
                "best_score": list(s.best_score) if s.best_score is not None else None,
                "synced_at": s.synced_at,
                "losses": [float(x) for x in s.losses],
                "episodes_started": self.env._episodes_started,
                "rng": self.rng.bit_generator.state,
                "env_rng": self.env.rng.bit_generator.state,
                "wall_s": self.wall_s(),
            }
            (tmp / CHECKPOINT_JSON).write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        _atomic_parquet(metrics, self.run_dir / "metrics.parquet")
        _atomic_parquet(evals, self.run_dir / "eval.parquet")

    def resumable(self) -> bool:
        """Whether the run folder holds a checkpoint to continue from (or an old one that ``load`` names); a run killed
        before its first checkpoint has none, and a resume starts it over."""
        last = self.checkpoints / LAST
        recover_directory(last)
        return (last / CHECKPOINT_JSON).is_file() or (self.checkpoints / "last.pt").exists()

    def load(self) -> None:
        """Restore everything from ``checkpoints/last/`` (``InputError`` if it is missing, partial or not data)."""
        last = self.checkpoints / LAST
        recover_directory(last)  # a kill between the swap's two renames leaves the previous checkpoint aside
        if not (last / CHECKPOINT_JSON).is_file():
            old = " (an old pickled last.pt is not loaded: start a new run)" if (self.checkpoints / "last.pt").exists() else ""
            raise InputError(last, f"no complete checkpoint to resume from{old}", field=CHECKPOINT_JSON)
        for entry in last.iterdir():  # a FIFO would block np.load for ever, a link lead elsewhere: refused unopened
            if not stat.S_ISREG(entry.lstat().st_mode):
                raise InputError(entry, "not a regular file (a link, a FIFO, a folder): the checkpoint is not resumed")
        try:
            doc = read_state(last / CHECKPOINT_JSON, self.config.total_steps + self.config.num_envs)
            ck = load_tensors(last / "networks.pt", map_location=self.agent.device)
            require(ck, last / "networks.pt", "online", "target", "optimizer", "torch_rng")
            self.agent.online.load_state_dict(ck["online"])
            self.agent.target.load_state_dict(ck["target"])
            self.agent.load_optimizer(ck["optimizer"])
            torch.set_rng_state(ck["torch_rng"].cpu())
            if self.agent.hidden is not None:
                require(ck, last / "networks.pt", "hidden")
                self.agent.hidden.copy_(ck["hidden"])
            if ck.get("cuda_rng") is not None and self.agent.device.type == "cuda":
                torch.cuda.set_rng_state_all([t.cpu() for t in ck["cuda_rng"]])
            with np.load(last / "env.npz", allow_pickle=False) as z:
                for k in self.env.state_arrays:
                    # A checkpoint from before the env counted visits holds which cells were visited: once each.
                    if k == "start" and k not in z:  # from before episodes were keyed by their start: where they stand
                        getattr(self.env, k)[...] = z["pos"] - self.env.maps.pad
                        continue
                    getattr(self.env, k)[...] = z["visited"] if k == "visits" and k not in z else z[k]
                self.state.last_action, self.state.start_sinr = z["last_action"], z["start_sinr"]
            self.env.check_state(last / "env.npz")
            top = self.config.n_actions - 1
            if (
                not np.isfinite(self.state.start_sinr).all()
                or ((self.state.last_action < -1) | (self.state.last_action > top)).any()
            ):
                raise InputError(last / "env.npz", f"start_sinr not finite or last_action outside -1..{top}", field="start_sinr")
            self.agent.updates = doc.updates
            self.state.step, self.state.synced_at = doc.step, doc.synced_at
            self.state.losses = list(doc.losses)
            self.state.best_score = doc.best_score
            self.env._episodes_started = doc.episodes_started
            self.rng.bit_generator.state = doc.rng
            self.env.rng.bit_generator.state = doc.env_rng
            self.state.wall_s = doc.wall_s  # checkpoints before the trainer kept time have none
            self.memory.load(last / self.memory_file)
            metrics = pd.read_parquet(last / "metrics.parquet")
            evals = pd.read_parquet(last / "eval.parquet")
        except InputError:
            raise
        except (*ARCHIVE_ERRORS, KeyError, TypeError) as exc:  # a damaged or foreign checkpoint
            raise InputError(last, f"cannot resume from this checkpoint ({type(exc).__name__}: {str(exc)[:200]})") from None
        self.state.episodes = metrics.drop(columns=["sinr_gain_mean100_db", "success_mean100"], errors="ignore").to_dict(
            "records"
        )
        self.state.evals = evals.to_dict("records")
        self.loaded = True

    # -- evaluation ---------------------------------------------------------------------------------
    def evaluate(self) -> dict:
        values, score = self.validate(DQNPolicy.from_config(self.agent.online, self.config))
        row = {"step": self.state.step, **values, "wall_s": self.wall_s()}
        if self.state.best_score is None or score > tuple(self.state.best_score):
            self.state.best_score = score
            self.checkpoints.mkdir(parents=True, exist_ok=True)
            save_tensors(
                {"online": self.agent.online.state_dict(), "config": self.config.model_dump(mode="json"), "eval": _plain(row)},
                self.checkpoints / "best.pt",
            )
            row["best"] = True
        else:
            row["best"] = False
        self.state.evals.append(row)
        return row

    def _finite(self, losses: list[float], lr: float) -> list[float]:
        """``losses``, or an ``InputError`` once one is NaN or inf: the training stops there, its last checkpoint and
        ``best.pt`` as the last evaluation left them (weights that diverged are never saved: ``save_tensors``)."""
        if np.isfinite(losses).all():
            return losses
        last = self.state.evals[-1]["step"] if self.state.evals else None
        kept = f"checkpoints/ hold step {last:,}" if last is not None else "no checkpoint was written yet"
        raise InputError(
            self.run_dir,
            f"the loss became {next(x for x in losses if not np.isfinite(x))} at step {self.state.step:,} "
            f"(learning rate {lr:.3g}): training stopped; {kept}. Lower --set lr_start or grad_clip",
            field="loss",
        )

    # -- the loop -----------------------------------------------------------------------------------
    def run(
        self, resume: bool = False, on_progress: Callable[[Progress], None] | None = None, stop_at: int | None = None
    ) -> Path:
        """Train to ``total_steps`` (from the last checkpoint if ``resume``). ``stop_at`` stops at that
        step (the first multiple of ``num_envs`` at or past it) and checkpoints there."""
        cfg, env, s = self.config, self.env, self.state
        n = cfg.num_envs
        resume = resume and (self.loaded or self.resumable())  # killed before its first checkpoint: start over
        if resume:
            if not self.loaded:
                self.load()
            obs, mask = env.observe(), env.action_mask()
        else:
            self.write_run_json()
            obs, info = env.reset(seed=cfg.seed)
            mask = info["action_mask"]
            s.last_action = np.full(n, -1, np.int64)
            s.start_sinr = env.sinr_here().copy()
        pending = s.step if resume else None  # a resume is recorded in run.json at its first checkpoint: only those that ran
        self._began = time.perf_counter()
        next_eval = (s.step // cfg.eval_every + 1) * cfg.eval_every
        with interrupts() as interrupted:
            while s.step < cfg.total_steps and (stop_at is None or s.step < stop_at) and not interrupted():
                frac = s.step / cfg.total_steps
                eps = linear(cfg.eps_start, cfg.eps_end, s.step / (cfg.eps_fraction * cfg.total_steps))
                genie = env.genie_moves() if cfg.aux_genie > 0 else None
                if self.rollout is not None and self.rollout.t == 0:
                    self.rollout.h0[...] = self.agent.state()  # a recurrent network learns from the state it began with
                visits = env.neighbour_visits() if cfg.train_revisit_penalty > 0 else None
                actions = self.agent.act(obs, mask, eps, s.last_action, self.rng, visits)
                next_obs, reward, term, trunc, info = env.step(actions)
                final_obs = final_mask = np.zeros((0,))
                if trunc.any():
                    pick = np.isin(info["final_index"], np.flatnonzero(trunc))
                    final_obs, final_mask = info["final_obs"][pick], info["final_mask"][pick]
                self.memory.add(obs, mask, actions, reward, term, trunc, final_obs, final_mask, genie)
                s.step += n
                done = term | trunc
                s.last_action = np.where(done, -1, actions)
                if done.any():
                    rows = np.flatnonzero(done)
                    self.agent.reset_state(rows)
                    for r in rows:
                        s.episodes.append(
                            {
                                "step": s.step,
                                "episode": len(s.episodes),
                                "sinr_gain_db": float(info["sinr"][r] - s.start_sinr[r]),
                                **self.episode_values(info, r, bool(term[r])),
                                "length": int(info["steps"][r]),
                                "epsilon": eps,
                                "lr": linear(cfg.lr_start, cfg.lr_end, frac),
                                "loss": float(np.mean(s.losses[-50:])) if s.losses else float("nan"),
                            }
                        )
                    s.start_sinr[rows] = env.sinr_here()[rows]
                obs, mask = next_obs, info["action_mask"]
                lr = linear(cfg.lr_start, cfg.lr_end, frac)
                if self.rollout is not None:
                    if self.rollout.full:  # PQN: fit this rollout's Q(lambda) returns, then collect the next
                        s.losses.extend(self._finite(pqn_round(self.agent, self.rollout, obs, mask, lr, self.rng), lr))
                        self.rollout.t = 0
                        s.losses = s.losses[-200:]
                elif s.step >= cfg.learning_starts and self.replay.can_sample():
                    # One gradient step per train_every env steps since learning started.
                    owed = (s.step - cfg.learning_starts) // cfg.train_every - self.agent.updates
                    for _ in range(max(0, owed)):
                        batch = self.replay.sample(cfg.batch_size, self.rng)
                        s.losses.extend(self._finite([self.agent.update(batch, lr)], lr))
                    s.losses = s.losses[-200:]
                if self.replay is not None and s.step - s.synced_at >= cfg.target_update:
                    self.agent.sync_target()
                    s.synced_at = s.step
                if s.step >= next_eval or s.step >= cfg.total_steps:
                    self.evaluate()
                    self.save(pending)
                    pending = None
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
            if interrupted():  # Ctrl-C: checkpoint at this step boundary, then say how to go on
                self.save(pending)
                raise Interrupted(self.run_dir, s.step)
        if stop_at is not None and stop_at <= s.step < cfg.total_steps:
            self.save(pending)  # a planned stop (`--until`): resumable from here
        s.wall_s = self.wall_s()  # this start's seconds, for a later ``run`` of this trainer
        return self.run_dir


def with_running_means(df: pd.DataFrame) -> pd.DataFrame:
    """Per-episode metrics plus their means over the last 100 episodes (the paper's training curve)."""
    if len(df):
        df = df.assign(
            sinr_gain_mean100_db=df["sinr_gain_db"].rolling(100, min_periods=1).mean(),
            success_mean100=df["success"].astype(float).rolling(100, min_periods=1).mean(),
        )
    return df


def _plain(row: dict) -> dict:
    """A row of numbers as plain Python values (what a weights-only checkpoint may hold)."""
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()}


def start_run(
    run_dir: Path,
    config: DQNConfig,
    datasets: list[str],
    val_datasets: list[str],
    root: str | Path,
    *,
    resume: bool,
    command: str = "",
) -> Trainer:
    """The trainer of the run in ``run_dir``, ready to ``run(resume=resume)``; call it with the folder's lock held
    (``exclusive_folder``). A new run claims its folder first (``FileExistsError`` when it exists) and gives the name
    back if its trainer cannot be made; a resumed one is loaded (every check of the checkpoint before the first
    step). ``uavrl train`` and every trial of ``uavrl sweep`` start here."""
    claimed = False
    if not resume:
        if run_dir.exists():
            raise FileExistsError(f"{run_dir} exists: choose another --name, or continue it with --resume {run_dir}")
        run_dir.mkdir(parents=True)
        claimed = True
    try:
        trainer = Trainer(config, list(datasets), root, run_dir, command=command, val_datasets=list(val_datasets))
    except BaseException:
        if claimed and not any(run_dir.iterdir()):
            run_dir.rmdir()  # nothing was written: give the name back
        raise
    if resume and trainer.resumable():
        trainer.load()
    return trainer

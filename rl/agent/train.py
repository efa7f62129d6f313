"""`uavrl train`: the training loop, its run folder and exact resumption.

``runs/<run-id>/``: ``run.json`` (the ``DQNConfig``, datasets and bundle versions, the command),
``metrics.parquet`` (one row per finished training episode), ``eval.parquet`` (one row per
evaluation, with ``wall_s``: the seconds of training and evaluation up to it, summed over the
run's starts and resumes; the time since the last checkpoint of a killed part is lost with it), ``checkpoints/last/`` (everything needed to continue exactly: networks, optimiser,
step counters, every random state, the environments' state, the replay or PQN's rollout so far,
the metrics up to its step; one folder renamed into place, see ``rl.agent.checkpoint``), and
``checkpoints/best.pt`` (the network of the best evaluation). No checkpoint is a pickle of Python
objects: they load with ``weights_only=True``. A tracking run (``DQNConfig.task``, ``uavrl train --task
tracking``) is the same loop, learner and folder on the tracking task (``TrackingTrainer``).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import io
import json
import os
import signal
import threading
import time
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from pydantic import Field, ValidationError
from torch import nn

from uavplace.dataset.bundle import Bundle, load_bundle
from uavplace.infra.files import (
    atomic_directory,
    atomic_write_bytes,
    atomic_write_text,
    in_corpus,
    read_small_file,
    recover_directory,
    write_model_json,
)
from uavplace.rl.agent.checkpoint import CHECKPOINT_JSON, CheckpointState, load_tensors, require, save_tensors
from uavplace.rl.agent.dqn import DQN, DQNConfig, DQNPolicy, make_network
from uavplace.rl.agent.pqn import Rollout, pqn_round
from uavplace.rl.agent.replay import ReplayBuffer
from uavplace.rl.maps import MapSet
from uavplace.rl.rollout import run_episodes, summarise
from uavplace.rl.tasks.fleet import FleetMaps, FleetPlacement, FleetTrainEnv, run_fleet
from uavplace.rl.tasks.tracking import RouteSet, TrackingEnv, run_tracking
from uavplace.rl.vec_env import BatchedEnv
from uavplace.schemas import InputError
from uavplace.schemas.base import Contract, uavplace_version, validation_message
from uavplace.schemas.bundle import BundleManifest, BundleSettings

#: The resumable checkpoint folder under ``checkpoints/``.
LAST = "last"


#: The run's record: how it was made.
RUN_JSON = "run.json"


class RunRecord(Contract):
    """``run.json``: the configuration, the bundles trained on, the command; written when a run starts."""

    config: DQNConfig
    datasets: dict[str, str] = Field(description="Training city -> bundle version")
    val_datasets: dict[str, str] = Field(
        default_factory=dict, description="Validation city -> bundle version: the cities best.pt was selected on"
    )
    bundle_settings: dict[str, BundleSettings] = Field(
        default_factory=dict,
        description="Training city -> the settings its bundle was built with (grid, altitude, noise): a report warns "
        "when it plays the agent on a bundle of other settings",
    )
    train_split: str | None = Field(description="Users episodes were drawn from (None: all users)")
    eval_split: str | None = Field(description="Users the periodic evaluation (and best.pt) used")
    command: str
    resumed: list[str] = Field(
        default_factory=list, description="Each later command that continued the run (`--resume`), with the step it resumed from"
    )
    uavplace_version: str
    torch_version: str
    created_utc: str
    members: dict[str, RunRecord] = Field(
        default_factory=dict,
        description="An ensemble's runs (`uavrl ensemble`): each run folder as it was given, with its run.json",
    )

    @property
    def commands(self) -> list[str]:
        """Every command that made the run, in order: an ensemble's members' first, then the first, then each
        ``--resume``."""
        return [*(c for m in self.members.values() for c in m.commands), self.command, *self.resumed]


def settings_unlike(record: RunRecord, manifest: BundleManifest, p_t_db: float | None = None) -> list[str]:
    """How ``manifest``'s bundle differs from every bundle the run was trained on (``BundleSettings.unlike`` against
    its most common training settings; empty when one of them is alike or none is recorded), and ``p_t_db`` from the
    P_T a placement agent was trained at, one phrase each."""
    trained = list(record.bundle_settings.values())
    mine = BundleSettings.of(manifest)
    unlike = [] if not trained or mine in trained else mine.unlike(max(trained, key=trained.count))
    if p_t_db is not None and record.config.task == "placement" and p_t_db != record.config.env.p_t_db:
        unlike.append(f"P_T {p_t_db:g} dB (trained at {record.config.env.p_t_db:g} dB)")
    return unlike


def read_run_json(folder: str | Path) -> RunRecord:
    """A run folder's ``run.json``; ``InputError`` naming the file when it is missing or malformed."""
    path = Path(folder) / RUN_JSON
    data = read_small_file(path, "a run's record", missing="no run.json: not a folder written by `uavrl train`")
    try:
        return RunRecord.model_validate_json(data)
    except (ValidationError, UnicodeDecodeError, ValueError) as exc:
        if isinstance(exc, ValidationError):
            field, message = validation_message(exc)
        else:
            field, message = "json", str(exc)
        raise InputError(path, message, field=field) from None


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
    wall_s: float | None = 0.0  # seconds before this start (the checkpoint's); None: one that did not count them


def linear(start: float, end: float, frac: float) -> float:
    return start + (end - start) * min(max(frac, 0.0), 1.0)


def role(bundle: Bundle) -> str | None:
    """The city's role given at build time (``--split CITY=ROLE``): train, val, test, or None."""
    return bundle.manifest.config.role


def training_users(bundle: Bundle) -> np.ndarray:
    """The users a run trains on in a city: a ``train`` city's training users, every user of a city without a role."""
    return bundle.user_indices("train") if role(bundle) == "train" else bundle.user_indices()


@dataclass
class Cities:
    """The bundles a run trains on and selects on, and the users of each it plays."""

    train: list[Bundle]
    train_users: list[np.ndarray]
    train_split: str | None
    val: list[Bundle]
    val_users: list[np.ndarray]
    val_split: str | None


def plan_cities(bundles: list[Bundle], val_bundles: list[Bundle], eval_split: str | None) -> Cities:
    """Split the given cities into training and validation ones; refuse a test city.

    A city built as ``val`` goes to validation; one built as ``test`` is refused (never trained or
    selected on). Training users: a ``train`` city's training users, every user of a city without a
    role. Validation: every user of the validation cities, each city once however often it is named
    (``--val-dataset`` and a val city of ``--dataset``); without any, the ``eval_split`` users of
    the training cities (all of them if none has that split).
    """
    for b in [*bundles, *val_bundles]:
        if role(b) == "test":
            raise InputError(
                None, f"{b.city} is a test city (built with --split {b.city}=test): never trained or selected on", field="dataset"
            )
    val = list({b.city: b for b in [*val_bundles, *(b for b in bundles if role(b) == "val")]}.values())
    train = [b for b in bundles if role(b) != "val"]
    if not train:
        raise InputError(None, "no training city: every --dataset given is a validation city", field="dataset")
    if set(b.city for b in train) & set(b.city for b in val):
        raise InputError(None, "a city cannot be both trained and validated on", field="val_dataset")
    train_users = [training_users(b) for b in train]
    train_split = "train" if any(role(b) == "train" for b in train) else None
    if val:
        return Cities(train, train_users, train_split, val, [b.user_indices() for b in val], None)
    has_split = eval_split is not None and any(len(b.user_indices(eval_split)) for b in train)
    split = eval_split if has_split else None
    return Cities(train, train_users, train_split, train, [b.user_indices(split) for b in train], split)


def validation_set(config: DQNConfig, cities: Cities) -> tuple[MapSet, np.ndarray]:
    """The maps and the fixed episodes (``config.eval_episodes``, seeded by ``config.seed``) of a run's periodic
    evaluation, the one that chooses ``best.pt``."""
    maps = MapSet(cities.val, config.env_config(evaluation=True).model_copy(update={"split": cities.val_split}), cities.val_users)
    return maps, maps.sample_episodes(config.eval_episodes, np.random.default_rng([config.seed, 2]))


def play_validation(
    policy: DQNPolicy, maps: MapSet, episodes: np.ndarray, on_step: Callable[[int, int], None] | None = None
) -> dict:
    """``policy`` on the validation episodes: success rate, median steps and mean return (``on_step``: progress)."""
    df = run_episodes(maps, policy, episodes, num_envs=min(256, len(episodes)), on_step=on_step)
    summary = summarise(df)
    return {
        "success": float(summary["success"]),
        "median_steps": float(summary["median_steps"]),
        "mean_return": float(df.return_.mean()),
    }


class Interrupted(Exception):
    """Training stopped by Ctrl-C (SIGINT) at a step boundary, after a checkpoint there."""

    def __init__(self, run_dir: Path, step: int) -> None:
        super().__init__(f"interrupted at step {step:,}; checkpoint saved. Continue with: uavrl train --resume {run_dir}")
        self.run_dir, self.step = run_dir, step


@contextlib.contextmanager
def _interrupts() -> Iterator[Callable[[], bool]]:
    """While the block runs, Ctrl-C (SIGINT) only sets a flag the training loop reads between steps, so that it can
    checkpoint a consistent state; a second Ctrl-C interrupts at once. Outside the main thread nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    pressed = []

    def handler(signum: int, frame: object) -> None:
        if pressed:
            raise KeyboardInterrupt
        pressed.append(signum)

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: bool(pressed)
    finally:
        signal.signal(signal.SIGINT, previous)


def read_state(path: Path, max_step: int) -> CheckpointState:
    """``checkpoint.json``, checked: its schema (``CheckpointState``) and a step within the run's schedule."""
    try:
        state = CheckpointState.model_validate_json(path.read_text(encoding="utf-8"))
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise InputError(path, message, field=field) from None
    if state.step > max_step:
        raise InputError(path, f"step {state.step:,} is beyond the run's {max_step:,} steps", field="step")
    return state


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
        self.setup_task(cities)
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

    # -- the task: placement here, tracking in TrackingTrainer ----------------------------------------
    def setup_task(self, cities: Cities) -> None:
        """The training env (``env``, compact observations) and what the periodic evaluation plays, from ``cities``."""
        config = self.config
        unmatched = [n for n in config.env.city_weights if not any(in_corpus(b.city, n) for b in cities.train)]
        if unmatched:
            raise InputError(
                None,
                f"{', '.join(unmatched)}: no training city or corpus of that name (training cities: "
                f"{', '.join(b.city for b in cities.train)})",
                field="env.city_weights",
            )
        self.maps = MapSet(cities.train, config.env_config().model_copy(update={"split": cities.train_split}), cities.train_users)
        self.eval_maps, self.eval_episodes = validation_set(config, cities)
        self.env = BatchedEnv(self.maps, config.num_envs, compact=True)
        self.train_bundles, self.val_bundles = self.maps.bundles, self.eval_maps.bundles

    @property
    def t_max(self) -> int:
        """The training episodes' step budget."""
        return self.config.env.t_max

    def validate(self, policy: DQNPolicy) -> tuple[dict, tuple[float, float]]:
        """``policy`` on the fixed validation episodes: the evaluation row's values, and its score (higher is better:
        ``best.pt`` keeps the best)."""
        row = play_validation(policy, self.eval_maps, self.eval_episodes)
        return row, (row["success"], -row["median_steps"])

    def episode_values(self, info: dict, row: int, terminated: bool) -> dict:
        """A finished training episode's task values for ``metrics.parquet``."""
        return {"success": terminated}

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
        except (
            OSError,
            ValueError,
            KeyError,
            TypeError,
            RuntimeError,
            EOFError,
            NotImplementedError,
            zipfile.BadZipFile,
        ) as exc:  # a damaged or foreign checkpoint (zipfile raises the last three)
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
        with _interrupts() as interrupted:
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


class TrackingTrainer(Trainer):
    """A run of the tracking task (``DQNConfig.task == "tracking"``, ``rl.tasks.tracking``): placement's learner, loop,
    checkpoints and run folder; the env is the tracking env over the training cities' routes (5 actions, stay the
    fifth), and ``best.pt`` is the network that covered the most of the horizon on fixed episodes of the validation
    cities' routes (ties: the one that reached P_T in more of them). A training city's routes are all trained on: a
    tracking run needs validation cities with routes of their own (built with ``--split CITY=val``, or
    ``--val-dataset``)."""

    def setup_task(self, cities: Cities) -> None:
        task, trained = self.config.tracking_config(), {b.city for b in cities.train}
        val = [b for b in cities.val if b.city not in trained]  # without validation cities, plan_cities gives the trained ones
        for b in cities.train + val:
            if b.routes is None:
                raise InputError(
                    None,
                    f"{b.city} has no routes: the tracking task trains and selects on cities simulated with "
                    f"`uavdata simulate --routes N`",
                    field="dataset" if b.city in trained else "val_dataset",
                )
        if not val:
            raise InputError(
                None,
                "the tracking task selects best.pt on validation cities with routes, and none is given: build one "
                "with `uavdata build --split CITY=val` and add it with --dataset or --val-dataset",
                field="val_dataset",
            )
        self.routes, self.eval_routes = RouteSet(cities.train, task, rotate=task.rotate), RouteSet(val, task)
        self.eval_episodes = self.eval_routes.sample_episodes(
            self.config.eval_episodes, np.random.default_rng([self.config.seed, 2])
        )
        self.env = TrackingEnv(self.routes, self.config.num_envs, compact=True)
        self.train_bundles, self.val_bundles = self.routes.bundles, self.eval_routes.bundles

    @property
    def t_max(self) -> int:
        return self.config.tracking_config().horizon

    def validate(self, policy: DQNPolicy) -> tuple[dict, tuple[float, float]]:
        table = run_tracking(self.eval_routes, policy, self.eval_episodes).table
        row = tracking_summary(table)
        return row, (row["covered_share"], row["success"])

    def episode_values(self, info: dict, row: int, terminated: bool) -> dict:
        share = float(info["covered_share"][row])
        return {"success": share > 0, "covered_share": share}


class FleetTrainer(Trainer):
    """A run of the fleet task (``DQNConfig.task == "fleet"``, ``rl.tasks.fleet``): placement's network, learner, loop,
    checkpoints and run folder; the env is ``FleetTrainEnv`` over fleet episodes of the training cities' training
    users (a row per UAV), and ``best.pt`` is the network that, run on every UAV of fixed fleet episodes of the
    validation cities (``FleetPlacement``), served every user in the most of them (ties: the fewer median steps)."""

    def setup_task(self, cities: Cities) -> None:
        task, env = self.config.fleet, self.config.env_config()
        self.maps = FleetMaps.of(cities.train, task, cities.train_users)
        self.eval_maps = FleetMaps.of(cities.val, task, cities.val_users)
        self.eval_episodes = self.eval_maps.episode_list(self.config.eval_episodes, self.config.seed)
        self.env = FleetTrainEnv(self.maps, env, self.config.num_envs)
        self.train_bundles, self.val_bundles = cities.train, cities.val

    @property
    def t_max(self) -> int:
        return self.config.fleet.t_max

    def validate(self, policy: DQNPolicy) -> tuple[dict, tuple[float, float]]:
        fleet = FleetPlacement(policy, self.config.env_config(evaluation=True), prefix="").bind(self.eval_maps)
        table = run_fleet(self.eval_maps, fleet, self.eval_episodes)
        row = {
            "success": float(table["success"].mean()),
            "median_steps": float(np.median(table["steps"])),
            "spl": float(table["spl"].mean()),
        }
        return row, (row["success"], -row["median_steps"])


def start_from(agent: DQN, config: DQNConfig) -> None:
    """Load ``config.init``'s weights (member ``init_member`` of an ensemble) into ``agent``'s networks; ``InputError``
    naming the checkpoint when it holds no such network."""
    path = Path(config.init)
    ckpt = path / "checkpoints" / "best.pt" if path.is_dir() else path
    ck = load_tensors(ckpt)
    require(ck, ckpt, "online")
    state = ck["online"]
    if any(k.startswith("nets.") for k in state):  # an ensemble (MeanQ): its members side by side
        prefix = f"nets.{config.init_member}."
        state = {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}
        if not state:
            raise InputError(ckpt, f"an ensemble without a member {config.init_member}", field="init_member")
    try:
        agent.online.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise InputError(ckpt, f"its weights do not fit this run's network ({str(exc)[:200]})", field="init") from None
    agent.target.load_state_dict(agent.online.state_dict())


def tracking_summary(table: pd.DataFrame) -> dict:
    """An evaluation row of tracking episodes (``run_tracking``'s table): the mean share of the horizon covered, the
    mean coverage after the first reach, the share of episodes that reached P_T (``success``) and the median steps
    to the first reach (``median_steps``; inf when half never did)."""
    return {
        "covered_share": float(table["covered_share"].mean()),
        "coverage": float(table["coverage"].mean()),
        "success": float(np.isfinite(table["first_reach"]).mean()),
        "median_steps": float(np.median(table["first_reach"])),
    }


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
    kind = {"tracking": TrackingTrainer, "fleet": FleetTrainer}.get(config.task, Trainer)
    try:
        trainer = kind(config, list(datasets), root, run_dir, command=command, val_datasets=list(val_datasets))
    except BaseException:
        if claimed and not any(run_dir.iterdir()):
            run_dir.rmdir()  # nothing was written: give the name back
        raise
    if resume and trainer.resumable():
        trainer.load()
    return trainer


def run_finished(run_dir: Path) -> bool:
    """True when the run's evaluations reached its ``total_steps`` (its schedule is done)."""
    path = run_dir / "eval.parquet"
    if not path.is_file() or not (run_dir / RUN_JSON).is_file():
        return False
    evals = pd.read_parquet(path, columns=["step"])
    return bool(len(evals)) and int(evals["step"].max()) >= read_run_json(run_dir).config.total_steps


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
    task = "" if config.task == "placement" else f"-{config.task}"
    return Path(runs) / f"{stamp}-{config.preset}{task}-{config.agent}-s{config.seed}"


def _plain(row: dict) -> dict:
    """A row of numbers as plain Python values (what a weights-only checkpoint may hold)."""
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()}


def policy_from_checkpoint(ck: dict, path: str | Path, epsilon: float = 0.096, seed: int = 0) -> tuple[DQNPolicy, DQNConfig]:
    """The policy a loaded ``best.pt`` (``load_tensors``) holds, with its config; ``InputError`` naming ``path``."""
    net, config = network_from_checkpoint(ck, path)
    return DQNPolicy.from_config(net, config, epsilon, seed), config


def network_from_checkpoint(ck: dict, path: str | Path) -> tuple[nn.Module, DQNConfig]:
    """The network a loaded ``best.pt`` holds, with its config; ``InputError`` naming ``path``."""
    require(ck, path, "online", "config")
    try:
        config = DQNConfig.model_validate(ck["config"])
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise InputError(path, f"checkpoint config: {message}", field=field) from None
    net = make_network(config, *config.observation())
    try:
        net.load_state_dict(ck["online"])
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise InputError(
            path, f"weights do not fit the network its config describes ({str(exc)[:200]})", field="online"
        ) from None
    return net, config


def load_policy(path: str | Path, epsilon: float = 0.096, seed: int = 0) -> tuple[DQNPolicy, DQNConfig]:
    """A ``best.pt`` as a ``Policy``, with the config it was trained with; ``InputError`` for anything but weights."""
    return policy_from_checkpoint(load_tensors(path), path, epsilon, seed)

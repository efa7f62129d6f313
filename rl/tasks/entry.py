"""What a task is to the rest of the package: its entry (``Task``, declared once in its folder's ``__init__``), the
settings a run's task carries (``RunTask``, the base of each task's), and what its learner hook gives the trainer
(``Learning``).

A task's entry names three things as ``module:attribute`` entry points, imported when first asked for: the model of
a run's task settings (a ``RunTask``), its learner hook (``learning(run, cities) -> Learning``: the training
environment and the validation that selects ``best.pt``; ``rl.agent.train.Trainer`` calls it and knows no task), and
its report (an ``eval.reports.base.TaskReport``; only a string here, so ``rl/`` imports nothing of ``eval/``); and its
Gymnasium environments. ``rl.tasks.registry`` lists the entries."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

from uavplace.schemas.base import Contract

if TYPE_CHECKING:
    from uavplace.dataset.bundle import Bundle
    from uavplace.rl.world.cities import Cities
    from uavplace.rl.world.settings import CanvasSettings, ObservationSettings


def load_entry(entry: str) -> Any:
    """The attribute an entry point ``module:attribute`` names (its module imported)."""
    module, _, name = entry.partition(":")
    if not module or not name:
        raise ValueError(f"{entry!r} is no entry point (module:attribute)")
    return getattr(importlib.import_module(module), name)


class RunSettings(Protocol):
    """What a task's model and learner hook read of a run's settings (``rl.agent.config.DQNConfig`` is one)."""

    agent: str
    seed: int
    num_envs: int
    eval_episodes: int
    task: RunTask

    def env_config(self, *, evaluation: bool = False) -> CanvasSettings:
        """Placement's environment settings (``EnvConfig``), for training or (``evaluation``) the test protocol."""


class RunTask(Contract):
    """A run's task and its settings (``DQNConfig.task``), told apart by ``kind``; each task's model extends it with
    its ``kind`` and settings, and says here how the learner and the reports treat it."""

    #: The network's outputs: the 4 moves, and stay where the task has it.
    actions: ClassVar[int] = 4
    #: The prefix of its settings in ``uavrl train --set PREFIX.FIELD=VALUE`` (None: it has none beyond ``env.``).
    prefix: ClassVar[str | None] = None
    #: How the run's folder, its name in tables and its report's folder under reports/ say the task ("": nothing).
    tag: ClassVar[str] = ""
    #: Whether the env's belief and context channels may be on (a fleet UAV's users change as they are dealt).
    channels: ClassVar[bool] = True
    #: Whether placement's revisit penalties may be on (a moving user brings the UAV back to cells it stood in).
    revisits: ClassVar[bool] = True
    #: Whether the agent reaches the P_T of its ``env`` (a report at another P_T plays it out of its training).
    env_p_t: ClassVar[bool] = True
    #: Whether its runs make an ensemble (``uavrl ensemble`` validates one as a placement agent).
    ensembles: ClassVar[bool] = True

    def playing(self, run: RunSettings) -> ObservationSettings:
        """The settings of the observation the run's network reads in this task (its channels and window)."""
        return run.env_config()


@dataclass(frozen=True)
class Task:
    """One task as the learner, the run folders and the reports see it: its name and three entry points."""

    #: Its name: ``DQNConfig.task.kind``, ``uavrl train --task`` and ``uavrl report --task``.
    name: str
    #: The model of a run's task settings (a ``RunTask`` whose ``kind`` is ``name``).
    model: str
    #: The learner hook: ``learning(run, cities) -> Learning``.
    learning: str
    #: The report that plays its agents (``eval.reports.base.TaskReport``).
    report: str
    #: Its Gymnasium environments, registered when ``uavplace.rl`` is imported: ``(id, module:Class, kwargs)`` each.
    gym: tuple[tuple[str, str, dict], ...] = ()

    @cached_property
    def settings(self) -> type[RunTask]:
        """The model of a run's task settings, imported."""
        return load_entry(self.model)

    def learn(self, run: RunSettings, cities: Cities) -> Learning:
        """The training environment and validation of a run of this task on ``cities``."""
        return load_entry(self.learning)(run, cities)

    @property
    def played_by(self) -> str:
        """The command that plays its agents, for messages."""
        return f"`uavrl report --task {self.name}`"


def terminated_is_success(info: dict, row: int, terminated: bool) -> dict:
    """A finished episode's values for ``metrics.parquet`` where ending early means reaching P_T (placement's)."""
    return {"success": terminated}


def reached_in_share(row: dict) -> str:
    """An evaluation row's words where it is success and median steps (placement's)."""
    return f"{100 * row['success']:.1f} % success, median {row['median_steps']:g} steps"


@dataclass
class Learning:
    """What a task's learner hook gives the trainer: the batched training env (``rl.world.rows.EpisodeRows``'s
    interface, checkpoints included), the training episodes' step budget, the cities trained and selected on (for
    ``run.json``), the validation and the values of a finished training episode."""

    env: Any
    t_max: int
    train_bundles: list[Bundle]
    val_bundles: list[Bundle]
    #: A policy on the fixed validation episodes: the evaluation row's values, and its score (higher is better:
    #: ``best.pt`` keeps the best).
    validate: Callable[[Any], tuple[dict, tuple[float, float]]]
    #: A finished training episode's task values (``info``, its row, whether it ended early).
    episode_values: Callable[[dict, int, bool], dict] = terminated_is_success
    #: An evaluation row (``validate``'s) in words, for the command's last line.
    describe: Callable[[dict], str] = reached_in_share

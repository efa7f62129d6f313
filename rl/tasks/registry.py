"""The three tasks, declared once: what the learner, the run folders and the reports need to know of each (``TASKS``).

Code that depends on the task looks its ``Task`` up here instead of comparing the task's name: a fourth task is one
entry (and its folder under ``rl/tasks/``), not a branch in every module.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Annotated, Literal

from pydantic import BaseModel, Field

from uavplace.rl.tasks.fleet.config import FleetConfig
from uavplace.rl.tasks.tracking.config import TRACK_MOVES, TrackingConfig
from uavplace.schemas.base import Contract


class PlacementTask(Contract):
    """A run's task when it is placement: no settings beyond the run's environment (``DQNConfig.env``)."""

    kind: Literal["placement"] = "placement"


class TrackingTask(TrackingConfig):
    """A run's task when it is tracking: the tracking task's settings (``TrackingConfig``)."""

    kind: Literal["tracking"] = "tracking"


class FleetTask(FleetConfig):
    """A run's task when it is the fleet's: the fleet task's settings (``FleetConfig``)."""

    kind: Literal["fleet"] = "fleet"


#: A learner's task and its settings, told apart by ``kind`` (``DQNConfig.task``).
LearnerTask = Annotated[PlacementTask | TrackingTask | FleetTask, Field(discriminator="kind")]


@dataclass(frozen=True)
class Task:
    """One task as a run (``DQNConfig.task``) and a report see it."""

    #: Its name: ``DQNConfig.task.kind``, ``uavrl train --task`` and ``uavrl report --task``.
    name: str
    #: The network's outputs: the 4 moves, and stay where the task has it.
    actions: int
    #: The prefix of its settings in ``uavrl train --set PREFIX.FIELD=VALUE`` (None: placement's are ``env.``), and
    #: the model of a run's task (``DQNConfig.task``, one of ``LearnerTask``).
    settings: str | None
    model: type[BaseModel]
    #: The ``DQNConfig`` method that gives the settings of the observation the network reads.
    observation: str
    #: Whether the env's belief and context channels may be on (a fleet UAV's users change as they are dealt).
    channels: bool
    #: Whether placement's revisit penalties may be on (a moving user brings the UAV back to cells it stood in).
    revisits: bool
    #: Whether the agent reaches the P_T of its ``env`` (a report at another P_T plays it out of its training).
    env_p_t: bool
    #: Whether its runs make an ensemble (``uavrl ensemble`` validates one as a placement agent).
    ensembles: bool
    #: How the run's folder, its name in tables and the report's folder under reports/ say the task (placement says
    #: nothing).
    tag: str
    #: The report that plays an agent of this task.
    report: str


#: Placement: the paper's task, the one the env, the presets and the reports start from.
PLACEMENT = Task(
    name="placement",
    actions=4,
    settings=None,
    model=PlacementTask,
    observation="env_config",
    channels=True,
    revisits=True,
    env_p_t=True,
    ensembles=True,
    tag="",
    report="a placement report",
)
#: The tasks, each by what it changes of placement.
TASKS: dict[str, Task] = {
    "placement": PLACEMENT,
    "tracking": replace(
        PLACEMENT,
        name="tracking",
        actions=len(TRACK_MOVES),
        settings="tracking",
        model=TrackingTask,
        observation="tracking_config",
        revisits=False,
        env_p_t=False,
        ensembles=False,
        tag="tracking",
        report="`uavrl report --task tracking`",
    ),
    "fleet": replace(
        PLACEMENT,
        name="fleet",
        settings="fleet",
        model=FleetTask,
        channels=False,
        env_p_t=False,
        ensembles=False,
        tag="fleet",
        report="`uavrl report --task fleet`",
    ),
}

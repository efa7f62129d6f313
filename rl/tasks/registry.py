"""The tasks: a folder each under ``rl/tasks/``, listed here once (``FOLDERS``), each declaring its entry in its
``__init__`` (``TASK``, an ``rl.tasks.entry.Task``); ``TASKS`` holds them by name.

Code that depends on the task looks its ``Task`` up here (and its run settings' model, ``Task.settings``) instead of
comparing the task's name. A new task is a folder with its entry and one line below; a task from another package
registers the same entry under the ``uavplace.tasks`` entry-point group of its distribution (``module:TASK``)."""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Annotated, Union

from pydantic import Field

from uavplace.rl.tasks.entry import RunTask, Task, load_entry

#: The task folders of this package, placement first (the task a run, a preset and a report start from).
FOLDERS = (
    "placement",
    "tracking",
    "fleet",
)


def _entries() -> list[Task]:
    own = [importlib.import_module(f"uavplace.rl.tasks.{folder}").TASK for folder in FOLDERS]
    added = [load_entry(e.value) for e in entry_points(group="uavplace.tasks")]
    tasks = own + added
    for task in tasks:
        if not isinstance(task, Task):
            raise TypeError(f"{task!r}: a task's entry is an rl.tasks.entry.Task")
    return tasks


#: The tasks by name.
TASKS: dict[str, Task] = {task.name: task for task in _entries()}
#: A learner's task and its settings, told apart by ``kind`` (``DQNConfig.task``).
LearnerTask = Annotated[Union[tuple(task.settings for task in TASKS.values())], Field(discriminator="kind")]  # noqa: UP007


def task_of(settings: RunTask) -> Task:
    """The entry of a run's task (``DQNConfig.task``)."""
    return TASKS[settings.kind]

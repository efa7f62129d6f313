"""The reports of ``uavrl report``, one module or folder a task (``placement.py``, ``tracking/``, ``fleet/``), each
declaring its ``REPORT`` (``base.TaskReport``) on the shared base (``base.py``: the request read once from the
command line, the checks and console lines every report makes). Each task's entry (``rl.tasks.registry.TASKS``)
names its report as a ``module:attribute`` entry point, imported when the task is asked for: a new task's report is a
module (here, or in the package that adds the task) named by its entry."""

from __future__ import annotations

from uavplace.eval.reports.base import TaskReport
from uavplace.rl.tasks.entry import load_entry
from uavplace.rl.tasks.registry import TASKS


def task_report(task: str) -> TaskReport:
    """The ``TaskReport`` of ``task`` (a name of ``TASKS``)."""
    return load_entry(TASKS[task].report)


__all__ = ["TaskReport", "task_report"]

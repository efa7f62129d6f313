"""The reports of ``uavrl report``, one module a task (``placement.py``, ``tracking.py``, ``fleet.py``), each
declaring its ``REPORT`` (``base.TaskReport``) on the shared base (``base.py``: the request read once from the
command line, the checks and console lines every report makes). ``REPORTS`` lists them by the task's name (the names
of ``rl.tasks.registry.TASKS``) as ``module:attribute`` entry points, imported when the task is asked for: a new
task's report is a module here and one line below."""

from __future__ import annotations

import importlib

from uavplace.eval.reports.base import TaskReport

#: Each task's report, by the task's name.
REPORTS = {
    "placement": "uavplace.eval.reports.placement:REPORT",
    "tracking": "uavplace.eval.reports.tracking:REPORT",
    "fleet": "uavplace.eval.reports.fleet:REPORT",
}


def task_report(task: str) -> TaskReport:
    """The ``TaskReport`` of ``task`` (a name of ``REPORTS``)."""
    module, _, name = REPORTS[task].partition(":")
    return getattr(importlib.import_module(module), name)


__all__ = ["REPORTS", "TaskReport", "task_report"]

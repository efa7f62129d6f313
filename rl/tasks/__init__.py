"""The tasks, one folder each with the same files: ``config`` (the task's settings and its run settings' model),
``maps`` (its cities, episodes and oracle, where not the world's), ``env`` (the task stepped in numpy), ``policies``,
``searcher`` (the map searcher run for it), ``rollout`` (playing a list of episodes with a policy), ``learner`` (its
learner hook), ``gym`` (its Gymnasium face) and where the task has it ``zoo`` (PettingZoo); each folder's ``__init__``
declares the task's entry (``entry.Task``), and ``registry`` lists the folders."""

from __future__ import annotations

from uavplace.rl.world import exported

__all__ = ["exported"]

"""The tasks beyond placement, one folder each with the same files: ``config`` (the task's settings), ``maps`` (its
cities, episodes and oracle), ``env`` (the task stepped in numpy and what a policy may read of it), ``policies``,
``searcher`` (the map searcher run for it), ``rollout`` (playing a list of episodes with a policy), and where the task
has them ``learner`` (the task as the learner's environment, when its env is not one) and ``zoo`` (PettingZoo)."""

from __future__ import annotations

from uavplace.rl.world import exported

__all__ = ["exported"]

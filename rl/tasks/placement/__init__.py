"""The placement task, the paper's: a UAV finds a cell where the SINR of a user who stands still, at a position
nobody knows, reaches P_T (docs/method.md). The tracking and fleet tasks build on it.

``config`` (``EnvConfig``: the environment's settings, on ``rl.world.settings.CanvasSettings``), ``env``
(``BatchedEnv``: the task stepped in numpy for every row of a batch, over ``rl.world``'s ``MapSet``; what a policy
may read of it is ``rl.world.view``'s ``AgentView``), ``policies`` (the genie, the steered random walk, greedy
hill-climbing), ``searcher`` (the map searcher, ``MapSearchPolicy``, on ``rl.belief``) and ``rollout``
(``run_episodes``: a list of episodes played by a policy; their statistics are ``rl.world.stats``). The Gymnasium environments of every
task are each task's ``gym.py``; the learner is ``rl.agent``.
"""

from __future__ import annotations

from uavplace.rl.tasks import exported
from uavplace.rl.tasks.entry import Task

#: The task's entry (``rl.tasks.registry``): its run settings, its learner hook and its report.
TASK = Task(
    name="placement",
    model="uavplace.rl.tasks.placement.config:PlacementTask",
    learning="uavplace.rl.tasks.placement.learner:learning",
    report="uavplace.eval.reports.placement:REPORT",
    gym=(
        ("uavplace/UavPlacement-v0", "uavplace.rl.tasks.placement.gym:UavPlacementEnv", {}),
        ("uavplace/BlindUavPlacement-v0", "uavplace.rl.tasks.placement.gym:UavPlacementEnv", {"blind": True}),
    ),
)

#: What the package offers, by the file that holds it, imported on first use (``rl.tasks.exported``).
FILES = {
    "config": ("EnvConfig",),
    "env": ("BatchedEnv",),
    "policies": ("GeniePolicy", "GreedyPolicy", "Policy", "RandomWalkPolicy", "episode_draws", "pick_legal", "random_legal"),
    "searcher": ("MapSearchPolicy", "SEARCHER"),
    "learner": ("learning", "play_validation", "validation_set"),
    "rollout": ("run_episodes",),
    "gym": ("UavPlacementEnv",),
}
EXPORTS = {name: file for file, names in FILES.items() for name in names}

__all__ = sorted(EXPORTS)


__getattr__ = exported(__name__, EXPORTS)

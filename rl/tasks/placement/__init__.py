"""The placement task, the paper's: a UAV finds a cell where the SINR of a user who stands still, at a position
nobody knows, reaches P_T (docs/method.md). The tracking and fleet tasks build on it.

``config`` (``EnvConfig``: the environment's settings), ``maps`` (``MapSet``: the bundles' maps on square canvases
under the map symmetries, the moves), ``env`` (``BatchedEnv``: the task stepped in numpy for every row of a batch;
what a policy may read of it is ``rl.view``'s ``AgentView``), ``policies`` (the genie, the steered random walk,
greedy hill-climbing), ``searcher`` (the map searcher, ``MapSearchPolicy``, on ``rl.belief``) and ``rollout``
(``run_episodes``: a list of episodes played by a policy, and their statistics). The Gymnasium environments of every
task are ``rl.env``'s; the learner is ``rl.agent``.
"""

from __future__ import annotations

from uavplace.rl.tasks import exported

#: What the package offers, by the file that holds it, imported on first use (``rl.tasks.exported``).
FILES = {
    "config": ("EnvConfig",),
    "maps": ("MOVES", "MapSet", "transform"),
    "env": ("BatchedEnv", "EpisodeRows", "OBS_OFFSET", "decode_obs", "encode_obs", "refuse_bad_rows"),
    "policies": ("GeniePolicy", "GreedyPolicy", "Policy", "RandomWalkPolicy", "episode_draws", "pick_legal", "random_legal"),
    "searcher": ("MapSearchPolicy", "SEARCHER"),
    "rollout": ("STATS", "WITHIN", "episode_stats", "format_stat", "interquartile_mean", "run_episodes", "summarise"),
}
EXPORTS = {name: file for file, names in FILES.items() for name in names}

__all__ = sorted(EXPORTS)


__getattr__ = exported(__name__, EXPORTS)

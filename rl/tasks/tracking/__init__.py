"""The tracking task: a UAV keeps a usable link to a user who moves along a ray-traced route.

The second task beside placement (placement is unchanged). A bundle with routes (``uavdata simulate
--routes``, then ingest and build) holds a radio map per route point. An episode picks a route, a start
time on it and a start cell (legal, live, below P_T, a target reachable at the start time), and lasts a
fixed ``horizon`` of steps. Each step takes ``step_s`` = cell side / ``uav_speed_mps`` seconds (4 m at
10 m/s: 0.4 s): the UAV moves one cell (actions 0-3, the placement moves) or stays (action 4); the user
walks on by speed x time, to the route's end and back (``user_point``). The UAV measures the SINR of its
cell to the user's current position, the route point nearest in time, and nothing else of the user.

Observation ``[C, window, window]`` around the UAV: the height channel (not blind), the age of each
measurement (seconds since the cell was last measured, clipped at ``age_clip_s``; unvisited cells and
blocked ones show the clip), and the SINR memory (the last SINR measured at each cell; P_H unvisited, P_L
blocked or beyond the edge), which stays last as in placement. Reward: ``cover_reward`` for each step at
or above P_T plus ``gain_weight`` times the SINR change.

Per-episode metrics (``episode_metrics``): steps to first reach P_T, the share of the steps after that at
or above P_T (coverage), the longest outage after it, and the share of the whole horizon covered.
Baselines: the ``oracle`` (dynamic programming over (time, cell) on the whole route and every map: the
most covered steps possible, the upper bound), the placement genie re-planned every step toward the
current P_T region (``ReplanningGenie``), and the placement baselines, which act through the same
interface (``rl.tasks.placement.policies``), as they are or holding the cell while it covers the user (``Holding``). Agents:
a placement agent run unchanged (``PlacementInTracking``; also with ``Holding``), or one trained on this task
(``uavrl train --task tracking``, its learner hook, ``learner.py``) on its own observation (``TrackingAgent``).
"""

from __future__ import annotations

from uavplace.rl.tasks import exported
from uavplace.rl.tasks.entry import Task

#: The task's entry (``rl.tasks.registry``): its run settings, its learner hook and its report.
TASK = Task(
    name="tracking",
    model="uavplace.rl.tasks.tracking.config:TrackingTask",
    learning="uavplace.rl.tasks.tracking.learner:learning",
    report="uavplace.eval.reports.tracking:REPORT",
    gym=(("uavplace/UavTracking-v0", "uavplace.rl.tasks.tracking.gym:UavTrackingEnv", {}),),
)

#: What the package offers, by the file that holds it, imported on first use (``rl.tasks.exported``).
FILES = {
    "config": ("ACTION_OF", "MotionModel", "OBSERVATION_FIELDS", "STAY", "TRACK_MOVES", "TrackingConfig", "tracking_search"),
    "maps": ("RouteSet", "episode_metrics", "oracle_path", "user_point"),
    "env": ("TrackingEnv",),
    "policies": ("Holding", "MovesOnly", "OraclePolicy", "PlacementInTracking", "ReplanningGenie", "TrackingAgent"),
    "searcher": ("TRACKING_SEARCHER", "TrackingSearchPolicy", "fit_motion", "transition"),
    "learner": ("learning", "tracking_summary"),
    "rollout": ("TrackingEpisodes", "run_tracking"),
    "gym": ("UavTrackingEnv",),
}
EXPORTS = {name: file for file, names in FILES.items() for name in names}

__all__ = sorted(EXPORTS)


__getattr__ = exported(__name__, EXPORTS)

"""The fleet task: several UAVs serve several users of unknown position at once (the paper's second future work).

K UAVs (``FleetConfig.uavs``, 1-4) start on distinct legal cells of one city and move together, each one cell a
step or staying (actions 0-3 the placement moves, 4 stay). A UAV never enters a cell another UAV holds at the
start of the step, and of two UAVs that move into one free cell the first in order enters while the other stays:
no two ever share a cell, and none pass through each other. N users (``users``, 1-6) are drawn from the city's
traced users; nobody knows where they are. Every UAV measures every user's SINR at its cell at every step (the
users are told apart by their pilots) and the fleet shares what it measures. The episode succeeds when, at one
step, every user has a UAV at SINR >= P_T; it is truncated after ``t_max`` steps.

Episodes (``FleetMaps.episode_list``): episode ``i`` of a list is drawn from its own generator (the list's seed
and ``i`` hashed, ``rl.randomness``), so any prefix of a list is the shorter list: a city, N distinct users, K
distinct legal starts from which every user's target cells (SINR >= P_T) are reachable, not every user served at
the start. ``episode_keys`` names an episode by what the fleet knows of it (its city's public map and its UAVs'
starts, never its users) for the policies' random draws.

Observation ``[K, 2 + N, window, window]``, one window per UAV centred on it: the building height minus the
altitude [m] (clipped; ``edge_height_m`` beyond the edge), the fleet channel (P_H where another UAV stands, 0
elsewhere) and each user's shared SINR memory [dB] (the SINR measured at each visited cell, P_H unvisited, P_L
blocked or beyond the edge). Reward (for learners): the gain, summed over the users, of the best SINR any UAV
measures of each user, counted up to P_T, plus ``c_e`` per UAV that enters a cell the fleet never visited, plus
``success_bonus`` when every user is served.

The oracle (``oracle_steps``) knows every user's map: the fewest steps until every user is served is, over the
assignments of users to UAVs, the largest of each UAV's fewest moves to a cell that serves all of its users (the
intersection of their target cells), minimised. It never counts two UAVs that must pass each other in a corridor
one cell wide (a lower bound there; exact elsewhere: ``tests/test_fleet.py`` checks it against a search over the
fleet's joint positions).
"""

from __future__ import annotations

from uavplace.rl.tasks import exported
from uavplace.rl.tasks.entry import Task

#: The task's entry (``rl.tasks.registry``): its run settings, its learner hook and its report.
TASK = Task(
    name="fleet",
    model="uavplace.rl.tasks.fleet.config:FleetTask",
    learning="uavplace.rl.tasks.fleet.learner:learning",
    report="uavplace.eval.reports.fleet:REPORT",
    gym=(("uavplace/UavFleet-v0", "uavplace.rl.tasks.fleet.gym:UavFleetEnv", {}),),
)

#: What the package offers, by the file that holds it, imported on first use (``rl.tasks.exported``).
FILES = {
    "config": ("FLEET_MOVES", "FleetConfig", "STAY"),
    "maps": ("FleetCity", "FleetMaps", "assignments", "fleet_oracle", "oracle_steps", "user_subsets"),
    "env": ("BatchedFleet", "FleetView"),
    "policies": ("FleetGreedy", "FleetPlacement", "FleetRandomWalk"),
    "searcher": ("FleetSearcher",),
    "learner": ("FleetTrainEnv", "learning"),
    "rollout": ("run_fleet",),
    "gym": ("UavFleetEnv",),
}
EXPORTS = {name: file for file, names in FILES.items() for name in names}

__all__ = sorted(EXPORTS)


__getattr__ = exported(__name__, EXPORTS)

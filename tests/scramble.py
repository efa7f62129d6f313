"""The scramble tests' worlds: a task's world changed everywhere a policy could not have measured.

A policy that reads only what its UAV measured moves the same in the scrambled world as in the real one; a policy
that reads a user's map, where the user is or where the user's route goes moves otherwise somewhere. Each function
returns a copy (the originals are left alone) in which:

- every user's map (SINR, dead cells, the genie's distances or targets) is random on the cells outside ``keep``
  (the cells the UAV visited), at every point of a route;
- the user is somewhere else: the users table (placement, fleet) or the route table (tracking) of the bundles the
  world holds names other cells, so a policy that steers by the user's position or route moves otherwise;
- a tracking route is another: its route numbers are shifted (``routes.names``), and its points' positions are moved.

Used by tests/test_information.py, tests/test_tracking.py, tests/test_fleet.py and tests/test_cheaters.py.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pandas as pd

from uavplace.dataset.bundle import Bundle
from uavplace.rl.tasks.fleet.env import BatchedFleet, FleetView
from uavplace.rl.tasks.fleet.maps import FleetMaps
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.tasks.tracking.maps import RouteSet
from uavplace.rl.tasks.tracking.rollout import run_tracking
from uavplace.rl.world.maps import MapSet


def moved(bundle: Bundle, table: str, rows: np.ndarray | None, rng: np.random.Generator) -> Bundle:
    """A copy of ``bundle`` whose ``table`` (``users`` or ``routes``) puts ``rows`` (default: all) at random open
    cells (``ix``, ``iy`` and the metres ``x_m``, ``y_m``); route numbers are shifted by 1000."""
    frame: pd.DataFrame = getattr(bundle, table).copy()
    rows = np.arange(len(frame)) if rows is None else np.asarray(rows, np.int64)
    open_y, open_x = np.nonzero(~bundle.blocked)
    pick = rng.integers(len(open_y), size=len(rows))
    cells = {"iy": open_y[pick], "ix": open_x[pick], "y_m": bundle.y_m[open_y[pick]], "x_m": bundle.x_m[open_x[pick]]}
    for col, values in cells.items():
        frame.loc[frame.index[rows], col] = values.astype(frame[col].dtype)
    if table == "routes":
        frame["route"] = frame["route"] + 1000
    return dataclasses.replace(bundle, **{table: frame})


def placement(maps: MapSet, view: int, keep: np.ndarray, rng: np.random.Generator) -> MapSet:
    """A copy of ``maps`` whose ``view`` holds random SINR, dead cells and genie distances outside ``keep`` [L, L],
    and whose user of that view stands elsewhere in its bundle's users table."""
    out = copy.copy(maps)
    out.sinr, out.dead, out.steps = maps.sinr.copy(), maps.dead.copy(), maps.steps.copy()
    hidden = ~keep
    out.sinr[view][hidden] = rng.uniform(-40, 40, hidden.sum()).astype(out.sinr.dtype)
    out.dead[view][hidden] = rng.random(hidden.sum()) < 0.3
    out.steps[view][hidden] = rng.integers(0, 50, hidden.sum())
    scenario = maps.scenarios[int(maps.scenario_of(np.array([view]))[0])]
    out.bundles = list(maps.bundles)
    out.bundles[scenario.bundle] = moved(maps.bundles[scenario.bundle], "users", np.array([scenario.user]), rng)
    return out


def tracking(routes: RouteSet, keep: np.ndarray, rng: np.random.Generator) -> RouteSet:
    """A copy of ``routes`` whose every route point's map is random outside ``keep`` [L, L] (the canvas cells the UAV
    visited), whose route tables put every point elsewhere, and whose routes are numbered otherwise."""
    out = copy.copy(routes)
    out.sinr, out.dead, out.steps = routes.sinr.copy(), routes.dead.copy(), routes.steps.copy()
    hidden = ~keep
    out.sinr[:, hidden] = rng.uniform(-150, 50, (len(routes.sinr), hidden.sum()))  # the memory's range
    out.dead[:, hidden] = rng.random((len(routes.sinr), hidden.sum())) < 0.3
    out.steps[:, hidden] = rng.integers(0, 2, (len(routes.sinr), hidden.sum()))  # 0: a target next door
    out.bundles = [moved(b, "routes", None, rng) for b in routes.bundles]
    out.names = [(city, route + 1000, kind) for city, route, kind in routes.names]
    return out


def fleet(maps: FleetMaps, city: int, users: np.ndarray, keep: np.ndarray, rng: np.random.Generator) -> FleetMaps:
    """A copy of ``maps`` whose ``users`` of ``city`` hold random SINR and targets outside ``keep`` [L, L], and whose
    city's users all stand elsewhere in its users table (where the maps carry their bundles)."""
    out = copy.copy(maps)
    out.sinr, out.target = maps.sinr.copy(), maps.target.copy()
    for u in users:
        out.sinr[city, u][~keep] = rng.uniform(-40, 40, (~keep).sum()).astype(np.float32)
        out.target[city, u][~keep] = rng.random((~keep).sum()) < 0.3
    if maps.bundles is not None:  # every user of the city elsewhere: a policy may read any of them
        out.bundles = list(maps.bundles)
        out.bundles[city] = moved(maps.bundles[city], "users", None, rng)
    return out


def replay_placement(maps: MapSet, policy, episodes: np.ndarray, rng: np.random.Generator):  # noqa: ANN001, ANN202
    """Per episode of ``episodes`` played by ``policy``: (the same moves, the moves or the steps changed) when it is
    played again, as number k of the same list (same draws), in the world ``placement`` scrambles off its path."""
    first = run_episodes(maps, policy, episodes, num_envs=4, record=np.arange(len(episodes)))
    same, changed = [], []
    for k in range(len(episodes)):
        path = first.attrs["paths"][k]
        view = int(episodes[k, 0])
        keep = visited(maps.sinr.shape[1:], np.stack(to_canvas(maps, view, path), axis=1))
        other = placement(maps, view, keep, rng)
        # Episode k again, as number k of the same list (the draws are keyed by the episode's number).
        again = run_episodes(other, policy, episodes, num_envs=4, record=np.array([k]))
        same.append(np.array_equal(again.attrs["paths"][k], path))
        changed.append(int(again.steps[k]) != int(first.steps[k]) or not same[-1])
    return same, changed


def to_canvas(maps: MapSet, view: int, path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bundle cells ``path`` [T, 2] as cells of the view's padded canvas (the inverse of ``MapSet.unrotate``)."""
    views = np.full(maps.sinr.shape[1] * maps.sinr.shape[2], view)
    yy, xx = np.mgrid[: maps.sinr.shape[1], : maps.sinr.shape[2]]
    by, bx = maps.unrotate(views, yy.ravel(), xx.ravel())
    lookup = {(int(a), int(b)): (int(y), int(x)) for a, b, y, x in zip(by, bx, yy.ravel(), xx.ravel(), strict=True)}
    cells = np.array([lookup[(int(a), int(b))] for a, b in path])
    return cells[:, 0], cells[:, 1]


def visited(shape: tuple[int, ...], path: np.ndarray) -> np.ndarray:
    """``shape`` bool: True at the cells of ``path`` [..., 2] (canvas cells ``(y, x)``)."""
    keep = np.zeros(shape, bool)
    keep[path[..., 0].ravel(), path[..., 1].ravel()] = True
    return keep


def replay_tracking(routes: RouteSet, policy, episodes: np.ndarray, rng: np.random.Generator):  # noqa: ANN001, ANN202
    """Per episode of ``episodes`` played by ``policy``: (the same moves, the moves or the covered steps changed) when
    the same list is played again in the world ``tracking`` scrambles off that episode's path."""
    first = run_tracking(routes, policy, episodes, num_envs=5, record=True)
    same, changed = [], []
    for k in range(len(episodes)):
        again = run_tracking(tracking(routes, visited(routes.sinr.shape[1:], first.path[k]), rng), policy, episodes,
                             num_envs=5, record=True)  # fmt: skip
        same.append(np.array_equal(again.path[k], first.path[k]))
        changed.append(not same[-1] or not np.array_equal(again.covered[k], first.covered[k]))
    return same, changed


def fleet_paths(maps: FleetMaps, policy, episodes: np.ndarray) -> list[np.ndarray]:  # noqa: ANN001
    """Each episode played alone on ``maps`` (a policy with ``bind`` bound to them first): the fleet's canvas cells
    ``[T + 1, K, 2]`` after every step."""
    if hasattr(policy, "bind"):
        policy.bind(maps)
    out = []
    for e in range(len(episodes)):
        env = BatchedFleet(maps, 1)
        env.begin(np.array([0]), episodes[e : e + 1], np.array([e]))
        policy.reset(np.array([0]), 1, maps.config.uavs)
        path = [env.pos[0].copy()]
        while not env.done[0]:
            env.step(policy.act(env.action_mask(), FleetView.of(env)))
            path.append(env.pos[0].copy())
        out.append(np.array(path))
    return out

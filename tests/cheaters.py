"""Planted cheaters: policies that read what their UAV does not know, so that each task's scramble test can be shown
to catch them (tests/scramble.py changes the world everywhere the UAV did not measure, and moves the user).

Each reads one thing a policy must not: where the user is (the users or route table), where the user's route goes
next, or a user's map beyond the cells the UAV measured. They are marked ``privileged``, as the genie is, to be handed
the env itself: an unprivileged policy receives the task's view, which holds none of these (the same classes with
``privileged = False`` fail on the view's missing attributes). ``PublicWriter`` writes to the public maps of its view.
"""

from __future__ import annotations

import numpy as np

from uavplace.rl.world.maps import MOVES


def toward(pos: np.ndarray, mask: np.ndarray, target: np.ndarray) -> np.ndarray:
    """[N] the legal move (of the 4, ``mask`` [N, >= 4]) that leaves each ``pos`` [N, 2] nearest ``target`` [N, 2]
    (city-block distance; the first on a tie)."""
    after = pos[:, None, :] + MOVES[None, :, :]
    distance = np.abs(after - target[:, None, :]).sum(axis=2).astype(float)
    distance[~mask[:, :4]] = np.inf
    return np.argmin(distance, axis=1)


def _best_neighbour(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """[N] the legal move (of the 4) to the neighbour of highest ``values`` [N, 4]."""
    return np.argmax(np.where(mask[:, :4], values, -np.inf), axis=1)


class _Cheater:
    privileged = True

    def reset(self, rows: np.ndarray, num_envs: int, *uavs: int) -> None:
        pass


class PlacementUserSeeker(_Cheater):
    """Steers to the user's cell, read from the bundle's users table (unrotated maps)."""

    name = "cheater: the user's position"

    def act(self, obs: np.ndarray, mask: np.ndarray, env) -> np.ndarray:  # noqa: ANN001 - a BatchedEnv
        maps = env.maps
        scenarios = [maps.scenarios[int(s)] for s in maps.scenario_of(env.view)]
        users = [maps.bundles[s.bundle].users.iloc[s.user] for s in scenarios]
        target = np.array([[u["iy"], u["ix"]] for u in users], np.int64) + maps.pad
        return toward(env.pos, mask, target)


class PlacementMapPeeker(_Cheater):
    """Moves to the neighbour where the user's map is strongest: a map read where it was not measured."""

    name = "cheater: the user's map"

    def act(self, obs: np.ndarray, mask: np.ndarray, env) -> np.ndarray:  # noqa: ANN001 - a BatchedEnv
        ny, nx = env.neighbours()
        return _best_neighbour(env.maps.sinr[env.view[:, None], ny, nx], mask)


class PublicWriter:
    """Opens every cell of its view's public maps and puts its UAVs in the canvas's corner (a building's cell, beyond
    the edge), each array made writable again, and tries the first move the written map allows: an env that read those
    arrays would let it through a building."""

    name = "cheater: writes the public maps"
    privileged = False

    def reset(self, rows: np.ndarray, num_envs: int, *uavs: int) -> None:
        pass

    def act(self, obs: np.ndarray, mask: np.ndarray, view) -> np.ndarray:  # noqa: ANN001 - an AgentView or TrackingView
        for a in (view.public.blocked, view.public.height, view.pos):
            a.flags.writeable = True  # a read-only copy that owns its memory may be made writable again
        view.public.blocked[...] = False
        view.public.height[...] = -100.0
        view.pos[...] = 0
        return np.zeros(len(mask), np.int64)  # always the first move, open on the written map


def _route_cells(env, ahead: int) -> np.ndarray:  # noqa: ANN001 - a TrackingEnv
    """[N, 2] the canvas cell of each row's user ``ahead`` steps from now, read from its bundle's route table."""
    routes = env.routes
    points = routes.point(env.route, env.start_s, env.t + ahead)
    out = np.zeros((env.num_envs, 2), np.int64)
    for r, (point, route) in enumerate(zip(points, env.route, strict=True)):
        b = int(routes.bundle[route])
        offset = sum(len(routes.bundles[i].routes) for i in range(b))  # rows of earlier bundles
        row = routes.bundles[b].routes.iloc[int(point) - offset]
        out[r] = (int(row["iy"]) + routes.maps.pad, int(row["ix"]) + routes.maps.pad)
    return out


class TrackingRouteReader(_Cheater):
    """Goes where the user's route will be ``ahead`` steps from now; stays once there."""

    name = "cheater: the user's route"
    ahead = 5

    def act(self, obs: np.ndarray, mask: np.ndarray, env) -> np.ndarray:  # noqa: ANN001 - a TrackingEnv
        target = _route_cells(env, self.ahead)
        return np.where((env.pos == target).all(axis=1), 4, toward(env.pos, mask, target))


class TrackingUserSeeker(TrackingRouteReader):
    """Goes where the user is now (the route table at the user's point); stays once there."""

    name = "cheater: the user's position"
    ahead = 0


class TrackingMapPeeker(_Cheater):
    """Moves to the neighbour where the user's map is strongest now; stays where it is covered."""

    name = "cheater: the user's map"

    def act(self, obs: np.ndarray, mask: np.ndarray, env) -> np.ndarray:  # noqa: ANN001 - a TrackingEnv
        ny, nx = env.neighbours()
        move = _best_neighbour(env.routes.sinr[env.point()[:, None], ny, nx], mask)
        return np.where(env.config.reaches(env.sinr_here()), 4, move)


class FleetUserSeeker(_Cheater):
    """Bound to the fleet's maps as the fleet searcher is; UAV k steers to the k-th user of its city's users table."""

    name = "cheater: the users' positions"

    def bind(self, maps):  # noqa: ANN001, ANN201 - FleetMaps
        self.maps = maps
        return self

    def act(self, mask: np.ndarray, view) -> np.ndarray:  # noqa: ANN001 - a FleetView
        e, k = mask.shape[:2]
        out = np.zeros((e, k), np.int64)
        for r in range(e):
            users = self.maps.bundles[int(view.city[r])].users
            target = users[["iy", "ix"]].to_numpy()[np.arange(k) % len(users)] + self.maps.pad
            out[r] = toward(view.pos[r], mask[r], target)
        return out


class FleetMapPeeker(FleetUserSeeker):
    """Bound to the fleet's maps; each UAV moves to the neighbour where any user of its city is strongest."""

    name = "cheater: the users' maps"

    def act(self, mask: np.ndarray, view) -> np.ndarray:  # noqa: ANN001 - a FleetView
        e, k = mask.shape[:2]
        out = np.zeros((e, k), np.int64)
        for r in range(e):
            ny, nx = view.pos[r, :, None, 0] + MOVES[None, :, 0], view.pos[r, :, None, 1] + MOVES[None, :, 1]
            strongest = self.maps.sinr[int(view.city[r])][:, ny, nx].max(axis=0)  # [K, 4]
            out[r] = _best_neighbour(strongest, mask[r])
        return out

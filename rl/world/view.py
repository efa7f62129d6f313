"""What a policy may read: the UAV's own knowledge, apart from the environment that also holds the users' maps.

``BatchedEnv`` holds every user's SINR map, dead cells and the genie's distances. A policy other than the genie
and the oracles receives an ``AgentView`` instead (``view_for``): per row, the UAV's position, the step, its own
measurements (the SINR memory and the visit counts), the key of its episode's random draws, and the ``PublicMaps``
of the canvas it flies over (the buildings, the grid and the bundle's public settings). Nothing in it leads back to
a user's map: the view holds no reference to the env or its ``MapSet``, and which canvas a row flies over
(``canvas``) names a city under a symmetry, not a user.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavplace.dataset.bundle import Bundle, public_settings
from uavplace.rl.config import MapErrorSettings
from uavplace.rl.world.maperror import error_tag
from uavplace.rl.world.maps import MOVES, MapSet, transform
from uavplace.rl.world.settings import CanvasSettings


@dataclass(frozen=True)
class PublicMaps:
    """The canvases of a ``MapSet`` as the UAV knows them: one per bundle and symmetry (``canvas = S * bundle + k``).

    ``height`` [num_canvases, L, L] (building height minus altitude, clipped), ``blocked`` [num_canvases, L, L] (the
    UAV may not enter; beyond the edge too), ``shapes`` [num_canvases, 2] (the transformed map's ``(num_y, num_x)``),
    ``pad`` (the map's offset on the canvas), ``symmetries`` and per bundle its public settings (``bundle_heights``:
    the untransformed heights of the UAV's map, ``MapSet.seen_heights``; ``settings``: grid spacing, altitude, noise,
    floor, transmit power, carrier, version, which names the map's error too)."""

    height: np.ndarray
    blocked: np.ndarray
    shapes: np.ndarray
    pad: int
    symmetries: int
    config: CanvasSettings
    settings: tuple[dict, ...]
    bundle_heights: tuple[np.ndarray, ...]

    @classmethod
    def of(cls, maps: MapSet) -> PublicMaps:
        """The public maps of ``maps``: read-only copies, never the env's own arrays (a policy that writes to them,
        or makes them writable again, changes nothing the env reads: not the legal moves, not the maps)."""
        return cls(
            height=sealed(maps.height),
            blocked=sealed(maps.blocked),
            shapes=sealed(maps.shapes),
            pad=maps.pad,
            symmetries=maps.symmetries,
            config=maps.config,
            settings=tuple(public_settings(b) | _erring(b, maps.config.map_error) for b in maps.bundles),
            bundle_heights=tuple(sealed(h) for h in maps.seen_heights),
        )

    def bundle_of(self, canvas: int) -> int:
        return canvas // self.symmetries

    def symmetry_of(self, canvas: int) -> int:
        return canvas % self.symmetries

    def map_heights(self, canvas: int) -> np.ndarray:
        """``[num_y, num_x]`` the canvas's building heights minus altitude (unclipped), under its symmetry."""
        return transform(self.bundle_heights[self.bundle_of(canvas)], self.symmetry_of(canvas))

    def legal(self, canvas: int) -> np.ndarray:
        """``[num_y, num_x]`` bool: the map cells the UAV may enter, under the canvas's symmetry."""
        ny, nx = self.shapes[canvas]
        p = self.pad
        return ~self.blocked[canvas, p : p + ny, p : p + nx]


class UavView:
    """What every task's view holds of its rows at one step (``AgentView``, ``rl.tasks.tracking.TrackingView``):
    where the UAVs are and when (``pos`` [N, 2] canvas cells, ``t`` [N], ``exhausted`` [N]: copies, so a policy
    that writes them moves no UAV), what they measured (``memory`` [N, L, L]: a read-only view of the env's), the
    canvas each row flies over (``canvas`` [N]: a city under a symmetry, never a user), the keys of their episodes'
    random draws, the task's settings (``config``) and the ``public`` maps. Values only: nothing in it leads back to
    the env (a bound method would, by ``__self__``)."""

    def __init__(
        self,
        public: PublicMaps,
        config: object,
        pos: np.ndarray,
        t: np.ndarray,
        exhausted: np.ndarray,
        memory: np.ndarray,
        canvas: np.ndarray,
        keys: np.ndarray,
    ) -> None:
        self.public, self.config = public, config
        self.pos, self.t, self.exhausted = sealed(pos), sealed(t), sealed(exhausted)
        self.memory = frozen(memory)
        self.canvas = sealed(canvas)
        self._keys = sealed(keys)

    @property
    def num_envs(self) -> int:
        return len(self.pos)

    def measured(self) -> np.ndarray:
        """[N] the SINR each UAV measured where it stands [dB]."""
        return self.memory[np.arange(self.num_envs), self.pos[:, 0], self.pos[:, 1]]

    def episode_keys(self) -> np.ndarray:
        """[N] uint64: the keys of the rows' episodes for per-episode draws (``rl.randomness``)."""
        return self._keys

    def neighbours(self) -> tuple[np.ndarray, np.ndarray]:
        """Canvas ``(y, x)`` of the 4 cells the moves lead to, each ``[N, 4]``."""
        return neighbour_cells(self.pos)


class AgentView(UavView):
    """The rows of a ``BatchedEnv`` as their UAVs know them at one step (see the module's docstring and ``UavView``):
    made anew for every ``act``; also ``visits`` [N, L, L] (times each episode stood in each cell, a read-only view).
    ``memory`` holds the SINR measured at visited cells (``P_H`` elsewhere, ``P_L`` at known blocked cells)."""

    config: CanvasSettings

    def __init__(self, env: object, public: PublicMaps) -> None:
        canvas = env.maps.view_map[env.view]
        super().__init__(public, public.config, env.pos, env.t, env.exhausted, env.memory, canvas, env.episode_keys())
        self.visits = frozen(env.visits)

    def neighbour_visits(self) -> np.ndarray:
        """``[N, 4]``: how often this episode has stood in the cell each move leads to."""
        ny, nx = self.neighbours()
        return self.visits[np.arange(self.num_envs)[:, None], ny, nx]


def _erring(bundle: Bundle, settings: MapErrorSettings) -> dict:
    """The public settings an erring map changes: its version names the error too (the searcher keys its predicted
    maps by it), nothing for the exact map."""
    tag = error_tag(settings)
    return {"version": bundle.version + tag} if tag else {}


def neighbour_cells(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canvas ``(y, x)`` of the 4 cells the moves (``MOVES``) lead to from ``pos`` [N, 2], each ``[N, 4]``."""
    return pos[:, None, 0] + MOVES[None, :, 0], pos[:, None, 1] + MOVES[None, :, 1]


def sealed(a: np.ndarray) -> np.ndarray:
    """A read-only copy of ``a``."""
    c = np.array(a, copy=True)
    c.flags.writeable = False
    return c


def frozen(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (the env's own array, seen as it changes; a policy cannot write through it)."""
    v = a.view()
    v.flags.writeable = False
    return v


def view_for(policy: object, env: object) -> object:
    """What ``policy`` receives as ``env`` in ``act``: the env itself for a privileged policy (the genie, the oracles:
    ``privileged = True``), else the env's view of what its UAVs know (``env.agent_view()``: an ``AgentView`` of a
    placement env, a ``TrackingView`` of a tracking env)."""
    if getattr(policy, "privileged", False):
        return env
    return env.agent_view()


def public_maps(env: object) -> PublicMaps:
    """The public maps of ``env``'s MapSet, made once and kept on the env while it flies over the same maps."""
    kept = getattr(env, "_public", None)
    if kept is None or kept[0] is not env.maps:
        env._public = kept = (env.maps, PublicMaps.of(env.maps))
    return kept[1]

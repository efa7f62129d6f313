"""The engine every task stands on, apart from any one task: ``settings`` (``ObservationSettings``, the observation's
settings every task's extend, and ``CanvasSettings``, what the map set reads), ``maps`` (``MapSet``: the bundles'
maps on square canvases under the symmetries of the square, ``MOVES``, ``transform``), ``rows`` (``EpisodeRows``:
the rows of episodes every batched environment steps, and the observation's byte encoding), ``stats`` (the episode
statistics every report reads: success, steps against the genie's, SPL) and ``view`` (what a policy may read:
``AgentView``, ``PublicMaps``). It imports no task, no learner and no report: the tasks (``rl.tasks``), the belief
(``rl.belief``) and the learner (``rl.agent``) stand on it (``tests/test_packaging.py`` holds the layers)."""

from __future__ import annotations

import importlib
from collections.abc import Callable


def exported(package: str, exports: dict[str, str]) -> Callable[[str], object]:
    """A package's ``__getattr__``: each name of ``exports`` imported from the file that holds it on first use, so
    that reading one file (a task's settings, for a command line) does not load the others."""

    def getattr_(name: str) -> object:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{exports[name]}"), name)

    return getattr_


#: What the package offers, by the file that holds it, imported on first use (``exported``).
FILES = {
    "settings": ("CanvasSettings", "ObservationSettings"),
    "maps": ("MOVES", "MapSet", "transform"),
    "rows": ("OBS_OFFSET", "EpisodeRows", "decode_obs", "encode_obs", "refuse_bad_rows"),
    "stats": ("STATS", "WITHIN", "episode_stats", "format_stat", "interquartile_mean", "spl_terms", "summarise"),
    "view": ("AgentView", "PublicMaps", "public_maps", "view_for"),
}
EXPORTS = {name: file for file, names in FILES.items() for name in names}

__all__ = sorted([*EXPORTS, "exported"])


__getattr__ = exported(__name__, EXPORTS)

"""The tasks beyond placement, one folder each with the same files: ``config`` (the task's settings), ``maps`` (its
cities, episodes and oracle), ``env`` (the task stepped in numpy and what a policy may read of it), ``policies``,
``searcher`` (the map searcher run for it), ``rollout`` (playing a list of episodes with a policy), and where the task
has them ``learner`` (the task as the learner's environment, when its env is not one) and ``zoo`` (PettingZoo)."""

from __future__ import annotations

import importlib
from collections.abc import Callable


def exported(package: str, exports: dict[str, str]) -> Callable[[str], object]:
    """A task package's ``__getattr__``: each name of ``exports`` imported from the file that holds it on first use,
    so that reading one file (the task's settings, for a command line) does not load the others."""

    def getattr_(name: str) -> object:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{exports[name]}"), name)

    return getattr_

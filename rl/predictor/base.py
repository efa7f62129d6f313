"""What every tier of the predictor is (``Predictor``) and the digest of the family's code (``code_digest``)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Protocol

import numpy as np

from uavplace.rl.predictor.scene import Scene

#: The folder of the predictor family: every module in it is code a prediction may run.
FAMILY = Path(__file__).resolve().parent


class Predictor(Protocol):
    """What predicts users' maps for the searcher: each tier of ``uavplace.rl.predictor`` (``TIERS``)."""

    tier: str
    error_db: float  # the spread of (measured - predicted) SINR on live cells [dB]

    def version(self) -> str: ...

    def predict(self, scene: Scene, users: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


#: The modules that only run commands (their options, what they print): no map depends on them.
COMMANDS = ("cli.py", "options.py")
#: The code a prediction depends on, below the package's root: the predictor family, the engine that hands it the
#: public maps (heights, blocked cells), the belief that caches its maps, the settings, the bundles the maps come from
#: and the ray tracer of the ray-traced tier.
DEPENDS = ("rl/predictor", "rl/world", "rl/belief", "rl/config.py", "rl/randomness.py", "dataset", "simulate", "schemas")
_PACKAGE = FAMILY.parent.parent


def _digest_of(root: Path) -> str:
    digest = hashlib.sha256()
    for part in DEPENDS:
        top = root / part
        for path in sorted([top] if top.suffix == ".py" else top.rglob("*.py")):
            if path.name not in COMMANDS and "__pycache__" not in path.parts:
                digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


#: Read once, when the family is first imported, so that it is the code this process loaded (not a file edited
#: while it runs, whose maps would be written under the new code's key).
_LOADED = _digest_of(_PACKAGE)


def code_digest() -> str:
    """The sha256 of the code a prediction depends on (every ``.py`` of ``DEPENDS`` but the commands', by path and
    content, as it was when this process first imported the family): part of every tier's version, so that a change
    to any of it is never served the maps of the code before it."""
    return _LOADED


def version_of(doc: dict) -> str:
    """12 hex digits of ``doc`` (a tier's settings, weights, constants and ``code_digest``): a cache of its maps' key."""
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]

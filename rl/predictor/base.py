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


#: The modules of the folder that only run commands (their options, what they print): no map depends on them.
COMMANDS = ("cli.py", "options.py")


def code_digest() -> str:
    """The sha256 of the predictor family's code (every ``.py`` of this folder but its commands', ``COMMANDS``, by name
    and content): part of every tier's version, so that a change to the code is never served the maps of the code
    before it."""
    digest = hashlib.sha256()
    for path in sorted(p for p in FAMILY.glob("*.py") if p.name not in COMMANDS):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def version_of(doc: dict) -> str:
    """12 hex digits of ``doc`` (a tier's settings, weights, constants and ``code_digest``): a cache of its maps' key."""
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]

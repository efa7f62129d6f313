"""Checkpoints that are data, never code.

A PyTorch ``.pt`` file is a pickle: loaded with ``weights_only=False`` it can run
any code its author put in it. Agents are what researchers exchange, so every
checkpoint uavplace reads is loaded with ``torch.load(weights_only=True)``,
which unpickles tensors, dicts, lists, strings and numbers only, and refuses
anything else with an ``InputError`` instead of running it. What is not a
tensor (random-generator states, counters) is kept in JSON and ``.npz``
(``allow_pickle=False``) beside the weights.

Formats:

- ``checkpoints/best.pt``: ``{"online": state_dict, "config": DQNConfig as JSON
  values, "eval": the evaluation row}``; the agent a report evaluates.
- ``checkpoints/last/``: the resumable state, one folder published by a
  rename (``infra.files.atomic_directory``), so it is whole or absent:
  ``networks.pt`` (networks, optimiser, torch RNG), ``env.npz`` (environment
  and run arrays), ``replay.npz``, ``metrics.parquet`` and ``eval.parquet``
  (the rows up to this step) and, written last, ``checkpoint.json`` (step,
  counters, numpy RNG states).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from pydantic import Field, model_validator

from uavplace.schemas import InputError
from uavplace.schemas.base import Contract

#: The resumable checkpoint folder's marker, written last.
CHECKPOINT_JSON = "checkpoint.json"


class CheckpointState(Contract):
    """``checkpoint.json``: the counters and random-generator states of a resumable checkpoint, checked on resume."""

    step: int = Field(ge=0, description="Environment steps done")
    updates: int = Field(ge=0, description="Gradient updates done")
    best_score: tuple[float, float] | None = Field(description="(success, -median steps) of the best evaluation")
    synced_at: int = Field(ge=0, description="Step of the last target-network sync")
    losses: list[float] = Field(max_length=10_000)
    episodes_started: int = Field(ge=0)
    rng: dict[str, Any] = Field(description="The trainer's numpy bit-generator state")
    env_rng: dict[str, Any] = Field(description="The environment's numpy bit-generator state")
    wall_s: float | None = Field(default=None, ge=0, description="Training seconds so far (None before they were kept)")

    @model_validator(mode="after")
    def _ordered(self) -> CheckpointState:
        if self.synced_at > self.step:
            raise ValueError(f"synced_at {self.synced_at} is after step {self.step}")
        if self.best_score is not None and not (0 <= self.best_score[0] <= 1 and self.best_score[1] <= 0):
            raise ValueError(f"best_score {list(self.best_score)}: expected (success in 0..1, -median steps <= 0)")
        if not all(math.isfinite(v) for v in self.losses):
            raise ValueError("losses holds NaN or inf: a training stops before it saves a non-finite loss")
        return self


def best_checkpoint(folder: str | Path) -> Path:
    """A run folder's ``checkpoints/best.pt``; ``InputError`` when there is none (one that is there but no regular
    file is refused by ``load_tensors``, as such)."""
    path = Path(folder) / "checkpoints" / "best.pt"
    if not os.path.lexists(path):
        raise InputError(folder, "no checkpoints/best.pt (not a training run, or it never evaluated)")
    return path


def require(ck: dict, path: str | Path, *keys: str) -> None:
    """``InputError`` if the checkpoint dict lacks one of ``keys``."""
    missing = [k for k in keys if k not in ck]
    if missing:
        raise InputError(path, f"checkpoint lacks {', '.join(missing)}", field=missing[0])

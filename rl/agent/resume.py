"""What a run starts or resumes from: the state a checkpoint restores (``RunState``, ``read_state``), the
weights of ``--set init`` (``start_from``), and Ctrl-C turned into a checkpoint (``Interrupted``)."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from uavplace.infra.tensors import load_tensors
from uavplace.rl.agent.checkpoint import CheckpointState, require
from uavplace.rl.agent.config import DQNConfig
from uavplace.rl.agent.dqn import DQN
from uavplace.rl.agent.network import add_input_channel
from uavplace.schemas import InputError
from uavplace.schemas.base import validation_message


@dataclass
class RunState:
    """What changes while training (and is saved for resuming)."""

    step: int = 0
    last_action: np.ndarray | None = None
    start_sinr: np.ndarray | None = None
    episodes: list[dict] = field(default_factory=list)
    evals: list[dict] = field(default_factory=list)
    best_score: tuple[float, float] | None = None
    synced_at: int = 0
    losses: list[float] = field(default_factory=list)
    wall_s: float | None = 0.0  # seconds before this start (the checkpoint's); None: one that did not count them


class Interrupted(Exception):
    """Training stopped by Ctrl-C (SIGINT) at a step boundary, after a checkpoint there."""

    def __init__(self, run_dir: Path, step: int) -> None:
        super().__init__(f"interrupted at step {step:,}; checkpoint saved. Continue with: uavrl train --resume {run_dir}")
        self.run_dir, self.step = run_dir, step


#: The environment variable that, set to ``end``, leaves Ctrl-C as it is for any program: it ends a training at
#: once, without a checkpoint (the test suite sets it, so that a first Ctrl-C ends ``pytest``; tests/conftest.py).
CTRL_C = "UAVPLACE_CTRL_C"


@contextlib.contextmanager
def interrupts() -> Iterator[Callable[[], bool]]:
    """While the block runs, Ctrl-C (SIGINT) only sets a flag the training loop reads between steps, so that it can
    checkpoint a consistent state; a second Ctrl-C interrupts at once. Outside the main thread, or with ``CTRL_C`` set
    to ``end``, nothing changes."""
    if threading.current_thread() is not threading.main_thread() or os.environ.get(CTRL_C) == "end":
        yield lambda: False
        return
    pressed = []

    def handler(signum: int, frame: object) -> None:
        if pressed:
            raise KeyboardInterrupt
        pressed.append(signum)

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: bool(pressed)
    finally:
        signal.signal(signal.SIGINT, previous)


def read_state(path: Path, max_step: int) -> CheckpointState:
    """``checkpoint.json``, checked: its schema (``CheckpointState``) and a step within the run's schedule."""
    try:
        state = CheckpointState.model_validate_json(path.read_text(encoding="utf-8"))
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise InputError(path, message, field=field) from None
    if state.step > max_step:
        raise InputError(path, f"step {state.step:,} is beyond the run's {max_step:,} steps", field="step")
    return state


def start_from(agent: DQN, config: DQNConfig) -> None:
    """Load ``config.init``'s weights (member ``init_member`` of an ensemble) into ``agent``'s networks; ``InputError``
    naming the checkpoint when it holds no such network."""
    path = Path(config.init)
    ckpt = path / "checkpoints" / "best.pt" if path.is_dir() else path
    ck = load_tensors(ckpt)
    require(ck, ckpt, "online")
    state = ck["online"]
    if any(k.startswith("nets.") for k in state):  # an ensemble (MeanQ): its members side by side
        prefix = f"nets.{config.init_member}."
        state = {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}
        if not state:
            raise InputError(ckpt, f"an ensemble without a member {config.init_member}", field="init_member")
    own = agent.online.state_dict()
    if config.env.fleet_channel and any(k in own and v.shape != own[k].shape for k, v in state.items()):
        # a network without the fleet channel (a placement agent's): the channel added at zero weight
        try:
            state = add_input_channel(state, agent.online, config.env.fleet_index)
        except (KeyError, RuntimeError, TypeError, ValueError) as exc:
            raise InputError(ckpt, f"its weights do not fit this run's network ({str(exc)[:200]})", field="init") from None
    try:
        agent.online.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise InputError(ckpt, f"its weights do not fit this run's network ({str(exc)[:200]})", field="init") from None
    agent.target.load_state_dict(agent.online.state_dict())

"""A training run's folder: its record (``run.json``), whether it finished, its name, and the policy its
checkpoint holds."""

from __future__ import annotations

import time
from pathlib import Path

import pandas as pd
from pydantic import Field, ValidationError
from torch import nn

from uavplace.infra.device import torch_device
from uavplace.infra.files import (
    read_small_file,
)
from uavplace.infra.tensors import load_tensors
from uavplace.rl.agent.checkpoint import require
from uavplace.rl.agent.config import DQNConfig
from uavplace.rl.agent.dqn import DQNPolicy, make_network
from uavplace.schemas import InputError
from uavplace.schemas.base import Contract, validation_message
from uavplace.schemas.bundle import BundleManifest, BundleSettings

#: The resumable checkpoint folder under ``checkpoints/``.
LAST = "last"


#: The run's record: how it was made.
RUN_JSON = "run.json"


class RunRecord(Contract):
    """``run.json``: the configuration, the bundles trained on, the command; written when a run starts."""

    config: DQNConfig
    datasets: dict[str, str] = Field(description="Training city -> bundle version")
    val_datasets: dict[str, str] = Field(
        default_factory=dict, description="Validation city -> bundle version: the cities best.pt was selected on"
    )
    bundle_settings: dict[str, BundleSettings] = Field(
        default_factory=dict,
        description="Training city -> the settings its bundle was built with (grid, altitude, noise): a report warns "
        "when it plays the agent on a bundle of other settings",
    )
    train_split: str | None = Field(description="Users episodes were drawn from (None: all users)")
    eval_split: str | None = Field(description="Users the periodic evaluation (and best.pt) used")
    command: str
    resumed: list[str] = Field(
        default_factory=list, description="Each later command that continued the run (`--resume`), with the step it resumed from"
    )
    uavplace_version: str
    torch_version: str
    created_utc: str
    members: dict[str, RunRecord] = Field(
        default_factory=dict,
        description="An ensemble's runs (`uavrl ensemble`): each run folder as it was given, with its run.json",
    )

    @property
    def commands(self) -> list[str]:
        """Every command that made the run, in order: an ensemble's members' first, then the first, then each
        ``--resume``."""
        return [*(c for m in self.members.values() for c in m.commands), self.command, *self.resumed]


def settings_unlike(record: RunRecord, manifest: BundleManifest, p_t_db: float | None = None) -> list[str]:
    """How ``manifest``'s bundle differs from every bundle the run was trained on (``BundleSettings.unlike`` against
    its most common training settings; empty when one of them is alike or none is recorded), and ``p_t_db`` from the
    P_T a placement agent was trained at, one phrase each."""
    trained = list(record.bundle_settings.values())
    mine = BundleSettings.of(manifest)
    unlike = [] if not trained or mine in trained else mine.unlike(max(trained, key=trained.count))
    if p_t_db is not None and record.config.task.env_p_t and p_t_db != record.config.env.p_t_db:
        unlike.append(f"P_T {p_t_db:g} dB (trained at {record.config.env.p_t_db:g} dB)")
    return unlike


def read_run_json(folder: str | Path) -> RunRecord:
    """A run folder's ``run.json``; ``InputError`` naming the file when it is missing or malformed."""
    path = Path(folder) / RUN_JSON
    data = read_small_file(path, "a run's record", missing="no run.json: not a folder written by `uavrl train`")
    try:
        return RunRecord.model_validate_json(data)
    except (ValidationError, UnicodeDecodeError, ValueError) as exc:
        if isinstance(exc, ValidationError):
            field, message = validation_message(exc)
        else:
            field, message = "json", str(exc)
        raise InputError(path, message, field=field) from None


def run_finished(run_dir: Path) -> bool:
    """True when the run's evaluations reached its ``total_steps`` (its schedule is done)."""
    path = run_dir / "eval.parquet"
    if not path.is_file() or not (run_dir / RUN_JSON).is_file():
        return False
    evals = pd.read_parquet(path, columns=["step"])
    return bool(len(evals)) and int(evals["step"].max()) >= read_run_json(run_dir).config.total_steps


def new_run_dir(runs: str | Path, config: DQNConfig) -> Path:
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    tag = config.task.tag
    task = f"-{tag}" if tag else ""
    return Path(runs) / f"{stamp}-{config.preset}{task}-{config.agent}-s{config.seed}"


def policy_from_checkpoint(
    ck: dict, path: str | Path, epsilon: float = 0.096, seed: int = 0, device: str = "cpu", precision: str = "float32"
) -> tuple[DQNPolicy, DQNConfig]:
    """The policy a loaded ``best.pt`` (``load_tensors``) holds, with its config, its network on ``device``
    (``infra.device``'s setting) acting in ``precision`` (``DQNPolicy``); ``InputError`` naming ``path``."""
    net, config = network_from_checkpoint(ck, path)
    return DQNPolicy.from_config(net.to(torch_device(device)), config, epsilon, seed, precision), config


def network_from_checkpoint(ck: dict, path: str | Path) -> tuple[nn.Module, DQNConfig]:
    """The network a loaded ``best.pt`` holds, with its config; ``InputError`` naming ``path``."""
    require(ck, path, "online", "config")
    try:
        config = DQNConfig.model_validate(ck["config"])
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise InputError(path, f"checkpoint config: {message}", field=field) from None
    net = make_network(config, *config.observation())
    try:
        net.load_state_dict(ck["online"])
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise InputError(
            path, f"weights do not fit the network its config describes ({str(exc)[:200]})", field="online"
        ) from None
    return net, config


def load_policy(path: str | Path, epsilon: float = 0.096, seed: int = 0) -> tuple[DQNPolicy, DQNConfig]:
    """A ``best.pt`` as a ``Policy``, with the config it was trained with; ``InputError`` for anything but weights."""
    return policy_from_checkpoint(load_tensors(path), path, epsilon, seed)

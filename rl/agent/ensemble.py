"""`uavrl ensemble`: finished runs of one config acting as one agent, the mean of their Q values.

Each member keeps its own features and, when recurrent, its own state (``MeanQ``); the greedy move maximises the
mean Q less the config's revisit penalty, with the config's test epsilon, as one network would. The folder it
writes reads like a run folder to ``uavrl report``:

- ``run.json``: the members' config with ``ensemble`` = their number (and the first member's seed, which seeds the
  random moves), their cities and bundle versions, and each member's own ``run.json`` under ``members``;
- ``checkpoints/best.pt``: the members' ``best.pt`` side by side, with the ensemble's evaluation on the members'
  validation episodes (the fixed episodes its seed draws, as a run's periodic evaluation does);
- ``eval.parquet``: that evaluation; ``metrics.parquet``: the members' training episodes, with a ``member`` column.

The members must share everything but the seed: the config, the cities and their bundle versions. An ensemble is
chosen as a run is, on validation cities only, never on a test city.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import torch

from uavplace.dataset.bundle import load_bundle
from uavplace.infra.files import atomic_directory, write_model_json
from uavplace.infra.tensors import load_tensors, save_tensors
from uavplace.rl.agent.checkpoint import best_checkpoint
from uavplace.rl.agent.config import DQNConfig
from uavplace.rl.agent.dqn import DQNPolicy
from uavplace.rl.agent.network import MeanQ
from uavplace.rl.agent.runs import RUN_JSON, RunRecord, network_from_checkpoint, read_run_json
from uavplace.rl.tasks.placement.learner import play_validation, validation_set
from uavplace.rl.world.cities import plan_cities
from uavplace.schemas import InputError
from uavplace.schemas.base import uavplace_version

#: Config fields members may differ in: the seed (what makes them members) and where they trained.
FREE_FIELDS = {"seed", "device"}


@dataclass
class Member:
    folder: Path
    run: RunRecord
    config: DQNConfig
    net: torch.nn.Module


def read_member(folder: str | Path) -> Member:
    """A finished run's ``run.json`` and ``best.pt``; ``InputError`` naming the file that is missing or wrong."""
    folder = Path(folder)
    run = read_run_json(folder)
    ckpt = best_checkpoint(folder)
    net, config = network_from_checkpoint(load_tensors(ckpt), ckpt)
    if config.ensemble != 1:
        raise InputError(ckpt, "already an ensemble: give the runs it was built from", field="ensemble")
    if not config.task.ensembles:
        raise InputError(ckpt, f"a {config.task.kind} run: an ensemble is validated as a placement agent", field="task")
    if config != run.config:
        raise InputError(ckpt, f"its config is not the one {folder / RUN_JSON} records", field="config")
    return Member(folder, run, config, net)


def check_members(members: list[Member]) -> None:
    """Refuse members that differ in anything but the seed (naming the first field that differs), or that share one."""
    if len(members) < 2:
        raise InputError(None, "an ensemble needs at least two runs", field="runs")
    first = members[0]
    base = first.config.model_dump(exclude=FREE_FIELDS)
    seen: dict[int, Path] = {}
    for m in members:
        where = m.folder / RUN_JSON
        other = m.config.model_dump(exclude=FREE_FIELDS)
        diff = [k for k in base if base[k] != other[k]]
        if diff:  # first: runs that differ are never called the same network
            raise InputError(
                where,
                f"differs from {first.folder} ({base[diff[0]]!r} there, {other[diff[0]]!r} here)",
                field=f"config.{diff[0]}",
            )
        if m.config.seed in seen:
            raise InputError(
                where, f"the same settings and seed as {seen[m.config.seed]}: the same network twice", field="config.seed"
            )
        seen[m.config.seed] = m.folder
        for name in ("datasets", "val_datasets", "train_split", "eval_split"):
            if getattr(m.run, name) != getattr(first.run, name):
                raise InputError(where, f"differs from {first.folder}: trained or selected on other cities", field=name)


def build_ensemble(
    runs: list[str | Path],
    out: str | Path,
    root: str | Path,
    command: str = "",
    on_progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Write the ensemble of ``runs`` to the new folder ``out``; return its evaluation (success, median steps, mean
    return) on the members' validation episodes (``on_progress(done, total)``: episodes played). Everything that can
    fail is checked before anything is written."""
    out = Path(out)
    if out.exists():
        raise InputError(out, "exists: choose another --out (an ensemble folder is written once)")
    members = [read_member(r) for r in runs]
    check_members(members)
    first = members[0]
    config = first.config.model_copy(update={"ensemble": len(members)})
    net = MeanQ([m.net for m in members])  # the network `make_network(config)` builds, with the members' weights
    cities = plan_cities(
        [load_bundle(c, v, root=root) for c, v in first.run.datasets.items()],
        [load_bundle(c, v, root=root) for c, v in first.run.val_datasets.items()],
        config.eval_split,
    )
    maps, episodes = validation_set(config, cities)
    labels = [m.folder.name for m in members]
    if len(set(labels)) < len(labels):  # runs of one name in other folders: the whole path tells them apart
        labels = [str(m.folder) for m in members]
    curves = [
        _metrics(m.folder).assign(member=label)
        for m, label in zip(members, labels, strict=True)
        if (m.folder / "metrics.parquet").is_file()
    ]
    policy = DQNPolicy.from_config(net, config)
    row = {"step": None, **play_validation(policy, maps, episodes, on_step=on_progress), "wall_s": None}
    record = RunRecord(
        config=config,
        datasets=first.run.datasets,
        bundle_settings=first.run.bundle_settings,
        val_datasets=first.run.val_datasets,
        train_split=first.run.train_split,
        eval_split=first.run.eval_split,
        command=command,
        uavplace_version=uavplace_version(),
        torch_version=torch.__version__,
        created_utc=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        members={str(m.folder): m.run for m in members},
    )
    with atomic_directory(out, marker=RUN_JSON, what="ensemble", new=True) as tmp:  # not one another process wrote
        (tmp / "checkpoints").mkdir()
        best = {"online": net.state_dict(), "config": config.model_dump(mode="json"), "eval": row}
        save_tensors(best, tmp / "checkpoints" / "best.pt")
        pd.DataFrame([row | {"best": True}]).to_parquet(tmp / "eval.parquet", index=False)
        if curves:
            pd.concat(curves, ignore_index=True).to_parquet(tmp / "metrics.parquet", index=False)
        write_model_json(record, tmp / RUN_JSON)
    return row


def _metrics(folder: Path) -> pd.DataFrame:
    try:
        return pd.read_parquet(folder / "metrics.parquet")
    except (OSError, ValueError) as exc:
        raise InputError(folder / "metrics.parquet", f"unreadable ({str(exc)[:160]})") from None

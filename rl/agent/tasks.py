"""The trainers of the tasks beyond placement (tracking, fleet) and the one registry that picks a run's trainer by its
task (``TRAINERS``, ``start_run``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from uavplace.rl.agent.cities import Cities
from uavplace.rl.agent.config import DQNConfig
from uavplace.rl.agent.dqn import DQNPolicy
from uavplace.rl.agent.train import Trainer
from uavplace.rl.tasks.fleet import FleetMaps, FleetPlacement, FleetTrainEnv, run_fleet
from uavplace.rl.tasks.tracking import RouteSet, TrackingEnv, run_tracking
from uavplace.schemas import InputError


class TrackingTrainer(Trainer):
    """A run of the tracking task (``DQNConfig.task`` "tracking", ``rl.tasks.tracking``): placement's learner, loop,
    checkpoints and run folder; the env is the tracking env over the training cities' routes (5 actions, stay the
    fifth), and ``best.pt`` is the network that covered the most of the horizon on fixed episodes of the validation
    cities' routes (ties: the one that reached P_T in more of them). A training city's routes are all trained on: a
    tracking run needs validation cities with routes of their own (built with ``--split CITY=val``, or
    ``--val-dataset``)."""

    def setup_task(self, cities: Cities) -> None:
        task, trained = self.config.tracking_config(), {b.city for b in cities.train}
        val = [b for b in cities.val if b.city not in trained]  # without validation cities, plan_cities gives the trained ones
        for b in cities.train + val:
            if b.routes is None:
                raise InputError(
                    None,
                    f"{b.city} has no routes: the tracking task trains and selects on cities simulated with "
                    f"`uavdata simulate --routes N`",
                    field="dataset" if b.city in trained else "val_dataset",
                )
        if not val:
            raise InputError(
                None,
                "the tracking task selects best.pt on validation cities with routes, and none is given: build one "
                "with `uavdata build --split CITY=val` and add it with --dataset or --val-dataset",
                field="val_dataset",
            )
        self.routes, self.eval_routes = RouteSet(cities.train, task, rotate=task.rotate), RouteSet(val, task)
        self.eval_episodes = self.eval_routes.sample_episodes(
            self.config.eval_episodes, np.random.default_rng([self.config.seed, 2])
        )
        self.env = TrackingEnv(self.routes, self.config.num_envs, compact=True)
        self.train_bundles, self.val_bundles = self.routes.bundles, self.eval_routes.bundles

    @property
    def t_max(self) -> int:
        return self.config.task.horizon

    def validate(self, policy: DQNPolicy) -> tuple[dict, tuple[float, float]]:
        table = run_tracking(self.eval_routes, policy, self.eval_episodes).table
        row = tracking_summary(table)
        return row, (row["covered_share"], row["success"])

    def episode_values(self, info: dict, row: int, terminated: bool) -> dict:
        share = float(info["covered_share"][row])
        return {"success": share > 0, "covered_share": share}


class FleetTrainer(Trainer):
    """A run of the fleet task (``DQNConfig.task`` "fleet", ``rl.tasks.fleet``): placement's network, learner, loop,
    checkpoints and run folder; the env is ``FleetTrainEnv`` over fleet episodes of the training cities' training
    users (a row per UAV), and ``best.pt`` is the network that, run on every UAV of fixed fleet episodes of the
    validation cities (``FleetPlacement``), served every user in the most of them (ties: the fewer median steps)."""

    def setup_task(self, cities: Cities) -> None:
        task, env = self.config.fleet_config(), self.config.env_config()
        self.maps = FleetMaps.of(cities.train, task, cities.train_users)
        self.eval_maps = FleetMaps.of(cities.val, task, cities.val_users)
        self.eval_episodes = self.eval_maps.episode_list(self.config.eval_episodes, self.config.seed)
        self.env = FleetTrainEnv(self.maps, env, self.config.num_envs)
        self.train_bundles, self.val_bundles = cities.train, cities.val

    @property
    def t_max(self) -> int:
        return self.config.task.t_max

    def validate(self, policy: DQNPolicy) -> tuple[dict, tuple[float, float]]:
        fleet = FleetPlacement(policy, self.config.env_config(evaluation=True), prefix="").bind(self.eval_maps)
        table = run_fleet(self.eval_maps, fleet, self.eval_episodes)
        row = {
            "success": float(table["success"].mean()),
            "median_steps": float(np.median(table["steps"])),
            "spl": float(table["spl"].mean()),
        }
        return row, (row["success"], -row["median_steps"])


#: A run's trainer, by its task (``DQNConfig.task``).
TRAINERS: dict[str, type[Trainer]] = {"placement": Trainer, "tracking": TrackingTrainer, "fleet": FleetTrainer}


def tracking_summary(table: pd.DataFrame) -> dict:
    """An evaluation row of tracking episodes (``run_tracking``'s table): the mean share of the horizon covered, the
    mean coverage after the first reach, the share of episodes that reached P_T (``success``) and the median steps
    to the first reach (``median_steps``; inf when half never did)."""
    return {
        "covered_share": float(table["covered_share"].mean()),
        "coverage": float(table["coverage"].mean()),
        "success": float(np.isfinite(table["first_reach"]).mean()),
        "median_steps": float(np.median(table["first_reach"])),
    }


def start_run(
    run_dir: Path,
    config: DQNConfig,
    datasets: list[str],
    val_datasets: list[str],
    root: str | Path,
    *,
    resume: bool,
    command: str = "",
) -> Trainer:
    """The trainer of the run in ``run_dir``, ready to ``run(resume=resume)``; call it with the folder's lock held
    (``exclusive_folder``). A new run claims its folder first (``FileExistsError`` when it exists) and gives the name
    back if its trainer cannot be made; a resumed one is loaded (every check of the checkpoint before the first
    step). ``uavrl train`` and every trial of ``uavrl sweep`` start here."""
    claimed = False
    if not resume:
        if run_dir.exists():
            raise FileExistsError(f"{run_dir} exists: choose another --name, or continue it with --resume {run_dir}")
        run_dir.mkdir(parents=True)
        claimed = True
    kind = TRAINERS[config.task.kind]
    try:
        trainer = kind(config, list(datasets), root, run_dir, command=command, val_datasets=list(val_datasets))
    except BaseException:
        if claimed and not any(run_dir.iterdir()):
            run_dir.rmdir()  # nothing was written: give the name back
        raise
    if resume and trainer.resumable():
        trainer.load()
    return trainer

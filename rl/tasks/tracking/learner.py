"""Tracking as the learner's task (``learning``, the hook of its entry): placement's learner, loop, checkpoints and
run folder on the tracking env over the training cities' routes (5 actions, stay the fifth); ``best.pt`` is the
network that covered the most of the horizon on fixed episodes of the validation cities' routes (ties: the one that
reached P_T in more of them)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from uavplace.rl.tasks.entry import Learning, RunSettings
from uavplace.rl.tasks.tracking.env import TrackingEnv
from uavplace.rl.tasks.tracking.maps import RouteSet
from uavplace.rl.tasks.tracking.rollout import run_tracking
from uavplace.rl.world.cities import Cities
from uavplace.schemas import InputError


def learning(run: RunSettings, cities: Cities) -> Learning:
    """The tracking env over the training cities' routes and the validation on the validation cities' routes. A
    training city's routes are all trained on: a tracking run needs validation cities with routes of their own (built
    with ``--split CITY=val``, or ``--val-dataset``)."""
    task, trained = run.task.playing(run), {b.city for b in cities.train}
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
    routes, eval_routes = RouteSet(cities.train, task, rotate=task.rotate), RouteSet(val, task)
    episodes = eval_routes.sample_episodes(run.eval_episodes, np.random.default_rng([run.seed, 2]))

    def validate(policy) -> tuple[dict, tuple[float, float]]:
        row = tracking_summary(run_tracking(eval_routes, policy, episodes).table)
        return row, (row["covered_share"], row["success"])

    def episode_values(info: dict, row: int, terminated: bool) -> dict:
        share = float(info["covered_share"][row])
        return {"success": share > 0, "covered_share": share}

    def describe(row: dict) -> str:
        return f"{100 * row['covered_share']:.1f} % of the horizon covered, P_T reached in {100 * row['success']:.1f} % of the episodes"

    env = TrackingEnv(routes, run.num_envs, compact=True)
    return Learning(env, task.horizon, routes.bundles, eval_routes.bundles, validate, episode_values, describe)


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

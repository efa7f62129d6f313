"""Placement as the learner's task (``learning``, the hook of its entry): the training env over the training cities'
users and the fixed validation episodes that select ``best.pt`` (``validation_set``, ``play_validation``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from uavplace.infra.files import in_corpus
from uavplace.rl.tasks.entry import Learning, RunSettings
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.tasks.placement.policies import Policy
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.world.cities import Cities
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.stats import summarise
from uavplace.schemas import InputError


def learning(run: RunSettings, cities: Cities) -> Learning:
    """The training env (compact observations, ``run.num_envs`` rows over the training users) and the validation
    that selects ``best.pt``: success on the fixed validation episodes (ties: the fewer median steps)."""
    env = run.env_config()
    unmatched = [n for n in env.city_weights if not any(in_corpus(b.city, n) for b in cities.train)]
    if unmatched:
        raise InputError(
            None,
            f"{', '.join(unmatched)}: no training city or corpus of that name (training cities: "
            f"{', '.join(b.city for b in cities.train)})",
            field="env.city_weights",
        )
    maps = MapSet(cities.train, env.model_copy(update={"split": cities.train_split}), cities.train_users)
    eval_maps, episodes = validation_set(run, cities)

    def validate(policy: Policy) -> tuple[dict, tuple[float, float]]:
        row = play_validation(policy, eval_maps, episodes)
        return row, (row["success"], -row["median_steps"])

    return Learning(BatchedEnv(maps, run.num_envs, compact=True), env.t_max, maps.bundles, eval_maps.bundles, validate)


def validation_set(run: RunSettings, cities: Cities) -> tuple[MapSet, np.ndarray]:
    """The maps and the fixed episodes (``run.eval_episodes``, seeded by ``run.seed``) of a run's periodic
    evaluation, the one that chooses ``best.pt``."""
    maps = MapSet(cities.val, run.env_config(evaluation=True).model_copy(update={"split": cities.val_split}), cities.val_users)
    return maps, maps.sample_episodes(run.eval_episodes, np.random.default_rng([run.seed, 2]))


def play_validation(
    policy: Policy, maps: MapSet, episodes: np.ndarray, on_step: Callable[[int, int], None] | None = None
) -> dict:
    """``policy`` on the validation episodes: success rate, median steps and mean return (``on_step``: progress)."""
    df = run_episodes(maps, policy, episodes, num_envs=min(256, len(episodes)), on_step=on_step)
    summary = summarise(df)
    return {
        "success": float(summary["success"]),
        "median_steps": float(summary["median_steps"]),
        "mean_return": float(df.return_.mean()),
    }

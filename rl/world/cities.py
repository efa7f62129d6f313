"""The cities of a training run, whatever its task: which it trains on and which it selects its checkpoints on, and
the users of each (``plan_cities``; each task's ``learner.learning`` builds its environments from them)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavplace.dataset.bundle import Bundle
from uavplace.schemas import InputError


def role(bundle: Bundle) -> str | None:
    """The city's role given at build time (``--split CITY=ROLE``): train, val, test, or None."""
    return bundle.manifest.config.role


def training_users(bundle: Bundle) -> np.ndarray:
    """The users a run trains on in a city: a ``train`` city's training users, every user of a city without a role."""
    return bundle.user_indices("train") if role(bundle) == "train" else bundle.user_indices()


@dataclass
class Cities:
    """The bundles a run trains on and selects on, and the users of each it plays."""

    train: list[Bundle]
    train_users: list[np.ndarray]
    train_split: str | None
    val: list[Bundle]
    val_users: list[np.ndarray]
    val_split: str | None


def plan_cities(bundles: list[Bundle], val_bundles: list[Bundle], eval_split: str | None) -> Cities:
    """Split the given cities into training and validation ones; refuse a test city.

    A city built as ``val`` goes to validation; one built as ``test`` is refused (never trained or
    selected on). Training users: a ``train`` city's training users, every user of a city without a
    role. Validation: every user of the validation cities, each city once however often it is named
    (``--val-dataset`` and a val city of ``--dataset``); without any, the ``eval_split`` users of
    the training cities (all of them if none has that split).
    """
    for b in [*bundles, *val_bundles]:
        if role(b) == "test":
            raise InputError(
                None, f"{b.city} is a test city (built with --split {b.city}=test): never trained or selected on", field="dataset"
            )
    val = list({b.city: b for b in [*val_bundles, *(b for b in bundles if role(b) == "val")]}.values())
    train = [b for b in bundles if role(b) != "val"]
    if not train:
        raise InputError(None, "no training city: every --dataset given is a validation city", field="dataset")
    if set(b.city for b in train) & set(b.city for b in val):
        raise InputError(None, "a city cannot be both trained and validated on", field="val_dataset")
    train_users = [training_users(b) for b in train]
    train_split = "train" if any(role(b) == "train" for b in train) else None
    if val:
        return Cities(train, train_users, train_split, val, [b.user_indices() for b in val], None)
    has_split = eval_split is not None and any(len(b.user_indices(eval_split)) for b in train)
    split = eval_split if has_split else None
    return Cities(train, train_users, train_split, train, [b.user_indices(split) for b in train], split)

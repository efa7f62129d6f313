"""The fleet task's settings and its moves (the package's docstring says what the task is)."""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator

from uavplace.rl.config import SearchConfig
from uavplace.rl.tasks.entry import RunTask
from uavplace.rl.world.maps import MOVES
from uavplace.rl.world.settings import ObservationSettings

#: The fleet's 5 actions per UAV in map coordinates (dy, dx): the 4 placement moves, then 4 = stay.
FLEET_MOVES = np.vstack([MOVES, [[0, 0]]])
STAY = 4


def fleet_search() -> SearchConfig:
    """The fleet searcher's settings: the map searcher's with its belief products in bfloat16
    (``SearchConfig.precision``: issue 90's validation comparison on etoile-val and florence-val, docs/benchmarks.md)."""
    return SearchConfig(precision="bfloat16")


class FleetConfig(ObservationSettings):
    """Everything that defines the fleet task (saved with every run and report that uses it)."""

    uavs: int = Field(default=2, ge=1, le=4, description="Fleet: UAVs K in the fleet")
    users: int = Field(default=3, ge=1, le=6, description="Fleet: users N served at once, drawn from a city's traced users")
    t_max: int = Field(default=500, ge=1, description="Step budget: truncated after t_max steps")
    c_e: float = Field(default=1.2, description="Reward per UAV entering a cell the fleet never visited")
    success_bonus: float = Field(default=100.0, description="Reward when every user is served")

    @field_validator("window")
    @classmethod
    def _odd(cls, window: int) -> int:
        if window % 2 != 1:
            raise ValueError(f"window {window} must be odd")
        return window

    @property
    def num_channels(self) -> int:
        return 2 + self.users


class FleetTask(FleetConfig, RunTask):
    """A run's task when it is the fleet's: the fleet task's settings (``FleetConfig``); a UAV's users change as they
    are dealt, so the env's belief and context channels stay off."""

    kind: Literal["fleet"] = "fleet"

    prefix: ClassVar[str | None] = "fleet"
    tag: ClassVar[str] = "fleet"
    channels: ClassVar[bool] = False
    env_p_t: ClassVar[bool] = False
    ensembles: ClassVar[bool] = False

    def fleet(self) -> FleetConfig:
        """The fleet task these settings describe (its network reads placement's observation of each UAV's users,
        ``RunTask.playing``: the run's ``env``)."""
        return FleetConfig(**self.model_dump(exclude={"kind"}))

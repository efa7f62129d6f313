"""The tracking task's settings and its moves (the package's docstring says what the task is)."""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from uavplace.rl.config import SearchConfig
from uavplace.rl.tasks.entry import RunSettings, RunTask
from uavplace.rl.world.maps import MOVES
from uavplace.rl.world.settings import CanvasSettings, ObservationSettings
from uavplace.schemas.base import Contract

#: The 5 tracking actions in canvas coordinates (dy, dx): the 4 placement moves, then 4 = stay.
TRACK_MOVES = np.vstack([MOVES, [[0, 0]]])
STAY = 4
#: The action of each move (dy + 1, dx + 1) in ``TRACK_MOVES`` (-1: no action makes it).
ACTION_OF = np.full((3, 3), -1, np.int64)
ACTION_OF[TRACK_MOVES[:, 0] + 1, TRACK_MOVES[:, 1] + 1] = np.arange(len(TRACK_MOVES))


#: A horizon's bound beside its field's: the resource limit on steps per episode (``infra.options``).
STEPS = {"limit": "t_max"}
#: The fields of ``TrackingConfig`` that shape what an agent observes (the others define the task).
OBSERVATION_FIELDS = ("window", "blind", "p_h_db", "p_l_db", "age_clip_s", "edge_height_m", "height_clip_m")


class TrackingConfig(ObservationSettings):
    """Everything that defines the tracking task (saved with every run and report that uses it)."""

    horizon: int = Field(300, ge=1, le=100_000, description="Tracking: steps per episode (0.4 s each)", json_schema_extra=STEPS)
    uav_speed_mps: float = Field(default=10.0, gt=0, le=100, description="UAV speed: one cell per cell side / speed seconds")
    blind: bool = Field(default=False, description="No height channel; blocked cells shown as P_H in the SINR memory")
    age_clip_s: float = Field(
        default=100.0, gt=0, description="Measurement ages are clipped at this [s]; unvisited cells show it"
    )
    cover_reward: float = Field(default=1.0, description="Reward of a covered step")
    gain_weight: float = Field(default=0.05, description="Reward per dB of SINR change")
    rotate: bool = Field(
        default=False,
        description="Training: every route also under the quarter turns of its city (each city seen four ways, as "
        "placement's rotate); evaluation and reports play the routes as they are",
    )

    @property
    def num_channels(self) -> int:
        return 2 if self.blind else 3

    def observed_as(self, agent: TrackingConfig) -> TrackingConfig:
        """This task (horizon, P_T, speeds) with ``agent``'s observation (``OBSERVATION_FIELDS``): what a tracking
        agent trained with ``agent`` sees when it plays this task."""
        return self.model_copy(update={k: getattr(agent, k) for k in OBSERVATION_FIELDS})

    def canvas(self) -> CanvasSettings:
        """The canvas settings of the map set (``rl.world.maps.MapSet``) this task's routes are laid out on."""
        shared = {"p_t_db", "map_error", *OBSERVATION_FIELDS} - {"age_clip_s"}
        return CanvasSettings(**self.model_dump(include=shared), rotate=False)


class MotionModel(Contract):
    """The user's speeds [m/s] and the prior probability of each. The defaults are ``fit_motion`` of the tracking
    task's training cities, trk-000 ... trk-003 (``tests/test_tracking.py`` holds them to it)."""

    speeds_mps: tuple[float, ...] = Field(default=(1.4, 10.0), min_length=1, description="The speed classes [m/s]")
    weights: tuple[float, ...] = Field(default=(0.5, 0.5), min_length=1, description="Prior probability of each")

    @model_validator(mode="after")
    def _check(self) -> MotionModel:
        if len(self.speeds_mps) != len(self.weights) or min(self.speeds_mps) <= 0 or min(self.weights) <= 0:
            raise ValueError("one positive weight per positive speed")
        if abs(sum(self.weights) - 1) > 1e-6:
            raise ValueError(f"the weights sum to {sum(self.weights):g}, not 1")
        return self


def tracking_search() -> SearchConfig:
    """The tracking searcher's settings: the map searcher's with a distance scale of 192 cells (``reach_cells``; the
    placement searcher's is 12), so that a likely cell far away beats an unlikely one nearby: the user moves, and a
    cell near the UAV stays unlikely. Chosen on the validation cities etoile-val-routes and trk-val
    (experiments/log/tracking.md). Its belief product in bfloat16 (``SearchConfig.precision``: issue 90's
    validation comparison on the same cities, docs/benchmarks.md)."""
    return SearchConfig(reach_cells=192.0, precision="bfloat16")


class TrackingTask(TrackingConfig, RunTask):
    """A run's task when it is tracking: the tracking task's settings (``TrackingConfig``); the network has stay as a
    fifth action, and placement's revisit penalties are off (a moving user brings the UAV back to cells it stood in)."""

    kind: Literal["tracking"] = "tracking"

    actions: ClassVar[int] = len(TRACK_MOVES)
    prefix: ClassVar[str | None] = "tracking"
    tag: ClassVar[str] = "tracking"
    revisits: ClassVar[bool] = False
    env_p_t: ClassVar[bool] = False
    ensembles: ClassVar[bool] = False

    def playing(self, run: RunSettings) -> TrackingConfig:
        """The tracking task as the run plays it (blind as the agent is)."""
        return TrackingConfig(**self.model_dump(exclude={"kind"}) | {"blind": run.agent == "blind"})

"""Placement's settings: the environment of the paper's task (``EnvConfig``, the paper's values as defaults), which
the tracking and fleet tasks build on. Light to import: pydantic only."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from uavplace.rl.tasks.entry import RunTask
from uavplace.rl.world.settings import CanvasSettings


class EnvConfig(CanvasSettings):
    """Everything that defines the UAV placement problem (docs/method.md: Problem, Observation, Reward): the canvas and
    observation settings every task shares (``CanvasSettings``), the step budget, the reward and the extra channels."""

    t_max: int = Field(
        default=800, ge=1, description="Step budget: the episode is truncated after t_max moves (paper: 800 train, 500 test)"
    )
    c_e: float = Field(default=1.2, description="Exploration bonus c_E added to the reward for a never-visited cell")
    success_bonus: float = Field(
        default=0.0, description="Reward added on reaching P_T (the paper: 0); makes ending the search worth more than wandering"
    )
    step_cost: float = Field(default=0.0, ge=0, description="Subtracted from the reward on every move [dB]")
    revisit_cost: float = Field(
        default=0.0,
        ge=0,
        description="Subtracted from the reward once per earlier visit of the cell a move leads to (0: the paper's "
        "reward, where a revisit only forgoes c_E)",
    )
    shaping: float = Field(
        default=0.0,
        ge=0,
        description="Potential-based shaping (training only): adds shaping * (gamma * phi' - phi), phi = -(genie moves "
        "to a target); the policy still acts on the observation alone",
    )
    shaping_gamma: float = Field(default=1.0, gt=0, le=1, description="The gamma of the shaping term (the learner's discount)")
    reward_scale: float = Field(default=1.0, gt=0, description="Every reward (all terms) is multiplied by this")
    fleet_channel: bool = Field(
        default=False,
        description="Fleet task only: add a channel, before the visited channel, of the fleet's other UAVs (p_h_db where "
        "one stands, 0 elsewhere), so that an agent on every UAV sees where the others are (rl/tasks/fleet/learner.py)",
    )
    visited_channel: bool = Field(
        default=False,
        description="Add a channel of the visited cells (value p_h_db where visited, 0 elsewhere) before the SINR memory, "
        "so that pooling keeps the route visible",
    )
    homing_channel: bool = Field(
        default=False,
        description="Add a channel, before the SINR memory, of the best SINR measured so far in the episode less "
        "homing_slope_db per cell of distance from the cell where it was measured (clipped at p_l_db): a cone whose "
        "slope points back to the best cell even when that cell lies beyond the window",
    )
    homing_slope_db: float = Field(
        default=1.0, gt=0, description="The homing channel's fall per cell of Euclidean distance [dB / cell]"
    )
    belief_channel: bool = Field(
        default=False,
        description="Add a channel, after the homing channel and before the SINR memory, of the map searcher's "
        "posterior probability that each cell reaches P_T [%] (0 where the UAV may not go), from its belief over the "
        "user's position given the episode's measurements and the predicted maps of belief_predictor (rl/belief/, "
        "BeliefTracker): the hybrid learner of docs/searcher.md",
    )
    belief_predictor: str | None = Field(
        default=None,
        description="The belief channel's predictor: the physics tier's constants (a JSON file) or a learned tier (a "
        "folder); None: the map searcher's (data/agents/searcher/unet). Its predicted maps are kept beside the bundles "
        "(.predictions)",
    )
    belief_precision: Literal["float32", "bfloat16"] = Field(
        default="bfloat16",
        description="The belief channel's product (the belief times every candidate's cover): 'bfloat16' rounds both "
        "to bfloat16 and the channel to it (within 1.2 % of its value, 0.15 % typically; 2 to 3 x faster on a CPU "
        "with bfloat16 units, docs/benchmarks.md), 'float32' as the searcher computes it",
    )

    @property
    def num_channels(self) -> int:
        extra = int(self.fleet_channel) + int(self.visited_channel) + int(self.homing_channel) + int(self.belief_channel)
        return (1 if self.blind else 2) + self.num_context + extra

    @property
    def fleet_index(self) -> int:
        """The fleet channel's index in an observation (``fleet_channel``): before the visited, homing, belief and SINR
        memory channels."""
        if not self.fleet_channel:
            raise ValueError("no fleet channel: EnvConfig.fleet_channel is off")
        return self.num_channels - 2 - int(self.visited_channel) - int(self.homing_channel) - int(self.belief_channel)


class PlacementTask(RunTask):
    """A run's task when it is placement: no settings beyond the run's environment (``DQNConfig.env``)."""

    kind: Literal["placement"] = "placement"

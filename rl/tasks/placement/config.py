"""Placement's settings: the environment of the paper's task (``EnvConfig``, the paper's values as defaults), which
the tracking and fleet tasks build on. Light to import: pydantic only."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from uavplace.rl.config import TaskSettings
from uavplace.schemas.bundle import UserSplit as Split


class EnvConfig(TaskSettings):
    """Everything that defines the UAV placement problem (docs/method.md: Problem, Observation, Reward)."""

    t_max: int = Field(
        default=800, ge=1, description="Step budget: the episode is truncated after t_max moves (paper: 800 train, 500 test)"
    )
    c_e: float = Field(default=1.2, description="Exploration bonus c_E added to the reward for a never-visited cell")
    success_bonus: float = Field(
        default=0.0, description="Reward added on reaching P_T (the paper: 0); makes ending the search worth more than wandering"
    )
    p_h_db: float = Field(default=50.0, description="P_H: SINR memory value of unvisited cells [dB]")
    p_l_db: float = Field(
        default=-150.0, description="P_L: SINR memory value of blocked cells and of cells beyond the map edge [dB]"
    )
    window: int = Field(
        default=61, ge=3, le=1001, description="Observation side in cells (odd), centred on the UAV; at most 1001"
    )
    blind: bool = Field(
        default=False, description="Blind variant: no height channel; blocked cells shown as P_H in the SINR memory"
    )
    rotate: bool = Field(
        default=False, description="Turn each episode's maps by a random symmetry of the square (training; see symmetries)"
    )
    symmetries: Literal[4, 8] = Field(
        default=4, description="Symmetries drawn when rotating: 4 (the quarter turns) or 8 (the quarter turns and their mirrors)"
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
        "user's position given the episode's measurements and the predicted maps of belief_predictor (rl/belief.py, "
        "BeliefTracker): the hybrid learner of docs/searcher.md",
    )
    belief_predictor: str | None = Field(
        default=None,
        description="The belief channel's predictor: the physics tier's constants (a JSON file) or a learned tier (a "
        "folder); None: the map searcher's (data/agents/searcher/unet). Its predicted maps are kept beside the bundles "
        "(.predictions)",
    )
    context_zoom: int = Field(
        default=0,
        ge=0,
        le=64,
        description="Context channels (0: none; at most 64): the whole window again at 1/context_zoom resolution (blocks of "
        "context_zoom x context_zoom cells, so it covers context_zoom times the span): the blocks' mean height and the "
        "best SINR measured in each block (P_H where none is visited, P_L where the block is all blocked or beyond the "
        "edge); blind: the SINR one only. They sit after the height channel, before the visited and SINR memory channels",
    )
    far_starts: float = Field(
        default=0.0,
        ge=0,
        le=1,
        description="Curriculum: share of starts drawn as the farther (genie moves) of two uniform draws",
    )
    city_weights: dict[str, float] = Field(
        default_factory=dict,
        description="Training only: how often each city's users are drawn, relative to the others, by city or corpus "
        "name (oldtown: every oldtown-NNN); an exact city name wins over its corpus, unnamed cities weigh 1 ({}: every "
        "user alike, the paper's)",
    )
    edge_height_m: float = Field(
        default=100.0, description="Height channel value beyond the map edge (blocked) [m above the UAV]"
    )
    height_clip_m: float = Field(default=100.0, gt=0, description="Height channel clipped to +/- this [m]")
    start: Literal["legal_live_below_target"] = Field(
        default="legal_live_below_target",
        description="Start cells: not blocked, not dead, SINR below P_T, with a target reachable over legal cells "
        "(a start at the target is no search; one in a closed courtyard can never succeed)",
    )
    split: Split | None = Field(default=None, description="Users of this split only (bundles' users.parquet); None: all users")

    @field_validator("context_zoom")
    @classmethod
    def _zoom_is_a_block(cls, zoom: int) -> int:
        if zoom == 1:
            raise ValueError("context_zoom 1 repeats the window; use 0 (no context) or a block side >= 2")
        return zoom

    @field_validator("city_weights")
    @classmethod
    def _weights_are_positive(cls, weights: dict[str, float]) -> dict[str, float]:
        bad = {name: w for name, w in weights.items() if not w > 0 or w == float("inf")}
        if bad:
            raise ValueError(f"city weights must be positive and finite: {bad}")
        return weights

    @property
    def num_context(self) -> int:
        """How many context channels (``context_zoom``) the observation has."""
        return 0 if self.context_zoom == 0 else 1 if self.blind else 2

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

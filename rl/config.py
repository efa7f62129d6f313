"""The settings of rl/, each declared once as a pydantic model (the commands' options derive from their fields,
``infra.options``): the environment's (``EnvConfig``, the paper's values as defaults), the evaluation protocol's
(``EpisodeSettings``), the map searcher's (``SearchConfig``), the learned predictor's (``UNetConfig``) and where the
shipped predictor lives. Light to import: pydantic only, read by the command line before any heavy work."""

from __future__ import annotations

from typing import Literal

from pydantic import ConfigDict, Field, field_validator

from uavplace.infra.files import shipped
from uavplace.schemas.base import MAX_SEED, Contract
from uavplace.schemas.constants import P_T_DB

Split = Literal["train", "val", "test"]

#: Where the shipped physics tier's constants live (in the project, wherever a command runs).
DEFAULT_CONSTANTS = shipped("data/agents/searcher/predictor.json")
#: The shipped predictor the searcher uses: the learned tier (chosen on the validation cities, docs/searcher.md).
DEFAULT_PREDICTOR = shipped("data/agents/searcher/unet")


class EnvConfig(Contract):
    """Everything that defines the UAV placement problem (docs/method.md: Problem, Observation, Reward)."""

    model_config = ConfigDict(allow_inf_nan=False)  # a NaN target or reward would train and report without a word

    p_t_db: float = Field(default=P_T_DB, description="SINR target P_T: the episode ends (terminated) when reached [dB]")
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
        extra = int(self.visited_channel) + int(self.homing_channel) + int(self.belief_channel)
        return (1 if self.blind else 2) + self.num_context + extra


class SearchConfig(Contract):
    """The searcher's settings (chosen on validation cities)."""

    stride: int = Field(default=2, ge=1, le=16, description="Candidate user cells on a lattice of this many cells")
    temper: float = Field(default=0.5, gt=0, le=1, description="Exponent of each measurement's likelihood")
    reach_cells: float = Field(default=12.0, gt=0, description="Distance scale of a cell's discount [cells]")
    discount: Literal["exp", "hyperbolic"] = Field(
        default="hyperbolic",
        description="A cell's score is its posterior probability of reaching P_T times exp(-d / reach_cells) ('exp') "
        "or 1 / (1 + d / reach_cells) ('hyperbolic': a likely cell far away can beat an unlikely one nearby)",
    )
    buildings: bool = Field(default=True, description="Predict with the city's buildings (False: open ground, the ablation)")
    min_sigma_db: float = Field(default=3.0, gt=0, description="Least spread of the likelihood [dB]")
    outlier: float = Field(
        default=0.1,
        ge=0,
        lt=1,
        description="Share of the likelihood that is flat: one measurement the predictor "
        "got wrong lowers a candidate, never rules it out",
    )
    planner: Literal["cover", "info", "lookahead"] = Field(
        default="cover",
        description="cover: move toward the unvisited cell of best discounted posterior probability of reaching P_T; "
        "info: add to that probability info_weight times the information [bits] a measurement at the cell gives "
        "about the user's cell (mutual information), for the cells within info_radius moves; lookahead: take the "
        "move whose measurement, over its possible outcomes, leaves the best expected discounted score (1 where it "
        "reaches P_T) among the lookahead_targets cells the cover planner scores best",
    )
    lookahead_targets: int = Field(default=64, ge=1, le=4096, description="lookahead: target cells it weighs")
    info_weight: float = Field(default=0.1, ge=0, description="info: the worth of one bit, in probability of reaching P_T")
    info_radius: int = Field(default=3, ge=1, le=32, description="info: cells within this many moves get the term")
    info_bin_db: float = Field(default=4.0, gt=0, le=40, description="info: width of the SINR bins a measurement falls in")


class EpisodeSettings(Contract):
    """The evaluation protocol: which episodes every method plays (``uavrl baselines``, ``uavrl report``; their
    options derive from these fields, ``infra.options``)."""

    model_config = ConfigDict(allow_inf_nan=False)

    episodes: int = Field(
        default=1000, ge=1, description="Episodes, the same for every method.", json_schema_extra={"limit": "episodes"}
    )
    t_max: int = Field(
        default=500, ge=1, description="Step budget per episode (paper: 500 at test).", json_schema_extra={"limit": "t_max"}
    )
    p_t_db: float = Field(default=P_T_DB, ge=-100, le=100, description="SINR target P_T [dB].")
    split: Split | None = Field(default=None, description="Users of this split only (default: all).")
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="Seed of the episodes and of every random move.")


class UNetConfig(Contract):
    """The learned radio-map predictor's network and training settings (``rl.learned``; `uavrl train-predictor`'s
    options derive from them)."""

    widths: list[int] = Field(
        default=[16, 32, 64, 64],
        min_length=1,
        max_length=5,
        description="Channels per U-Net level, comma-separated (1 to 5 levels).",
        json_schema_extra={"type": "list"},
    )
    crop: int = Field(default=64, ge=16, le=512, description="Training crops [cells] (a multiple of 2^(levels-1))")
    batch: int = Field(default=16, ge=1, le=1024, description="Crops per step.")
    steps: int = Field(default=2000, ge=1, le=1_000_000, description="Gradient steps.")
    lr: float = Field(default=2e-3, gt=0, le=1, description="Adam's learning rate (cosine decay to 1/20 of it)")
    dead_weight: float = Field(default=1.0, ge=0, description="Weight of the dead-cell cross-entropy in the loss")
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="Seed of the initial weights and the crops.")
    threads: int = Field(default=2, ge=1, le=256, description="torch CPU threads.")
    calibration_share: float = Field(
        default=0.1,
        ge=0,
        lt=1,
        description="Share of the training users held out of the gradient steps to calibrate the dead probability "
        "(Platt scaling of its logit, fitted on their legal cells); none when it rounds down to no user",
    )

    @field_validator("widths", mode="before")
    @classmethod
    def _levels(cls, value: object) -> object:
        if isinstance(value, str):  # the option's word: 16,32,64
            try:
                return [int(w) for w in value.split(",")]
            except ValueError:
                raise ValueError(f"{value!r}: expected 1 to 5 positive integers, e.g. 16,32,64") from None
        return value

    @field_validator("widths")
    @classmethod
    def _positive(cls, value: list[int]) -> list[int]:
        if any(w < 1 for w in value):
            raise ValueError(f"{value}: expected 1 to 5 positive integers, e.g. 16,32,64")
        return value

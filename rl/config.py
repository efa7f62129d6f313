"""The settings of rl/, each declared once as a pydantic model (the commands' options derive from their fields,
``infra.options``) that every task shares: the base of each task's settings (``TaskSettings``: P_T and its rule),
the evaluation protocol's (``EpisodeSettings``), the map searcher's (``SearchConfig``), the learned predictor's
(``UNetConfig``) and where the shipped predictor lives; placement's environment is
``rl.tasks.placement.config.EnvConfig``. Light to import (pydantic and numpy), read by the command line before any
heavy work."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import ConfigDict, Field, field_validator

from uavplace.infra.files import shipped
from uavplace.schemas.base import MAX_SEED, Contract
from uavplace.schemas.bundle import UserSplit as Split
from uavplace.schemas.constants import P_T_DB, reaches_target

#: Where the shipped physics tier's constants live (in the project, wherever a command runs).
DEFAULT_CONSTANTS = shipped("data/agents/searcher/predictor.json")
#: The shipped predictor the searcher uses: the learned tier (chosen on the validation cities, docs/predictor.md).
DEFAULT_PREDICTOR = shipped("data/agents/searcher/unet")


class MeasurementSettings(Contract):
    """What the UAV reads at a cell (``rl.world.measurement``): the true SINR plus an error, i.i.d. Gaussian in dB
    of spread ``sigma_db``, and a shadowing field correlated in space (spread ``shadow_sigma_db``, correlation
    ``exp(-d / shadow_distance_m)``), one field per episode and user. All 0: the paper's exact measurement. Success is
    judged on the true SINR; only what policies read changes."""

    model_config = ConfigDict(allow_inf_nan=False)

    sigma_db: float = Field(default=0.0, ge=0, le=30, description="Spread of the i.i.d. Gaussian measurement error [dB]")
    shadow_sigma_db: float = Field(default=0.0, ge=0, le=30, description="Spread of the correlated shadowing [dB]")
    shadow_distance_m: float = Field(
        default=20.0, gt=0, le=10_000, description="Distance at which the shadowing's correlation falls to 1/e [m]"
    )

    @property
    def exact(self) -> bool:
        """The paper's measurement: no error at all."""
        return self.sigma_db == 0 and self.shadow_sigma_db == 0


class MapErrorSettings(Contract):
    """How the UAV's 3D map differs from the traced city (``rl.world.maperror``): each building's height off by a
    Gaussian error, a share of the smallest buildings missing, the whole map shifted by a registration error in a
    random direction; drawn from ``seed`` and the city's public map. What policies and their predictors read of the
    buildings (the height channel, the searcher's predicted maps) comes from this map; the cells the UAV may fly in
    (it senses obstacles), the users' maps, the genie and the oracles stay the traced city's. All 0: the paper's
    exact map."""

    model_config = ConfigDict(allow_inf_nan=False)

    height_sigma_m: float = Field(default=0.0, ge=0, le=50, description="Spread of each building's height error [m]")
    missing_share: float = Field(
        default=0.0, ge=0, le=1, description="Share of the small buildings (under missing_area_m2) missing from the map"
    )
    missing_area_m2: float = Field(default=100.0, gt=0, le=1e6, description="A building under this footprint is small [m2]")
    shift_m: float = Field(default=0.0, ge=0, le=100, description="Registration error: the whole map shifted this far [m]")
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="Seed of the errors (with the city's public map)")

    @property
    def exact(self) -> bool:
        """The paper's map: the traced city's buildings as they are."""
        return self.height_sigma_m == 0 and self.missing_share == 0 and self.shift_m == 0


class TaskSettings(Contract):
    """What the settings of every task hold (placement's ``EnvConfig``, ``TrackingConfig``, ``FleetConfig``): the SINR
    target P_T and the rule that says which cells reach it (``schemas.constants.reaches_target``, its one home), what
    the UAV reads (``measurement``) and how its 3D map errs (``map_error``). Each
    task adds its step budget (placement's and the fleet's ``t_max``; tracking's ``horizon``, a fixed length: its
    episodes do not end at P_T) and its observation."""

    model_config = ConfigDict(allow_inf_nan=False)  # a NaN target would train and report without a word

    p_t_db: float = Field(
        default=P_T_DB,
        description="SINR target P_T [dB]: placement's episode ends when it is reached, a tracking step is covered and "
        "a fleet's user served at or above it",
    )

    measurement: MeasurementSettings = Field(
        default_factory=MeasurementSettings, description="What the UAV reads at a cell: the true SINR plus an error"
    )
    map_error: MapErrorSettings = Field(
        default_factory=MapErrorSettings, description="How the UAV's 3D map differs from the traced city"
    )

    def reaches(self, sinr_db: np.ndarray | float, dead: np.ndarray | None = None, legal: np.ndarray | None = None) -> np.ndarray:
        """Which cells (or measurements) reach this task's P_T (``reaches_target``)."""
        return reaches_target(sinr_db, self.p_t_db, dead, legal)


class SearchConfig(Contract):
    """The searcher's settings (chosen on validation cities)."""

    model_config = ConfigDict(allow_inf_nan=False)  # reach_cells=Infinity would play, and be recorded as null

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
    measurement_sigma_db: float = Field(
        default=0.0,
        ge=0,
        le=30,
        description="The spread of the UAV's measurement error it assumes [dB] (declared, never read from the world): "
        "added in quadrature to the predictor's in the likelihood of a measurement",
    )
    outlier: float = Field(
        default=0.1,
        ge=0,
        lt=1,
        description="Share of the likelihood that is flat: one measurement the predictor "
        "got wrong lowers a candidate, never rules it out",
    )
    precision: Literal["belief", "bfloat16"] = Field(
        default="belief",
        description="The planner's belief product (each row's belief times every candidate's cover, its main cost): "
        "'belief' in the belief's own precision (float32; float64 for the tracking searcher), 'bfloat16' both "
        "rounded to bfloat16 and the sums too (within 1.2 % of each cell's value; 2 to 4 x faster on a CPU with "
        "bfloat16 units). The tracking and fleet searchers play bfloat16, the placement searcher 'belief' (its "
        "ablation's ties move in bfloat16: docs/benchmarks.md)",
    )
    planner: Literal["cover", "info", "lookahead"] = Field(
        default="cover",
        description="cover: move toward the unvisited cell of best discounted posterior probability of reaching P_T; "
        "info: add to that probability info_weight times the information [bits] a measurement at the cell gives "
        "about the user's cell (mutual information), for the cells within info_radius moves; lookahead: take the "
        "move whose measurement, over its possible outcomes, leaves the best expected discounted score (1 where it "
        "reaches P_T) among the lookahead_targets cells the cover planner scores best. The fleet searcher reads "
        "info (each user's information, within info_radius moves of a UAV) and plans as cover otherwise",
    )
    fleet_plan: Literal["makespan", "product", "union"] = Field(
        default="union",
        description="The fleet searcher's score of an assignment of users to UAVs: 'makespan': the product of the "
        "UAVs' probabilities of serving their users at their cells times the discount of the longest of their paths "
        "(the episode ends when the last UAV arrives); 'product': the product of each UAV's best probability times "
        "the discount of its own path; 'union': the makespan plan's cells, then each UAV's cell moved in turn while it "
        "raises the product over users of the probability that some UAV serves the user times the discount of the "
        "longest path (a UAV without users goes where it helps most)",
    )
    error_share: float = Field(
        default=0.0,
        ge=0,
        lt=1,
        description="The correlation of the predictor's errors at two cells a cell apart, before its decay with "
        "distance (error_range_cells): the cover planner moves each candidate's predicted chance of reaching P_T at "
        "the cells within error_reach of the cells measured by what those measurements say of its map's error "
        "there (kriging, rl.belief.BeliefModel.kriged_cover); 0: every cell's chance as predicted. The placement "
        "searcher's: the tracking and fleet searchers plan as without it",
    )
    kriging: Literal["planner", "belief", "both"] = Field(
        default="planner",
        description="What the errors' correlation (error_share > 0) moves: 'planner': each candidate's chance of "
        "reaching P_T near the cells measured; 'belief': the likelihood of a measurement is its probability given "
        "the measurements before it, so a candidate is not charged again for an error its map made nearby; 'both'",
    )
    error_range_cells: float = Field(
        default=9.8,
        gt=0,
        le=256,
        description="The errors' correlation decays as exp(-d / this) [cells] (fitted with error_share 0.8 on the "
        "training cities: experiments/error_correlation.py)",
    )
    error_reach: int = Field(default=12, ge=1, le=64, description="Cells within this many cells of a measured cell are kriged")
    error_memory: int = Field(default=96, ge=1, le=1024, description="The kriging reads the most recent this many measured cells")
    lookahead_targets: int = Field(default=64, ge=1, le=4096, description="lookahead: target cells it weighs")
    info_weight: float = Field(default=0.1, ge=0, description="info: the worth of one bit, in probability of reaching P_T")
    info_radius: int = Field(default=3, ge=1, le=32, description="info: cells within this many moves get the term")
    info_bin_db: float = Field(default=4.0, gt=0, le=40, description="info: width of the SINR bins a measurement falls in")

    @property
    def kriged_planner(self) -> bool:
        """Whether the cover planner krigs the predictor's errors (``error_share``, ``kriging``)."""
        return self.error_share > 0 and self.kriging != "belief"

    @property
    def kriged_belief(self) -> bool:
        """Whether the belief takes each measurement given those before it (``error_share``, ``kriging``)."""
        return self.error_share > 0 and self.kriging != "planner"


#: The settings only the placement searcher's own planner reads (its kriging and lookahead): the tracking and fleet
#: searchers plan without them.
PLACEMENT_PLAN_SETTINGS = frozenset(
    {"error_share", "kriging", "error_range_cells", "error_reach", "error_memory", "lookahead_targets"}
)


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
    """The learned radio-map predictor's network and training settings (``rl.predictor.learned``; `uavrl train-predictor`'s
    options derive from them)."""

    widths: list[Annotated[int, Field(ge=1, le=1024)]] = Field(
        default=[16, 32, 64, 64],
        min_length=1,
        max_length=5,
        description="Channels per U-Net level, comma-separated (1 to 5 levels of 1 to 1024 channels).",
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

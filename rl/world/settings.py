"""The settings every task's observation shares, declared once: ``ObservationSettings`` (the window and the values
it shows where nothing was measured, of a blocked cell and beyond the edge) and ``CanvasSettings``, what the map set
(``rl.world.maps.MapSet``) reads to lay the bundles out on canvases (symmetries, the context channels, which users,
how starts are drawn). Placement's ``EnvConfig`` extends ``CanvasSettings``; the tracking and fleet settings extend
``ObservationSettings`` and make a canvas's settings for the map set from it. Light to import: pydantic only."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from uavplace.rl.config import TaskSettings
from uavplace.schemas.bundle import UserSplit as Split


class ObservationSettings(TaskSettings):
    """What every task's observation window shows: its side, and the values of cells not measured, blocked or beyond
    the map's edge."""

    window: int = Field(
        default=61, ge=3, le=1001, description="Observation side in cells (odd), centred on the UAV; at most 1001"
    )
    p_h_db: float = Field(default=50.0, description="P_H: SINR memory value of unvisited cells [dB]")
    p_l_db: float = Field(
        default=-150.0, description="P_L: SINR memory value of blocked cells and of cells beyond the map edge [dB]"
    )
    edge_height_m: float = Field(
        default=100.0, description="Height channel value beyond the map edge (blocked) [m above the UAV]"
    )
    height_clip_m: float = Field(default=100.0, gt=0, description="Height channel clipped to +/- this [m]")


class CanvasSettings(ObservationSettings):
    """What the map set reads: the observation's values, the symmetries, the context channels, which users are played
    and how starts are drawn."""

    blind: bool = Field(
        default=False, description="Blind variant: no height channel; blocked cells shown as P_H in the SINR memory"
    )
    rotate: bool = Field(
        default=False, description="Turn each episode's maps by a random symmetry of the square (training; see symmetries)"
    )
    symmetries: Literal[4, 8] = Field(
        default=4, description="Symmetries drawn when rotating: 4 (the quarter turns) or 8 (the quarter turns and their mirrors)"
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

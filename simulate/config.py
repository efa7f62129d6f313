"""``Simulation``: every setting of one ``uavdata simulate`` call, declared once; the command's options derive from its
fields (``infra.options``) and the records of ``simulation.json`` from the model (``Simulation.city``,
``Simulation.raytrace``).

A field without an upper bound is bounded by the resource limit its ``limit`` names (``infra.limits.Limits``, raised
with ``--limit NAME=VALUE``): what the machine can afford, not what physics allows. The checks that need several
settings at once and the limits of what they make (grid cells, user-cells, route points) are
``simulate.sources.check_simulation``'s, run before any geometry is loaded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from pydantic import Field, field_validator

from uavplace.infra.device import DEVICE_HELP, Device
from uavplace.infra.files import check_name
from uavplace.schemas.base import MAX_SEED, Contract, InputError
from uavplace.schemas.constants import ALTITUDE_M, CARRIER_HZ, GRID_M, TX_POWER_DBM
from uavplace.simulate.raytrace import RayTraceConfig, mitsuba_variant
from uavplace.simulate.routes import KINDS
from uavplace.simulate.scene import MATERIALS, parse_mix

_METRES = {"type": "metres"}
_LIST = {"type": "list"}
_DEFAULT = RayTraceConfig()
#: Option names that are not ``--field-name``.
OPTION_NAMES = {
    "num_users": "--users",
    "users_m": "--user",
    "route_length_m": "--route-length",
    "grid_m": "--grid",
    "altitude_m": "--alt",
    "extent_m": "--extent",
    "crop_m": "--crop",
    "surround_m": "--surround",
    "frequency_hz": "--freq",
    "gap_fill_reach_m": "--gap-fill-reach",
    "gap_fill_decay_db_per_m": "--gap-fill-decay",
}


def _items(value: object) -> object:
    """A comma-separated option (``a,b``; ``none`` for none) as the tuple of its items."""
    if isinstance(value, str):
        return () if value.strip() == "none" else tuple(v.strip() for v in value.split(","))
    return value


class Simulation(Contract):
    """One ``uavdata simulate`` call: the city, its users and routes, the receiver grid, the ray tracer and the fill
    of what it misses."""

    name: str = Field(
        description="City name: the exports go to OUT/<name>/; with several cities, OUT/<name>-000/, OUT/<name>-001/, ...",
    )
    count: int = Field(
        default=1,
        ge=1,
        description="Cities to draw from one procedural SOURCE, seeds SEED, SEED+1, ... (a corpus).",
        json_schema_extra={"limit": "cities"},
    )
    first: int = Field(
        default=0,
        ge=0,
        description="With --count: the corpus's first city index, NAME-FIRST at seed SEED+FIRST (continue a corpus on a "
        "machine that lacks the earlier cities' exports; a city's name and seed do not depend on where a call starts).",
        json_schema_extra={"limit": "cities"},
    )
    num_users: int = Field(
        default=27,
        ge=1,
        description="Users (ground transmitters at 1.5 m) sampled uniformly over open ground.",
        json_schema_extra={"limit": "users"},
    )
    users_m: tuple[tuple[float, float], ...] = Field(
        default=(), description="Place a user at X,Y instead of sampling (repeatable; overrides --users)."
    )
    routes: int = Field(
        default=0,
        ge=0,
        description="User routes for the tracking task: paths along open ground (clear of every building by 0.25 m or "
        "more), sampled every <= 2 m, every point traced as a user; written as the .txrx points set 'Route' and "
        "<name>.routes.csv (simulate/routes.py).",
        json_schema_extra={"limit": "routes"},
    )
    route_length_m: float = Field(
        default=120.0, ge=4.0, description="Length of each route.", json_schema_extra=_METRES | {"limit": "route_length_m"}
    )
    route_kinds: tuple[str, ...] = Field(
        default=("pedestrian", "vehicle"),
        min_length=1,
        description="Kinds of the routes, in turn: pedestrian (1.4 m/s) and vehicle (10 m/s); a kind sets the user's speed.",
        json_schema_extra=_LIST,
    )
    grid_m: float = Field(default=GRID_M, ge=0.5, le=100.0, description="Receiver grid spacing.", json_schema_extra=_METRES)
    altitude_m: float = Field(
        default=ALTITUDE_M,
        ge=2.0,
        le=1000.0,
        description="Receiver grid height (the UAV altitude), above the users' 1.5 m.",
        json_schema_extra=_METRES,
    )
    extent_m: tuple[float, float, float, float] | None = Field(
        default=None, description="Grid extent XMIN,YMIN,XMAX,YMAX [m] (default: the city's bounds)."
    )
    crop_m: tuple[float, float, float, float] | None = Field(
        default=None,
        description="Real geometry only: keep the buildings inside XMIN,YMIN,XMAX,YMAX [m] (clipped; counted) and make "
        "that the city.",
    )
    surround_m: float = Field(
        default=0.0,
        ge=0.0,
        le=2000.0,
        description="With --crop: also trace the buildings within this distance around the crop (clipped there), "
        "whose shadows and reflections reach the crop's cells; the city (its grid, users and written buildings) "
        "stays the crop. 0: the crop's buildings only.",
        json_schema_extra=_METRES,
    )
    frequency_hz: float = Field(default=CARRIER_HZ, ge=1e8, le=1e11, description="Carrier frequency [Hz].")
    tx_dbm: float = Field(default=TX_POWER_DBM, ge=-50.0, le=70.0, description="User transmit power [dBm].")
    samples: float = Field(
        default=float(_DEFAULT.samples_per_tx),
        ge=1e3,
        description="Rays per user (Sionna samples_per_tx).",
        json_schema_extra={"limit": "samples"},
    )
    depth: int = Field(default=_DEFAULT.max_depth, ge=0, le=10, description="Maximum interactions per path.")
    solver: Literal["radio-map", "paths"] = Field(
        default=_DEFAULT.solver,
        description="radio-map: Sionna's radio map of every cell, the gaps filled by --gap-fill-method. paths: exact "
        "paths (Sionna's PathSolver, every path found, as InSite computes them) at every open cell, nothing filled, "
        "--samples rays per user for each cell (2e6 is the fidelity reference's): about a second a cell and user on 2 "
        "cores, so for small cities (simulate/raytrace.py, exact_path_maps; docs/fidelity.md, the exact-path twin).",
    )
    diffraction: bool = Field(
        default=_DEFAULT.diffraction, description="Edge diffraction (--no-diffraction: faster, more dead cells)."
    )
    gap_fill: tuple[int, ...] = Field(
        default=(),
        description="Coarser maps (cell x factor, same samples, e.g. 4,16) traced as well, which the smooth and parent "
        "methods take their levels from; 'none' for the geodesic method.",
        json_schema_extra=_LIST,
    )
    gap_fill_method: Literal["geodesic", "smooth", "parent"] = Field(
        default=_DEFAULT.gap_fill_method,
        description="How cells no ray hit are filled. geodesic: the exact straight path from the user through the walls "
        "it crosses (simulate/transmission.py; none beyond --depth walls), then a walk of --gap-fill-reach metres from "
        "the hit cells through open ground, losing --gap-fill-decay dB per metre; the rest stays unreached. The "
        "earlier fills from --gap-fill's coarse maps, which leave the coarse cells' lattice in the maps: smooth (the "
        "coarse level, the variation of the nearest hit cells) and parent (the coarse cell's mean, copied).",
    )
    gap_fill_reach_m: float = Field(
        default=_DEFAULT.gap_fill_reach_m,
        ge=0.0,
        le=400.0,
        description="geodesic: how far [m] from a hit cell the walk goes (0: direct paths only).",
    )
    gap_fill_decay_db_per_m: float = Field(
        default=_DEFAULT.gap_fill_decay_db_per_m, ge=0.0, le=100.0, description="geodesic: loss of the walk [dB per metre]."
    )
    gap_fill_walk: Literal["euclidean", "4-neighbour"] = Field(
        default=_DEFAULT.gap_fill_walk,
        description="geodesic: how the walk measures its reach. euclidean: the shortest way through open ground in "
        "steps of 1, sqrt 2 and sqrt 5 cells, so what it lights follows the streets; 4-neighbour: steps along the axes "
        "only (a lit patch is a diamond; the fill of the cities simulated before this option).",
    )
    complete_missed: bool = Field(
        default=False,
        description="Trace exact paths (Sionna's PathSolver, every path found) at every open cell the radio map missed, "
        "instead of filling them: each user's missed cells a Ray task (--ray-address; --cpus-per-city CPUs each; on a "
        "GPU where Mitsuba finds one), each user's result kept in --trace-cache so that a stopped run resumes per "
        "user. About 0.4 s a cell and user at 2e6 rays on 2 cores (docs/fidelity.md, 'Exact paths for the missed "
        "cells').",
    )
    complete_samples: float = Field(
        default=2e6,
        ge=1e3,
        description="--complete-missed: PathSolver's rays per user for each missed cell (2e6: the exact-path reference's).",
        json_schema_extra={"limit": "samples"},
    )
    materials: tuple[str, ...] = Field(
        default=("concrete",),
        min_length=1,
        description="The buildings' radio materials: one ITU-R P.2040 class for all, or a mix CLASS=SHARE,... whose "
        "shares of the buildings sum to 1 (e.g. concrete=0.4,brick=0.3,glass=0.2,metal=0.1), dealt to the buildings by "
        "--seed; classes: " + ", ".join(MATERIALS) + " (simulate/scene.py). The mapping goes to simulation.json.",
        json_schema_extra=_LIST,
    )
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="Seed of the city generator, the users and the ray sampler.")
    device: Device = Field(
        default="auto",
        description=f"Where the rays are traced (Mitsuba's CUDA variant on a GPU, LLVM on the CPU): {DEVICE_HELP}. The "
        "two may trace other rays: the variant is recorded when it is CUDA's, and a trace cache entry is its own.",
    )

    @field_validator("name")
    @classmethod
    def _safe(cls, value: str) -> str:
        try:
            return check_name(value, "city name")
        except InputError as err:
            raise ValueError(str(err)) from None

    @field_validator("route_kinds", "gap_fill", "materials", mode="before")
    @classmethod
    def _split(cls, value: object) -> object:
        return _items(value)

    @field_validator("extent_m", "crop_m", mode="before")
    @classmethod
    def _box(cls, value: object) -> object:
        if isinstance(value, str):  # a word of the Bounds option (auto, receivers, buildings): no box
            raise ValueError("expected XMIN,YMIN,XMAX,YMAX")
        return value

    @field_validator("route_kinds")
    @classmethod
    def _kinds(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [k for k in value if k not in KINDS]
        if unknown:
            raise ValueError(f"{unknown}: expected kinds among {', '.join(KINDS)}")
        return value

    @field_validator("materials")
    @classmethod
    def _mix(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        return tuple(f"{name}={share:g}" for name, share in parse_mix(value))

    @field_validator("gap_fill")
    @classmethod
    def _factors(cls, value: tuple[int, ...]) -> tuple[int, ...]:
        if any(f < 2 for f in value):
            raise ValueError("factors must be >= 2")
        return value

    @field_validator("gap_fill_method")
    @classmethod
    def _levels(cls, value: str, info) -> str:  # noqa: ANN001 - pydantic's ValidationInfo
        if value != "geodesic" and not info.data.get("gap_fill"):
            raise ValueError(f"the {value} method takes its levels from coarse maps: add --gap-fill 4,16")
        return value

    def city(self, source: str) -> SimulationSpec:
        """The first (or only) city of the call: its source, name and the settings of what to trace."""
        return SimulationSpec(
            source=source,
            name=self.name,
            num_users=len(self.users_m) or self.num_users,
            grid_m=self.grid_m,
            altitude_m=self.altitude_m,
            tx_dbm=self.tx_dbm,
            seed=self.seed,
            extent_m=self.extent_m,
            users_m=self.users_m,
            crop_m=self.crop_m,
            surround_m=self.surround_m,
            routes=self.routes,
            route_length_m=self.route_length_m,
            route_kinds=self.route_kinds,
            materials=self.materials,
        )

    def raytrace(self) -> RayTraceConfig:
        """The ray tracer's and the fill's settings (the record of ``simulation.json``'s ``raytrace``)."""
        return RayTraceConfig(
            frequency_hz=self.frequency_hz,
            samples_per_tx=_count(self.samples),
            max_depth=self.depth,
            diffraction=self.diffraction,
            seed=self.seed,
            gap_fill_factors=self.gap_fill,
            gap_fill_method=self.gap_fill_method,
            gap_fill_reach_m=self.gap_fill_reach_m,
            gap_fill_decay_db_per_m=self.gap_fill_decay_db_per_m,
            gap_fill_walk=self.gap_fill_walk,
            complete_missed_samples=_count(self.complete_samples) if self.complete_missed else 0,
            solver=self.solver,
            variant=mitsuba_variant(self.device),
        )


def _default(name: str) -> object:
    """``Simulation``'s default of setting ``name``: a city's record (``SimulationSpec``) defaults as the call does."""
    return Simulation.model_fields[name].default


@dataclass(frozen=True)
class SimulationSpec:
    """One city of a ``uavdata simulate`` call as ``simulation.json`` records it (its ``spec``): the source, the name and
    what to trace, made by ``Simulation.city`` (a corpus's cities by ``simulate.corpus.corpus_specs``); its defaults
    are the call's."""

    source: str
    name: str
    num_users: int = _default("num_users")
    grid_m: float = _default("grid_m")
    altitude_m: float = _default("altitude_m")
    tx_dbm: float = _default("tx_dbm")
    seed: int = _default("seed")
    extent_m: tuple[float, float, float, float] | None = None
    users_m: tuple[tuple[float, float], ...] = ()
    crop_m: tuple[float, float, float, float] | None = None
    surround_m: float = 0.0  # with crop_m: the buildings this far around it are traced too, not written
    routes: int = _default("routes")  # user routes drawn on open ground, every point traced as a user (simulate.routes)
    route_length_m: float = _default("route_length_m")
    route_kinds: tuple[str, ...] = _default("route_kinds")
    materials: tuple[str, ...] = _default("materials")  # each building's class dealt in these shares (scene.parse_mix)


def _count(value: float) -> int | float:
    """Rays as the solver takes them: an integer (a value beyond any integer is left for the limit check to refuse)."""
    return int(value) if math.isfinite(value) else value

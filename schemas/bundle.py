"""Map bundles: what `uavdata build` writes and what `rl/` and `eval/` read.

A bundle is one city rasterised at one grid spacing and one UAV altitude:

``data/processed/<city>/<version>/``
    ``maps.npz``       the arrays (shapes below), ``cells.parquet`` (the same
    as a long table), ``users.parquet`` and ``manifest.json`` (``BundleManifest``).

Grid convention (shared by every array): cell ``(iy, ix)`` has its centre at
``x = x_min_m + (ix + 0.5) * spacing_m`` and ``y = y_min_m + (iy + 0.5) * spacing_m``;
arrays are indexed ``[..., iy, ix]`` (rows are y, like Sionna's radio maps),
``iy = 0`` is the southern edge. Heights are above the local ground (terrain
where the city has one), so ``height_rel_m = building height above ground -
altitude_m``; a cell with no building holds ``-altitude_m``.
"""

from __future__ import annotations

import re
from typing import Literal

import pyarrow as pa
from pydantic import ConfigDict, Field, field_validator, model_validator

from uavplace.schemas.base import MAX_SEED, NAME_PATTERN, SCHEMA_VERSION, Contract, repeated
from uavplace.schemas.constants import ALTITUDE_M, EMBEDDED_NOISE_DBM, P_T_DB
from uavplace.schemas.tables import FREQUENCY_RANGE_HZ, POWER_RANGE_DBM, RATIO_RANGE_DB, XY_RANGE_M, Z_RANGE_M, Column, TableSpec

SplitRole = Literal["train", "val", "test"]
UserSplit = Literal["train", "val", "test"]
BoundsMode = Literal["auto", "receivers", "buildings"]
SinrSource = Literal["export_sinr", "power", "path_gain", "path_loss"]

#: Files of a bundle, each hashed in the manifest.
BUNDLE_FILES = ("maps.npz", "cells.parquet", "users.parquet")
BUNDLE_MANIFEST = "manifest.json"

#: Arrays of ``maps.npz``: name -> (dtype, shape description).
MAP_ARRAYS: dict[str, tuple[str, str]] = {
    "x_m": ("float64", "[num_x] cell centre x [m]"),
    "y_m": ("float64", "[num_y] cell centre y [m]"),
    "height_rel_m": ("float32", "[num_y, num_x] building height above ground minus the altitude [m]"),
    "blocked": ("bool", "[num_y, num_x] a building at or above the altitude: the UAV may not enter"),
    "building_id": ("int32", "[num_y, num_x] tallest building covering the cell centre, -1 where none"),
    "sinr_db": ("float32", "[num_users, num_y, num_x] SINR [dB]; dead cells hold the manifest's SINR floor"),
    "dead": ("bool", "[num_users, num_y, num_x] no ray-traced path reached the cell (or no receiver sampled it)"),
    "num_rx": ("uint16", "[num_users, num_y, num_x] receivers of the export averaged into the cell"),
    "provenance": (
        "uint8",
        "[num_users, num_y, num_x] where the cell's value came from (schemas/provenance.py; dead "
        "exactly where 0 unreached or 7 no receiver, no receiver exactly where 7 or 8)",
    ),
}

#: Arrays of ``routes.npz`` (a bundle with routes): name -> (dtype, shape description). A route point's map is a
#: user's, made the same way from the export.
ROUTE_ARRAYS: dict[str, tuple[str, str]] = {
    "sinr_db": ("float32", "[num_route_points, num_y, num_x] SINR [dB] of the user at each route point"),
    "dead": ("bool", "[num_route_points, num_y, num_x] no ray-traced path reached the cell"),
    "provenance": ("uint8", "[num_route_points, num_y, num_x] where the cell's value came from (schemas/provenance.py)"),
}


class BuildConfig(Contract):
    """Every parameter of `uavdata build` for one city (saved in the bundle's manifest). Every number must be finite
    and within physical bounds (a noise of +inf dBm would make every cell dead without a word)."""

    model_config = ConfigDict(allow_inf_nan=False)

    grid_m: float = Field(gt=0, le=1000, description="Grid spacing of the maps (e.g. 4m)", json_schema_extra={"type": "metres"})
    altitude_m: float = Field(
        default=ALTITUDE_M,
        ge=0,
        le=10_000,
        description="UAV altitude above ground; the receivers at this height (terrain taken into account) make the SINR "
        "maps [m].",
        json_schema_extra={"type": "metres"},
    )
    altitude_tol_m: float = Field(
        default=0.5,
        ge=0,
        le=1000,
        description="Receivers within this distance of the altitude are used [m].",
        json_schema_extra={"type": "metres"},
    )
    noise_dbm: float = Field(
        default=EMBEDDED_NOISE_DBM,
        ge=-250,
        le=100,
        description="Noise plus background interference power [dBm]. The default is the level the embedded cities are "
        "calibrated at and the shipped agents were trained at (EMBEDDED_NOISE_DBM in schemas/constants.py; "
        "docs/data.md); the paper's combined level is -104 dBm. Agents played on bundles of another level are warned "
        "about (`uavrl report --strict` refuses them).",
    )
    interference_std_db: float = Field(
        default=0.0, ge=0, le=100, description="Std [dB] of a Gaussian per-cell offset of the noise+interference level (0: none)."
    )
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="Seed of the interference draw and of the user split.")
    sinr_floor_db: float = Field(
        default=-40.0,
        ge=-300,
        le=100,
        description="SINR given to dead cells (no ray-traced path) and lowest SINR reported anywhere [dB].",
    )
    tx_dbm: float | None = Field(
        default=None,
        ge=-100,
        le=100,
        description="User transmit power [dBm]: needed when the export has path loss/gain and no power; else it "
        "overrides the export's (received power shifts with it).",
    )
    bounds: BoundsMode | tuple[float, float, float, float] = Field(
        default="auto",
        description="Grid extent: auto (the receiver grid; receivers and buildings when the receivers are points), "
        "receivers, buildings (buildings and receivers), or XMIN,YMIN,XMAX,YMAX [m].",
    )
    crop: bool = Field(
        default=False, description="Drop buildings wholly outside the grid (counted in the manifest) instead of failing."
    )
    role: SplitRole | None = Field(default=None, description="The city's role in experiments, if declared")
    p_t_db: float = Field(
        default=P_T_DB,
        ge=-100,
        le=100,
        description="SINR target the manifest's difficulty figures (targets, BFS steps) are computed at [dB].",
    )
    val_users: int = Field(default=0, ge=0, description="Users of a train city held out for validation (seeded)")

    @field_validator("bounds")
    @classmethod
    def _bounds_ordered(cls, b: object) -> object:
        if isinstance(b, tuple) and not (b[0] < b[2] and b[1] < b[3]):
            raise ValueError(f"bounds {b} must be x_min < x_max and y_min < y_max")
        return b

    @model_validator(mode="after")
    def _val_only_in_train(self) -> BuildConfig:
        if self.val_users and self.role in ("val", "test"):
            raise ValueError(f"val_users is for train cities; a {self.role} city's users are all {self.role} users")
        return self


class GridSpec(Contract):
    """The regular grid every array of a bundle lives on (see the module docstring)."""

    x_min_m: float
    y_min_m: float
    spacing_m: float = Field(gt=0)
    num_x: int = Field(ge=1)
    num_y: int = Field(ge=1)

    @property
    def shape(self) -> tuple[int, int]:
        """``(num_y, num_x)``, the shape of a 2-D map."""
        return (self.num_y, self.num_x)

    @property
    def x_max_m(self) -> float:
        return self.x_min_m + self.num_x * self.spacing_m

    @property
    def y_max_m(self) -> float:
        return self.y_min_m + self.num_y * self.spacing_m


class SinrInfo(Contract):
    """How the SINR maps were made."""

    source: SinrSource = Field(description="Export quantity the SINR comes from")
    noise_dbm: float | None = Field(description="Noise + interference used [dBm]; None when the export gave SINR")
    interference_std_db: float
    floor_db: float
    tx_power_dbm: tuple[float, ...] = Field(description="Distinct user transmit powers used [dBm]")
    resampled: bool = Field(description="True when the export's receiver spacing differs from the grid's")
    export_spacing_m: float | None = Field(description="Receiver spacing of the export (None for point receivers)")


class BundleManifest(Contract):
    """Everything a bundle is made of and how it was made; ``load_bundle`` checks it."""

    schema_version: str = SCHEMA_VERSION
    city: str = Field(pattern=NAME_PATTERN)
    version: str = Field(pattern=r"^[0-9a-f]{12}$", description="Content hash of inputs, config and schema version")
    created_utc: str
    uavplace_version: str
    command: str
    config: BuildConfig
    grid: GridSpec
    sinr: SinrInfo
    num_users: int = Field(ge=1)
    num_route_points: int = Field(
        default=0, ge=0, description="Route points of the tracking task's routes (routes.npz, routes.parquet); 0: no routes"
    )
    split: dict[str, int] = Field(description="Users per split (train, val, test)")
    counts: dict[str, int]
    difficulty: dict[str, float | None] = Field(
        description="Search difficulty at P_T (dataset.difficulty): target and dead shares, BFS steps to a target"
    )
    files: dict[str, str] = Field(description="Bundle file -> sha256")
    inputs: dict[str, str] = Field(description="Ingested file -> sha256 (the tables and terrain the bundle came from)")
    warnings: tuple[str, ...] = ()


class CityRoles(Contract):
    """The roles of the cities of a data folder (``data/raw/cities.toml``): facts about the data, declared beside it,
    that `uavdata build` applies to the cities it builds (its ``--split``, ``--crop-city`` and ``--val-users`` override
    them). A city in no list has no role; a city is in one role list at most."""

    train: list[str] = Field(default_factory=list, description="Cities episodes are trained on")
    val: list[str] = Field(default_factory=list, description="Validation cities: every choice is made on them")
    test: list[str] = Field(default_factory=list, description="Test cities: release numbers only")
    crop: list[str] = Field(
        default_factory=list, description="Cities whose receiver grid covers part of the scene by design (--crop-city)"
    )
    val_users: int = Field(default=0, ge=0, description="Users of each train city held out for validation (seeded)")

    @field_validator("train", "val", "test", "crop")
    @classmethod
    def _names(cls, names: list[str]) -> list[str]:
        bad = [n for n in names if not re.fullmatch(NAME_PATTERN, n)]
        if bad:
            raise ValueError(f"{bad[0]!r} is not a city name")
        twice = repeated(names)
        if twice:
            raise ValueError(f"{twice[0]} is listed twice")
        return names

    @model_validator(mode="after")
    def _one_role(self) -> CityRoles:
        seen: dict[str, str] = {}
        for role in ("train", "val", "test"):
            for city in getattr(self, role):
                if city in seen:
                    raise ValueError(f"{city} is both a {seen[city]} and a {role} city")
                seen[city] = role
        return self

    def role_of(self, city: str) -> SplitRole | None:
        return next((r for r in ("train", "val", "test") if city in getattr(self, r)), None)  # type: ignore[return-value]


class BundleSettings(Contract):
    """The settings of a bundle an agent depends on: a training run records its cities' (``run.json``), and a report
    names every bundle it plays an agent on whose settings none of the agent's training cities had."""

    grid_m: float = Field(description="Grid spacing [m]")
    altitude_m: float = Field(description="UAV altitude [m]")
    noise_dbm: float | None = Field(description="Noise plus interference [dBm]; None when the export gave SINR")

    @classmethod
    def of(cls, manifest: BundleManifest) -> BundleSettings:
        return cls(grid_m=manifest.grid.spacing_m, altitude_m=manifest.config.altitude_m, noise_dbm=manifest.sinr.noise_dbm)

    def unlike(self, trained: BundleSettings) -> list[str]:
        """How these settings differ from ``trained``'s, one phrase each (empty: alike)."""

        def shown(value: float | None, unit: str) -> str:
            return "the export's SINR" if value is None else f"{value:g} {unit}"

        fields = (("grid", "grid_m", "m"), ("altitude", "altitude_m", "m"), ("noise", "noise_dbm", "dBm"))
        return [
            f"{name} {shown(getattr(self, f), unit)} (trained at {shown(getattr(trained, f), unit)})"
            for name, f, unit in fields
            if getattr(self, f) != getattr(trained, f)
        ]


_I32 = pa.int32()
_F64 = pa.float64()
_F32 = pa.float32()

CELLS = TableSpec(
    name="cells",
    filename="cells.parquet",
    description="One row per user x cell: the maps of maps.npz as a long table (user-major, then iy, then ix).",
    columns=(
        Column("user", _I32, "", "User index in the bundle (row of users.parquet)"),
        Column("ix", _I32, "", "Cell column, 0 at x_min"),
        Column("iy", _I32, "", "Cell row, 0 at y_min"),
        Column("x_m", _F64, "m", "Cell centre x", min=XY_RANGE_M[0], max=XY_RANGE_M[1]),
        Column("y_m", _F64, "m", "Cell centre y", min=XY_RANGE_M[0], max=XY_RANGE_M[1]),
        Column(
            "sinr_db", _F32, "dB", "SINR at the cell (the SINR floor where dead)", min=RATIO_RANGE_DB[0], max=RATIO_RANGE_DB[1]
        ),
        Column("dead", pa.bool_(), "", "No ray-traced path reached the cell"),
        Column("provenance", pa.uint8(), "", "Where the cell's value came from (schemas/provenance.py)", min=0, max=8),
        Column("blocked", pa.bool_(), "", "Building at or above the UAV altitude"),
        Column(
            "height_rel_m", _F32, "m", "Building height above ground minus the UAV altitude", min=-Z_RANGE_M[1], max=Z_RANGE_M[1]
        ),
    ),
)

USERS = TableSpec(
    name="users",
    filename="users.parquet",
    description="One row per user (ray-traced transmitter) of the bundle.",
    columns=(
        Column("user", _I32, "", "User index in the bundle, 0-based"),
        Column("tx_set_id", _I32, "", "Transmitter set project_id in the export"),
        Column("tx_point", _I32, "", "Point number within the set in the export"),
        Column("x_m", _F64, "m", "User position x", nullable=True),
        Column("y_m", _F64, "m", "User position y", nullable=True),
        Column("z_m", _F64, "m", "User position z as in the export", nullable=True),
        Column("ix", _I32, "", "Cell column of the user position (-1 outside the grid or unknown)"),
        Column("iy", _I32, "", "Cell row of the user position (-1 outside the grid or unknown)"),
        Column("tx_power_dbm", _F64, "dBm", "Transmit power used", nullable=True, min=POWER_RANGE_DBM[0], max=POWER_RANGE_DBM[1]),
        Column(
            "frequency_hz", _F64, "Hz", "Carrier frequency", nullable=True, min=FREQUENCY_RANGE_HZ[0], max=FREQUENCY_RANGE_HZ[1]
        ),
        Column("split", pa.string(), "", "train, val or test; null when the city declares no role", nullable=True),
        Column("num_receivers", _I32, "", "Receivers of the export used for this user"),
        Column("num_dead_cells", _I32, "", "Cells of the grid no path reached for this user"),
    ),
)

ROUTE_POINTS = TableSpec(
    name="route_points",
    filename="routes.parquet",
    description="One row per route point of the tracking task (a bundle with routes), in route order; ``point`` is "
    "its map in routes.npz.",
    columns=(
        Column("point", _I32, "", "Index of the point's map in routes.npz, 0-based, in table order"),
        Column("route", _I32, "", "Route id"),
        Column("order", _I32, "", "0-based position along the route"),
        Column("time_s", _F64, "s", "When the user is at the point, from the route's start", min=0, max=1e6),
        Column("tx_set_id", _I32, "", "Transmitter set project_id in the export"),
        Column("tx_point", _I32, "", "Point number within the set in the export"),
        Column("x_m", _F64, "m", "Point position x"),
        Column("y_m", _F64, "m", "Point position y"),
        Column("ix", _I32, "", "Cell column of the point (-1 outside the grid)"),
        Column("iy", _I32, "", "Cell row of the point (-1 outside the grid)"),
        Column("kind", pa.string(), "", "Kind of route (pedestrian, vehicle)"),
        Column("speed_mps", _F64, "m/s", "The user's speed along the route", min=0.1, max=100.0),
    ),
)

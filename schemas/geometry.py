"""Building and terrain contracts."""

from __future__ import annotations

import numpy as np
import shapely
from pydantic import Field, field_validator, model_validator

from uavplace.schemas.base import Contract
from uavplace.schemas.tables import BUILDINGS


class Building(Contract):
    """A building: footprint polygon (local frame, metres) and heights."""

    building_id: int = Field(ge=0)
    name: str | None = None
    footprint_wkt: str = Field(description="Polygon or MultiPolygon, WKT, local frame [m]")
    base_z_m: float
    roof_z_m: float
    n_parts: int = Field(default=1, ge=1)
    source: str

    @field_validator("footprint_wkt")
    @classmethod
    def _valid_polygon(cls, wkt: str) -> str:
        geom = shapely.from_wkt(wkt)
        if geom.geom_type not in ("Polygon", "MultiPolygon"):
            raise ValueError(f"footprint is a {geom.geom_type}, not a polygon")
        if not geom.is_valid:
            raise ValueError(f"footprint is not a valid polygon: {shapely.is_valid_reason(geom)}")
        if geom.is_empty or geom.area <= 0:
            raise ValueError("footprint has no area")
        return wkt

    @model_validator(mode="after")
    def _physical_heights(self) -> Building:
        for name in ("base_z_m", "roof_z_m"):
            col = BUILDINGS.column(name)
            if col.first_out_of_range(np.array([getattr(self, name)])) is not None:
                raise ValueError(f"{name} {getattr(self, name)} is outside the physical range {col.range_text()}")
        if self.roof_z_m < self.base_z_m:
            raise ValueError(f"roof z {self.roof_z_m} below base z {self.base_z_m}")
        col = BUILDINGS.column("height_m")
        if col.first_out_of_range(np.array([self.height_m])) is not None:
            raise ValueError(f"height {self.height_m:g} m is outside the physical range {col.range_text()}")
        return self

    @property
    def height_m(self) -> float:
        return self.roof_z_m - self.base_z_m


class TerrainInfo(Contract):
    """Summary of a terrain mesh written beside the tables (arrays in terrain.npz)."""

    source: str
    num_vertices: int = Field(ge=3)
    num_faces: int = Field(ge=1)
    z_min_m: float
    z_max_m: float

"""Format-neutral buildings: what every geometry reader (InSite .city, GeoJSON, meshes) returns.

A building is one or more parts (tiers); each part a footprint polygon with a
base and roof z. ``buildings_tables`` validates them against the
``schemas.Building`` contract and lays them out as the BUILDINGS and
BUILDING_PARTS tables.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pyarrow as pa
import shapely
from pydantic import ValidationError
from shapely.geometry.base import BaseGeometry

from uavplace.schemas import BUILDING_PARTS, BUILDINGS, Building, InputError, Rejection
from uavplace.schemas.base import validation_message

#: Footprints smaller than this [m^2] are degenerate (a wall seen from above).
MIN_AREA_M2 = 1e-6


@dataclass
class Part:
    footprint: BaseGeometry
    base_z_m: float
    roof_z_m: float


@dataclass
class BuildingRecord:
    name: str | None
    source_file: str
    source_line: int | None
    parts: list[Part] = field(default_factory=list)

    @property
    def source(self) -> str:
        return self.source_file if self.source_line is None else f"{self.source_file}:{self.source_line}"


def crop_records(records: list[BuildingRecord], box: tuple[float, float, float, float]) -> tuple[list[BuildingRecord], int]:
    """Buildings clipped to ``box`` (x_min, y_min, x_max, y_max), and how many fell wholly outside."""
    clip = shapely.box(*box)
    kept, dropped = [], 0
    for rec in records:
        parts = []
        for p in rec.parts:
            polys = [
                g
                for g in shapely.get_parts(shapely.intersection(p.footprint, clip))
                if g.geom_type == "Polygon" and g.area > MIN_AREA_M2
            ]
            if polys:
                parts.append(Part(footprint=shapely.union_all(polys), base_z_m=p.base_z_m, roof_z_m=p.roof_z_m))
        if parts:
            kept.append(BuildingRecord(name=rec.name, source_file=rec.source_file, source_line=rec.source_line, parts=parts))
        else:
            dropped += 1
    return kept, dropped


def buildings_tables(records: list[BuildingRecord], ground_z_m: float = 0.0) -> tuple[pa.Table, pa.Table, list[Rejection]]:
    """Validate buildings and return (buildings, parts, rejections).

    A building whose parts have no footprint area, or whose roof is below
    ``ground_z_m`` (the lowest ground: the terrain's, or 0 without terrain, where
    the build puts the ground) is rejected (counted, with its source line), never
    silently dropped. A footprint that is not a valid polygon raises ``InputError``.
    """
    rows: dict[str, list] = {c: [] for c in BUILDINGS.column_names}
    parts: dict[str, list] = {c: [] for c in BUILDING_PARTS.column_names}
    rejected: list[Rejection] = []
    for rec in records:
        kept = [p for p in rec.parts if p.footprint is not None and not p.footprint.is_empty and p.footprint.area > MIN_AREA_M2]
        if not kept:
            rejected.append(
                Rejection(
                    file=rec.source_file,
                    line=rec.source_line,
                    field="footprint",
                    reason="building has no footprint area (no roof and no closed walls)",
                )
            )
            continue
        footprint = shapely.union_all([p.footprint for p in kept])
        base = min(p.base_z_m for p in kept)
        roof = max(p.roof_z_m for p in kept)
        if ground_z_m is not None and roof < ground_z_m:
            reason = f"roof at {roof:g} m is below the ground ({ground_z_m:g} m without terrain): never in the UAV's way"
            rejected.append(Rejection(file=rec.source_file, line=rec.source_line, field="roof_z_m", reason=reason))
            continue
        bid = len(rows["building_id"])
        try:
            Building(
                building_id=bid,
                name=rec.name,
                footprint_wkt=footprint.wkt,
                base_z_m=base,
                roof_z_m=roof,
                n_parts=len(kept),
                source=rec.source,
            )
        except ValidationError as exc:
            field, message = validation_message(exc, default_field="height")
            raise InputError(rec.source_file, message, line=rec.source_line, field=field) from None
        for key, value in (
            ("building_id", bid),
            ("name", rec.name),
            ("footprint_wkb", shapely.to_wkb(footprint)),
            ("base_z_m", base),
            ("roof_z_m", roof),
            ("height_m", roof - base),
            ("n_parts", len(kept)),
            ("source", rec.source),
        ):
            rows[key].append(value)
        for pid, p in enumerate(kept):
            for key, value in (
                ("building_id", bid),
                ("part_id", pid),
                ("footprint_wkb", shapely.to_wkb(p.footprint)),
                ("base_z_m", p.base_z_m),
                ("roof_z_m", p.roof_z_m),
            ):
                parts[key].append(value)
    return (
        pa.Table.from_pydict(rows, schema=BUILDINGS.arrow_schema()),
        pa.Table.from_pydict(parts, schema=BUILDING_PARTS.arrow_schema()),
        rejected,
    )

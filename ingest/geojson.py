"""GeoJSON building footprints with a height property.

A FeatureCollection of Polygon / MultiPolygon features in a projected, metric
local frame (the same frame as the receiver exports). Each feature needs a
height [m] in ``properties``: ``height_m`` or ``height``; the base is
``base_m`` or ``min_height`` (default 0). Features of other geometry types
are rejected and counted.
"""

from __future__ import annotations

import json
from pathlib import Path

import shapely
from shapely.geometry import shape

from ingest.buildings import BuildingRecord, Part
from schemas import InputError, Rejection

HEIGHT_KEYS = ("height_m", "height")
BASE_KEYS = ("base_m", "min_height")


def _number(props: dict, keys: tuple[str, ...], where: str, index: int, required: bool) -> float | None:
    for key in keys:
        if key in props and props[key] is not None:
            try:
                return float(props[key])
            except (TypeError, ValueError):
                raise InputError(where, f"feature {index}: '{props[key]}' is not a number", field=f"properties.{key}") from None
    if required:
        raise InputError(where, f"feature {index} has no height ({' or '.join(keys)})", field="properties.height_m")
    return None


def read_geojson(path: str | Path, display: str | None = None) -> tuple[list[BuildingRecord], list[Rejection]]:
    name = display or str(path)
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise InputError(name, f"invalid JSON: {exc.msg}", line=exc.lineno) from None
    if doc.get("type") != "FeatureCollection" or not isinstance(doc.get("features"), list):
        raise InputError(name, "not a GeoJSON FeatureCollection", field="type")
    records, rejected = [], []
    for i, feature in enumerate(doc["features"]):
        geom = feature.get("geometry")
        if not geom or geom.get("type") not in ("Polygon", "MultiPolygon"):
            kind = geom.get("type") if geom else "null"
            rejected.append(Rejection(file=name, field=f"features[{i}].geometry", reason=f"{kind} geometry is not a footprint"))
            continue
        try:
            footprint = shape(geom)
        except (ValueError, TypeError, AttributeError, IndexError) as exc:
            raise InputError(name, f"feature {i}: malformed geometry ({exc})", field=f"features[{i}].geometry") from None
        if not footprint.is_valid:
            raise InputError(
                name, f"feature {i}: invalid polygon ({shapely.is_valid_reason(footprint)})", field=f"features[{i}].geometry"
            )
        props = feature.get("properties") or {}
        height = _number(props, HEIGHT_KEYS, name, i, required=True)
        base = _number(props, BASE_KEYS, name, i, required=False) or 0.0
        assert height is not None
        fid = feature.get("id", props.get("name"))
        records.append(
            BuildingRecord(
                name=None if fid is None else str(fid),
                source_file=f"{name}#features[{i}]",
                source_line=None,
                parts=[Part(footprint=footprint, base_z_m=base, roof_z_m=base + height)],
            )
        )
    minx, miny, maxx, maxy = (
        shapely.union_all([p.footprint for r in records for p in r.parts]).bounds if records else (0, 0, 0, 0)
    )
    if records and max(maxx - minx, maxy - miny) < 1.0 and abs(minx) <= 180 and abs(miny) <= 90:
        raise InputError(
            name, "footprints look like longitude/latitude degrees; project them to metres first", field="coordinates"
        )
    return records, rejected

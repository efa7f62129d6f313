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

import numpy as np
import shapely
from shapely.geometry import shape

from ingest.buildings import BuildingRecord, Part
from schemas import InputError, Rejection
from schemas.tables import BUILDINGS

HEIGHT_KEYS = ("height_m", "height")
BASE_KEYS = ("base_m", "min_height")


def _number(props: dict, keys: tuple[str, ...], where: str, index: int, column: str, required: bool) -> float | None:
    """The first of ``keys`` in ``props`` as a number in the BUILDINGS ``column``'s physical range."""
    for key in keys:
        if key in props and props[key] is not None:
            field = f"features[{index}].properties.{key}"
            value = props[key]
            try:
                number = float(value) if not isinstance(value, bool) else float("nan")
            except (TypeError, ValueError, OverflowError):
                raise InputError(where, f"feature {index}: {str(value)[:40]!r} is not a number", field=field) from None
            col = BUILDINGS.column(column)
            if col.first_out_of_range(np.array([number])) is not None:
                raise InputError(
                    where, f"feature {index}: {str(value)[:40]} is outside the physical range {col.range_text()}", field=field
                )
            return number
    if required:
        raise InputError(where, f"feature {index} has no height ({' or '.join(keys)})", field=f"features[{index}].properties")
    return None


def _load(path: Path, name: str) -> object:
    """The parsed JSON document; ``InputError`` for text that is not UTF-8 JSON."""
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(
            name,
            f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); GeoJSON is UTF-8 (RFC 7946): "
            "convert it, e.g. with iconv -f latin1 -t utf-8",
            field="encoding",
        ) from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(name, f"invalid JSON: {exc.msg}", line=exc.lineno, field=f"column {exc.colno}") from None
    except RecursionError:
        raise InputError(name, "JSON nested too deeply to be GeoJSON", field="json") from None


def read_geojson(path: str | Path, display: str | None = None) -> tuple[list[BuildingRecord], list[Rejection]]:
    name = display or str(path)
    doc = _load(Path(path), name)
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection" or not isinstance(doc.get("features"), list):
        kind = f"a JSON {type(doc).__name__}" if not isinstance(doc, dict) else f"type {doc.get('type')!r}"
        raise InputError(name, f"not a GeoJSON FeatureCollection ({kind})", field="type")
    records, rejected = [], []
    for i, feature in enumerate(doc["features"]):
        field = f"features[{i}]"
        if not isinstance(feature, dict):
            raise InputError(name, f"feature {i} is a JSON {type(feature).__name__}, not an object", field=field)
        geom = feature.get("geometry")
        if geom is not None and not isinstance(geom, dict):
            raise InputError(name, f"feature {i}: geometry is a JSON {type(geom).__name__}", field=f"{field}.geometry")
        if not geom or geom.get("type") not in ("Polygon", "MultiPolygon"):
            kind = geom.get("type") if geom else "null"
            rejected.append(Rejection(file=name, field=f"{field}.geometry", reason=f"{kind} geometry is not a footprint"))
            continue
        try:
            footprint = shape(geom)
        except Exception as exc:  # shapely raises many types on malformed coordinates
            raise InputError(
                name, f"feature {i}: malformed geometry ({type(exc).__name__}: {exc})", field=f"{field}.geometry"
            ) from None
        if footprint.is_empty or not np.isfinite(shapely.total_bounds(footprint)).all():
            raise InputError(name, f"feature {i}: empty geometry or coordinates that are not finite", field=f"{field}.geometry")
        if not footprint.is_valid:
            raise InputError(
                name, f"feature {i}: invalid polygon ({shapely.is_valid_reason(footprint)})", field=f"{field}.geometry"
            )
        props = feature.get("properties") or {}
        if not isinstance(props, dict):
            raise InputError(name, f"feature {i}: properties is a JSON {type(props).__name__}", field=f"{field}.properties")
        height = _number(props, HEIGHT_KEYS, name, i, "height_m", required=True)
        base = _number(props, BASE_KEYS, name, i, "base_z_m", required=False) or 0.0
        assert height is not None
        fid = feature.get("id", props.get("name"))
        records.append(
            BuildingRecord(
                name=None if fid is None else str(fid)[:200],
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

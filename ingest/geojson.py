"""GeoJSON building footprints with heights, as OpenStreetMap tools export them.

A FeatureCollection of Polygon / MultiPolygon features in a projected, metric
local frame (the same frame as the receiver exports). Heights come from
``properties``, first found wins:

- top: ``height_m`` (the building's own height above its base, uavplace's
  convention), else ``height`` (OSM: the top above the ground; a number, or
  a string with a unit as OSM writes it: ``"12"``, ``"12 m"``, ``"40 ft"``,
  ``"40'"``), else ``building:levels`` x ``LEVEL_HEIGHT_M``;
- base: ``base_m``, ``min_height``, else ``building:min_level`` x
  ``LEVEL_HEIGHT_M``, else 0.

A feature with no usable height (none given, or text that is not a length)
is rejected and counted with its reason, never silently dropped; a number
outside the physical range is an error. Features of other geometry types are
rejected and counted.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import shape

from uavplace.infra.files import regular_file_bytes
from uavplace.infra.limits import check_limit
from uavplace.ingest.buildings import BuildingRecord, Part
from uavplace.schemas import InputError, Rejection
from uavplace.schemas.tables import BUILDINGS

HEIGHT_KEYS = ("height_m", "height")
BASE_KEYS = ("base_m", "min_height")
#: OSM level counts, turned into metres at ``LEVEL_HEIGHT_M`` a level.
LEVELS_KEY = "building:levels"
MIN_LEVEL_KEY = "building:min_level"
#: Height of one storey [m] (OSM's usual assumption).
LEVEL_HEIGHT_M = 3.0
#: ``"12"``, ``"12.5 m"``, ``"40 ft"``, ``"40'"``, ``"3 metres"``: a number and an optional unit.
_LENGTH = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+))\s*(m|meters?|metres?|ft|feet|foot|')?\s*", re.IGNORECASE)
_FEET_M = 0.3048


def _length_m(value: object) -> float | None:
    """A length in metres from a GeoJSON property, or None if it is not one (text, a list, a bool)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):
        return float(value)
    if not isinstance(value, str):
        return None
    try:
        return float(value)  # also "nan" and "1e400": numbers, refused below as not physical
    except ValueError:
        pass
    m = _LENGTH.fullmatch(value)
    if m is None:
        return None
    unit = (m.group(2) or "m").lower()
    return float(m.group(1)) * (_FEET_M if unit in ("ft", "feet", "foot", "'") else 1.0)


def _checked(number: float, value: object, where: str, index: int, key: str, column: str) -> float:
    col = BUILDINGS.column(column)
    if col.first_out_of_range(np.array([number])) is not None:
        raise InputError(
            where,
            f"feature {index}: {str(value)[:40]} is outside the physical range {col.range_text()}",
            field=f"features[{index}].properties.{key}",
        )
    return number


def _levels_m(props: dict, key: str, where: str, index: int) -> float | None:
    """``key`` (a level count) in metres, or None when absent or not a number."""
    value = props.get(key)
    levels = _length_m(value) if value is not None else None
    return None if levels is None else _checked(levels, value, where, index, key, "height_m") * LEVEL_HEIGHT_M


def _top(props: dict, base: float, where: str, index: int) -> tuple[float | None, str]:
    """(roof z [m], how it was found), or (None, why there is none).

    ``height_m`` is the building's own height above its base; OSM's ``height`` and
    ``building:levels`` measure the top from the ground.
    """
    for key in HEIGHT_KEYS:
        if props.get(key) is not None:
            number = _length_m(props[key])
            if number is None:
                return None, f"{key} {str(props[key])[:40]!r} is not a length"
            number = _checked(number, props[key], where, index, key, "height_m")
            return (base + number if key == "height_m" else number), key
    levels = _levels_m(props, LEVELS_KEY, where, index)
    if levels is not None:
        return levels, f"{LEVELS_KEY} x {LEVEL_HEIGHT_M:g} m"
    if props.get(LEVELS_KEY) is not None:
        return None, f"{LEVELS_KEY} {str(props[LEVELS_KEY])[:40]!r} is not a number"
    return None, f"no height ({', '.join(HEIGHT_KEYS)} or {LEVELS_KEY})"


def _base(props: dict, where: str, index: int) -> float:
    for key in BASE_KEYS:
        if props.get(key) is not None:
            number = _length_m(props[key])
            if number is None:
                field = f"features[{index}].properties.{key}"
                raise InputError(where, f"feature {index}: {str(props[key])[:40]!r} is not a length", field=field)
            return _checked(number, props[key], where, index, key, "base_z_m")
    return _levels_m(props, MIN_LEVEL_KEY, where, index) or 0.0


def _load(path: Path, name: str) -> object:
    """The parsed JSON document; ``InputError`` for text that is not UTF-8 JSON."""
    raw = regular_file_bytes(path, name, "text_bytes")
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
    check_limit("buildings", len(doc["features"]), name, "features of the GeoJSON (before any is processed)")
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
        base = _base(props, name, i)
        roof, found = _top(props, base, name, i)
        if roof is None:
            rejected.append(Rejection(file=name, field=f"{field}.properties", reason=f"no usable height: {found}"))
            continue
        if roof < base:
            raise InputError(
                name, f"feature {i}: top {roof:g} m below its base {base:g} m ({found})", field=f"{field}.properties"
            )
        fid = feature.get("id", props.get("name"))
        records.append(
            BuildingRecord(
                name=None if fid is None else str(fid)[:200],
                source_file=f"{name}#features[{i}]",
                source_line=None,
                parts=[Part(footprint=footprint, base_z_m=base, roof_z_m=roof)],
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

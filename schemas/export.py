"""JSON schemas of every contract, for ``uavdata schema`` and for tools outside uavplace."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel

from uavplace.schemas.base import SCHEMA_VERSION
from uavplace.schemas.bundle import CELLS, ROUTE_POINTS, USERS, BuildConfig, BundleManifest
from uavplace.schemas.city import CityManifest, IngestReport
from uavplace.schemas.geometry import Building, TerrainInfo
from uavplace.schemas.receivers import ReceiverSet
from uavplace.schemas.tables import ALL_TABLES, TableSpec
from uavplace.schemas.txrx import SetupInfo, Transmitter, TxRxSet

SCHEMA_MODELS: dict[str, type[BaseModel] | TableSpec] = {
    "city_manifest": CityManifest,
    "ingest_report": IngestReport,
    "receiver_set": ReceiverSet,
    "txrx_set": TxRxSet,
    "transmitter": Transmitter,
    "setup": SetupInfo,
    "building": Building,
    "terrain": TerrainInfo,
    "bundle_manifest": BundleManifest,
    "build_config": BuildConfig,
    **{f"table_{t.name}": t for t in (*ALL_TABLES, CELLS, USERS, ROUTE_POINTS)},
}

_JSON_TYPES = {
    "int32": "integer",
    "int64": "integer",
    "uint8": "integer",
    "double": "number",
    "float": "number",
    "bool": "boolean",
    "string": "string",
    "binary": "string",
}


def table_json_schema(spec: TableSpec) -> dict[str, Any]:
    """JSON schema of one row of a Parquet table (binary columns as base64 strings)."""
    props = {}
    for c in spec.columns:
        t = _JSON_TYPES[str(c.type)]
        prop: dict[str, Any] = {"type": [t, "null"] if c.nullable else t, "description": c.description}
        if c.unit:
            prop["unit"] = c.unit
        if c.min is not None:
            prop["minimum"] = c.min
        if c.max is not None:
            prop["maximum"] = c.max
        if str(c.type) == "binary":
            prop["contentEncoding"] = "base64"
        props[c.name] = prop
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": f"{spec.name} row ({spec.filename})",
        "description": spec.description,
        "type": "object",
        "properties": props,
        "required": [c.name for c in spec.columns],
        "additionalProperties": False,
        "x-schema-version": SCHEMA_VERSION,
    }


def json_schemas() -> dict[str, dict[str, Any]]:
    out = {}
    for name, model in SCHEMA_MODELS.items():
        if isinstance(model, TableSpec):
            out[name] = table_json_schema(model)
        else:
            s = model.model_json_schema()
            s["x-schema-version"] = SCHEMA_VERSION
            out[name] = s
    return out

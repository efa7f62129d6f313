"""What every ingest writes the same way, whatever it read: the city's tables as Parquet with their sha256, and the
fields of a city's manifest that say who made it, when and from where."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from uavplace.infra.files import sha256_file
from uavplace.schemas.base import uavplace_version
from uavplace.schemas.tables import TableSpec


def write_tables(folder: Path, tables: list[tuple[TableSpec, pa.Table]]) -> dict[str, str]:
    """Each table into ``folder`` under its spec's file name (zstd Parquet); ``{spec name: sha256 of its file}``."""
    digests = {}
    for spec, table in tables:
        pq.write_table(table, folder / spec.filename, compression="zstd")
        digests[spec.name] = sha256_file(folder / spec.filename)
    return digests


def made_by(city: str, command: str, folder: Path) -> dict[str, str]:
    """The manifest's ``name``, ``created_utc`` (now), ``uavplace_version``, ``command`` and ``source_dir``."""
    now = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    return {
        "name": city,
        "created_utc": now,
        "uavplace_version": uavplace_version(),
        "command": command,
        "source_dir": str(folder),
    }

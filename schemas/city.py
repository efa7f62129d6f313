"""What an ingested city is: its manifest and the report of how ingest went."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from uavplace.schemas.base import NAME_PATTERN, SCHEMA_VERSION, Contract
from uavplace.schemas.geometry import TerrainInfo
from uavplace.schemas.receivers import ReceiverSet
from uavplace.schemas.txrx import SetupInfo, TxRxSet

FileStatus = Literal["parsed", "skipped", "unknown"]


class SourceFile(Contract):
    path: str = Field(description="Path relative to the city folder")
    sha256: str | None = Field(
        pattern=r"^[0-9a-f]{64}$", description="sha256 of the bytes; None for a link out of the city folder (never opened)"
    )
    size_bytes: int | None = Field(ge=0, description="Size [bytes]; None for a link out of the city folder (never followed)")
    kind: str = Field(
        description="Format family: p2m, txrx, setup, city, terrain, geojson, mesh, routes, cells (the provenance side file), geometry, provenance (simulation.json), radiomapseer (a file of a RadioMapSeer-style folder), link (out of the folder), special (not a regular file), other"
    )
    status: FileStatus


class Origin(Contract):
    """Geographic reference of the local cartesian frame, when a source declares one."""

    longitude: float = Field(ge=-180, le=180)
    latitude: float = Field(ge=-90, le=90)
    source: str


class Rejection(Contract):
    """Rows of an input that were read but not kept, and why."""

    file: str
    line: int | None = None
    field: str | None = None
    reason: str
    count: int = Field(default=1, ge=1)


class FileReport(Contract):
    path: str
    kind: str
    status: FileStatus
    rows_read: int = 0
    rows_rejected: int = 0
    message: str | None = None


class IngestReport(Contract):
    schema_version: str = SCHEMA_VERSION
    city: str
    files: tuple[FileReport, ...]
    rejections: tuple[Rejection, ...] = ()
    warnings: tuple[str, ...] = ()

    @property
    def rows_read(self) -> int:
        return sum(f.rows_read for f in self.files)

    @property
    def rows_rejected(self) -> int:
        return sum(r.count for r in self.rejections)


class CityManifest(Contract):
    """Everything an ingested city is made of, and how it was made."""

    schema_version: str = SCHEMA_VERSION
    name: str = Field(pattern=NAME_PATTERN)
    created_utc: str
    uavplace_version: str
    command: str
    source_dir: str
    origin: Origin | None = None
    frequency_hz: float | None = Field(default=None, description="Carrier frequency if one is shared by all")
    tx_power_dbm: tuple[float, ...] = Field(default=(), description="Distinct transmitter powers [dBm]")
    counts: dict[str, int]
    sources: tuple[SourceFile, ...]
    tables: dict[str, str] = Field(description="Table name -> sha256 of the file written")
    setup: SetupInfo | None = None
    txrx_sets: tuple[TxRxSet, ...] = ()
    receiver_sets: tuple[ReceiverSet, ...] = ()
    terrain: TerrainInfo | None = None

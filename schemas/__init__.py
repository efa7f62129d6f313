"""uavplace contracts: the pydantic models and table declarations every stage relies on.

Everything that crosses a stage boundary (ingest -> dataset -> rl -> eval) is
declared here once. Nothing in this package imports another uavplace package.
"""

from uavplace.schemas.base import SCHEMA_VERSION, Contract, InputError
from uavplace.schemas.bundle import CELLS, USERS, BuildConfig, BundleManifest, GridSpec, SinrInfo
from uavplace.schemas.city import (
    CityManifest,
    FileReport,
    IngestReport,
    Origin,
    Rejection,
    SourceFile,
)
from uavplace.schemas.geometry import Building, TerrainInfo
from uavplace.schemas.receivers import QUANTITIES, Quantity, ReceiverSet
from uavplace.schemas.tables import BUILDING_PARTS, BUILDINGS, RECEIVERS, ROUTES, TRANSMITTERS, TableSpec
from uavplace.schemas.txrx import AntennaInfo, CommSystemInfo, SetupInfo, Transmitter, TxRxSet, WaveformInfo

__all__ = [
    "SCHEMA_VERSION",
    "AntennaInfo",
    "BUILDINGS",
    "BUILDING_PARTS",
    "Building",
    "BuildConfig",
    "BundleManifest",
    "CELLS",
    "GridSpec",
    "SinrInfo",
    "USERS",
    "CityManifest",
    "CommSystemInfo",
    "Contract",
    "FileReport",
    "IngestReport",
    "InputError",
    "Origin",
    "QUANTITIES",
    "Quantity",
    "RECEIVERS",
    "ReceiverSet",
    "Rejection",
    "SetupInfo",
    "SourceFile",
    "ROUTES",
    "TRANSMITTERS",
    "TableSpec",
    "TerrainInfo",
    "Transmitter",
    "TxRxSet",
    "WaveformInfo",
]

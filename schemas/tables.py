"""Column declarations of every Parquet table uavplace writes (PUDL style).

Each column is declared once (name, Arrow type, unit, description); the Arrow
schema, the validation and the documentation all come from that declaration.
"""

from __future__ import annotations

from dataclasses import dataclass

import pyarrow as pa

from schemas.base import SCHEMA_VERSION


@dataclass(frozen=True)
class Column:
    name: str
    type: pa.DataType
    unit: str
    description: str
    nullable: bool = False


@dataclass(frozen=True)
class TableSpec:
    """A named table: its columns in order, and the file name it is written under."""

    name: str
    filename: str
    description: str
    columns: tuple[Column, ...]

    @property
    def column_names(self) -> list[str]:
        return [c.name for c in self.columns]

    def arrow_schema(self) -> pa.Schema:
        fields = [
            pa.field(c.name, c.type, nullable=c.nullable, metadata={"unit": c.unit, "description": c.description})
            for c in self.columns
        ]
        return pa.schema(fields, metadata={"table": self.name, "schema_version": SCHEMA_VERSION})

    def conform(self, table: pa.Table) -> pa.Table:
        """Return ``table`` with exactly this spec's columns, order and types.

        Raises ``ValueError`` naming the column on a missing or extra column, a
        type that does not cast safely, or a null in a non-nullable column.
        """
        missing = [n for n in self.column_names if n not in table.column_names]
        extra = [n for n in table.column_names if n not in self.column_names]
        if missing or extra:
            raise ValueError(f"table {self.name}: missing columns {missing}, unexpected columns {extra}")
        arrays = []
        for col in self.columns:
            arr = table.column(col.name)
            if not col.nullable and arr.null_count:
                raise ValueError(f"table {self.name}: column {col.name} has {arr.null_count} nulls")
            arrays.append(arr.cast(col.type, safe=True))
        return pa.Table.from_arrays(arrays, schema=self.arrow_schema())

    def describe(self) -> list[dict[str, str]]:
        """The declaration as plain rows (name, type, unit, nullable, description), for docs and JSON."""
        return [
            {
                "name": c.name,
                "type": str(c.type),
                "unit": c.unit,
                "nullable": str(c.nullable).lower(),
                "description": c.description,
            }
            for c in self.columns
        ]


_F64 = pa.float64()
_I32 = pa.int32()

RECEIVER_KEY = ("tx_set_id", "tx_point", "rx_set_id", "rx_index")

RECEIVERS = TableSpec(
    name="receivers",
    filename="receivers.parquet",
    description="One row per transmitter point x receiver: every quantity the exports carry for it.",
    columns=(
        Column("tx_set_id", _I32, "", "Transmitter set project_id (InSite .txrx), the SS of t<TTT>_<SS>"),
        Column("tx_point", _I32, "", "Transmitter point number within its set, 1-based (the TTT)"),
        Column("rx_set_id", _I32, "", "Receiver set project_id (the RRR of r<RRR>)"),
        Column("rx_index", _I32, "", "Receiver number within its set as in the export, 1-based"),
        Column("x_m", _F64, "m", "Receiver x in the project's local cartesian frame"),
        Column("y_m", _F64, "m", "Receiver y in the project's local cartesian frame"),
        Column("z_m", _F64, "m", "Receiver z as exported (InSite: above sea level or terrain per the set)"),
        Column("distance_m", _F64, "m", "Direct distance transmitter to receiver, as exported", nullable=True),
        Column("power_dbm", _F64, "dBm", "Received power; null where not reached", nullable=True),
        Column("phase_deg", _F64, "deg", "Phase of the received power; null where not reached", nullable=True),
        Column("path_loss_db", _F64, "dB", "Path loss; null where not reached (export sentinel 250)", nullable=True),
        Column("path_gain_db", _F64, "dB", "Path gain; null where not reached (export sentinel -250)", nullable=True),
        Column("txloss_db", _F64, "dB", "Transmission loss; null where not reached (sentinel 250)", nullable=True),
        Column("delay_spread_s", _F64, "s", "RMS delay spread; null where not reached", nullable=True),
        Column("interference_dbm", _F64, "dBm", "Interference power (communication-system output)", nullable=True),
        Column("noise_dbm", _F64, "dBm", "Noise power (communication-system output)", nullable=True),
        Column("snr_db", _F64, "dB", "Signal to noise ratio (communication-system output)", nullable=True),
        Column("sir_db", _F64, "dB", "Signal to interference ratio (communication-system output)", nullable=True),
        Column("sinr_db", _F64, "dB", "SINR (communication-system output); null where not reached", nullable=True),
        Column(
            "reached",
            pa.bool_(),
            "",
            "True if a ray-traced path reached the receiver; null if no file for it carries reach information",
            nullable=True,
        ),
    ),
)

TRANSMITTERS = TableSpec(
    name="transmitters",
    filename="transmitters.parquet",
    description="One row per transmitter point (a ground user in uavplace's problem).",
    columns=(
        Column("tx_set_id", _I32, "", "Transmitter set project_id"),
        Column("tx_point", _I32, "", "Point number within the set, 1-based"),
        Column("set_name", pa.string(), "", "Transmitter set name in the .txrx", nullable=True),
        Column("x_m", _F64, "m", "Position x; null if no .txrx defines it", nullable=True),
        Column("y_m", _F64, "m", "Position y; null if no .txrx defines it", nullable=True),
        Column("z_m", _F64, "m", "Position z as in the .txrx (height above terrain)", nullable=True),
        Column("power_dbm", _F64, "dBm", "Transmit power from the .txrx", nullable=True),
        Column("frequency_hz", _F64, "Hz", "Carrier frequency of its waveform (.setup)", nullable=True),
        Column("antenna", pa.string(), "", "Antenna type of its transmitter pattern (.setup)", nullable=True),
        Column("source", pa.string(), "", "File (and line) that defined it"),
    ),
)

BUILDINGS = TableSpec(
    name="buildings",
    filename="buildings.parquet",
    description="One row per building: footprint polygon (WKB) and heights.",
    columns=(
        Column("building_id", _I32, "", "0-based id, in file order"),
        Column("name", pa.string(), "", "Name in the source (InSite structure name, GeoJSON id)", nullable=True),
        Column("footprint_wkb", pa.binary(), "m", "Footprint (Polygon or MultiPolygon) as WKB, local frame"),
        Column("base_z_m", _F64, "m", "Lowest z of the building"),
        Column("roof_z_m", _F64, "m", "Highest roof z of the building"),
        Column("height_m", _F64, "m", "roof_z_m - base_z_m"),
        Column("n_parts", _I32, "", "Parts (InSite sub_structures, mesh bodies) the building is made of"),
        Column("source", pa.string(), "", "File and line the building starts at"),
    ),
)

BUILDING_PARTS = TableSpec(
    name="building_parts",
    filename="building_parts.parquet",
    description="One row per building part (a tier of a stepped building), for exact height maps.",
    columns=(
        Column("building_id", _I32, "", "Building the part belongs to"),
        Column("part_id", _I32, "", "0-based part number within the building"),
        Column("footprint_wkb", pa.binary(), "m", "Part footprint as WKB"),
        Column("base_z_m", _F64, "m", "Lowest z of the part"),
        Column("roof_z_m", _F64, "m", "Highest z of the part"),
    ),
)

ALL_TABLES = (RECEIVERS, TRANSMITTERS, BUILDINGS, BUILDING_PARTS)

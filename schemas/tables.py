"""Column declarations of every Parquet table uavplace writes (PUDL style).

Each column is declared once (name, Arrow type, unit, description); the Arrow
schema, the validation and the documentation all come from that declaration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from uavplace.schemas.base import SCHEMA_VERSION, InputError


@dataclass(frozen=True)
class Column:
    """One column: name, Arrow type, unit, description, and for a physical quantity its valid range.

    ``min`` / ``max`` bound every non-null value (inclusive); a float column with
    a range must also be finite. Values outside are not physical: readers
    refuse them with the file, line and column.
    """

    name: str
    type: pa.DataType
    unit: str
    description: str
    nullable: bool = False
    min: float | None = None
    max: float | None = None

    @property
    def has_range(self) -> bool:
        return self.min is not None or self.max is not None

    def range_text(self) -> str:
        lo = "-inf" if self.min is None else f"{self.min:g}"
        hi = "inf" if self.max is None else f"{self.max:g}"
        return f"[{lo}, {hi}]" + (f" {self.unit}" if self.unit else "")

    def first_out_of_range(self, values: np.ndarray, valid: np.ndarray | None = None) -> int | None:
        """Index of the first value that is NaN, infinite or outside [min, max], or None.

        ``valid`` (bool, same shape) restricts the check to those entries (e.g. not null, or reached).
        """
        v = np.asarray(values, dtype=float)
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(v)
            if self.min is not None:
                bad |= v < self.min
            if self.max is not None:
                bad |= v > self.max
        if valid is not None:
            bad &= valid
        return int(np.argmax(bad)) if bad.any() else None


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

    def column(self, name: str) -> Column:
        return next(c for c in self.columns if c.name == name)

    def arrow_schema(self) -> pa.Schema:
        fields = [
            pa.field(c.name, c.type, nullable=c.nullable, metadata={"unit": c.unit, "description": c.description})
            for c in self.columns
        ]
        return pa.schema(fields, metadata={"table": self.name, "schema_version": SCHEMA_VERSION})

    def conform(self, table: pa.Table, source: str | None = None) -> pa.Table:
        """Return ``table`` with exactly this spec's columns, order and types, every value in its range.

        Raises ``InputError`` (naming ``source``, the column, and the row) on a
        missing or extra column, a type that does not cast safely, a null in a
        non-nullable column, or a value outside its column's range.
        """
        where = source or self.filename
        missing = [n for n in self.column_names if n not in table.column_names]
        extra = [n for n in table.column_names if n not in self.column_names]
        if missing or extra:
            raise InputError(where, f"table {self.name}: missing columns {missing}, unexpected columns {extra}")
        arrays = []
        for col in self.columns:
            arr = table.column(col.name)
            if not col.nullable and arr.null_count:
                raise InputError(where, f"table {self.name} has {arr.null_count} nulls", field=col.name)
            try:
                arr = arr.cast(col.type, safe=True)
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as exc:
                raise InputError(where, f"table {self.name}: {exc}", field=col.name) from None
            if col.has_range:
                valid = arr.is_valid().to_numpy(zero_copy_only=False)
                bad = col.first_out_of_range(arr.to_numpy(zero_copy_only=False), valid)
                if bad is not None:
                    raise InputError(
                        where,
                        f"row {bad}: {arr[bad].as_py()} is outside the physical range {col.range_text()}",
                        field=col.name,
                    )
            arrays.append(arr)
        return pa.Table.from_arrays(arrays, schema=self.arrow_schema())

    def describe(self) -> list[dict[str, str]]:
        """The declaration as plain rows (name, type, unit, nullable, description), for docs and JSON."""
        return [
            {
                "name": c.name,
                "type": str(c.type),
                "unit": c.unit,
                "nullable": str(c.nullable).lower(),
                "range": c.range_text() if c.has_range else "",
                "description": c.description,
            }
            for c in self.columns
        ]


_F64 = pa.float64()
_I32 = pa.int32()

# Physical ranges (inclusive), one place for every reader and writer. Generous, but finite: a value outside is
# a corrupt or mistyped export, never a city.
#: Horizontal coordinates in a local projected frame [m] (10 000 km either way).
XY_RANGE_M = (-1e7, 1e7)
#: Elevations: below the Dead Sea to above Everest with a tower on it [m].
Z_RANGE_M = (-1000.0, 10000.0)
#: A building's height above its own base [m] (the tallest today is 828 m).
BUILDING_HEIGHT_RANGE_M = (0.0, 1000.0)
#: Radiated or received power [dBm]: -250 is InSite's "no path" floor, 100 dBm is 10 MW.
POWER_RANGE_DBM = (-400.0, 100.0)
#: Carrier frequency [Hz]: positive, up to 10 THz.
FREQUENCY_RANGE_HZ = (1.0, 1e13)
#: Path loss / transmission loss [dB]: no passive channel amplifies; 250 dB is InSite's "no path" sentinel.
LOSS_RANGE_DB = (0.0, 250.0)
#: Ratios of powers (SNR, SIR, SINR) [dB].
RATIO_RANGE_DB = (-400.0, 400.0)

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
        Column("x_m", _F64, "m", "Receiver x in the project's local cartesian frame", min=XY_RANGE_M[0], max=XY_RANGE_M[1]),
        Column("y_m", _F64, "m", "Receiver y in the project's local cartesian frame", min=XY_RANGE_M[0], max=XY_RANGE_M[1]),
        Column(
            "z_m",
            _F64,
            "m",
            "Receiver z as exported (InSite: above sea level or terrain per the set)",
            min=Z_RANGE_M[0],
            max=Z_RANGE_M[1],
        ),
        Column(
            "distance_m",
            _F64,
            "m",
            "Direct distance transmitter to receiver, as exported",
            nullable=True,
            min=0.0,
            max=XY_RANGE_M[1],
        ),
        Column(
            "power_dbm",
            _F64,
            "dBm",
            "Received power; null where not reached (also at most the transmit power + antenna gains)",
            nullable=True,
            min=POWER_RANGE_DBM[0],
            max=POWER_RANGE_DBM[1],
        ),
        Column(
            "phase_deg", _F64, "deg", "Phase of the received power; null where not reached", nullable=True, min=-360.0, max=360.0
        ),
        Column(
            "path_loss_db",
            _F64,
            "dB",
            "Path loss; null where not reached (export sentinel 250)",
            nullable=True,
            min=LOSS_RANGE_DB[0],
            max=LOSS_RANGE_DB[1],
        ),
        Column(
            "path_gain_db",
            _F64,
            "dB",
            "Path gain; null where not reached (export sentinel -250)",
            nullable=True,
            min=-LOSS_RANGE_DB[1],
            max=-LOSS_RANGE_DB[0],
        ),
        Column(
            "txloss_db",
            _F64,
            "dB",
            "Transmission loss; null where not reached (sentinel 250)",
            nullable=True,
            min=LOSS_RANGE_DB[0],
            max=LOSS_RANGE_DB[1],
        ),
        Column("delay_spread_s", _F64, "s", "RMS delay spread; null where not reached", nullable=True, min=0.0, max=1.0),
        Column(
            "interference_dbm",
            _F64,
            "dBm",
            "Interference power (communication-system output)",
            nullable=True,
            min=POWER_RANGE_DBM[0],
            max=POWER_RANGE_DBM[1],
        ),
        Column(
            "noise_dbm",
            _F64,
            "dBm",
            "Noise power (communication-system output)",
            nullable=True,
            min=POWER_RANGE_DBM[0],
            max=POWER_RANGE_DBM[1],
        ),
        Column(
            "snr_db",
            _F64,
            "dB",
            "Signal to noise ratio (communication-system output)",
            nullable=True,
            min=RATIO_RANGE_DB[0],
            max=RATIO_RANGE_DB[1],
        ),
        Column(
            "sir_db",
            _F64,
            "dB",
            "Signal to interference ratio (communication-system output)",
            nullable=True,
            min=RATIO_RANGE_DB[0],
            max=RATIO_RANGE_DB[1],
        ),
        Column(
            "sinr_db",
            _F64,
            "dB",
            "SINR (communication-system output); null where not reached",
            nullable=True,
            min=RATIO_RANGE_DB[0],
            max=RATIO_RANGE_DB[1],
        ),
        Column(
            "reached",
            pa.bool_(),
            "",
            "True if a ray-traced path reached the receiver; null if no file for it carries reach information",
            nullable=True,
        ),
        Column(
            "provenance",
            pa.uint8(),
            "",
            "Where the receiver's value came from (schemas/provenance.py: 0 unreached, 1 ray-traced, 2 exact paths, "
            "3 straight path, 4 walked, 5 coarse map, 6 not recorded): the export's side file, or its kind without one",
            min=0,
            max=6,
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
        Column("x_m", _F64, "m", "Position x; null if no .txrx defines it", nullable=True, min=XY_RANGE_M[0], max=XY_RANGE_M[1]),
        Column("y_m", _F64, "m", "Position y; null if no .txrx defines it", nullable=True, min=XY_RANGE_M[0], max=XY_RANGE_M[1]),
        Column(
            "z_m",
            _F64,
            "m",
            "Position z as in the .txrx (height above terrain)",
            nullable=True,
            min=Z_RANGE_M[0],
            max=Z_RANGE_M[1],
        ),
        Column(
            "power_dbm",
            _F64,
            "dBm",
            "Transmit power from the .txrx",
            nullable=True,
            min=POWER_RANGE_DBM[0],
            max=POWER_RANGE_DBM[1],
        ),
        Column(
            "frequency_hz",
            _F64,
            "Hz",
            "Carrier frequency of its waveform (.setup)",
            nullable=True,
            min=FREQUENCY_RANGE_HZ[0],
            max=FREQUENCY_RANGE_HZ[1],
        ),
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
        Column("base_z_m", _F64, "m", "Lowest z of the building", min=Z_RANGE_M[0], max=Z_RANGE_M[1]),
        Column("roof_z_m", _F64, "m", "Highest roof z of the building", min=Z_RANGE_M[0], max=Z_RANGE_M[1]),
        Column("height_m", _F64, "m", "roof_z_m - base_z_m", min=BUILDING_HEIGHT_RANGE_M[0], max=BUILDING_HEIGHT_RANGE_M[1]),
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
        Column("base_z_m", _F64, "m", "Lowest z of the part", min=Z_RANGE_M[0], max=Z_RANGE_M[1]),
        Column("roof_z_m", _F64, "m", "Highest z of the part", min=Z_RANGE_M[0], max=Z_RANGE_M[1]),
    ),
)

#: Route points of one route are at most this far apart [m] (the sampling ``uavdata simulate --routes`` writes).
ROUTE_MAX_STEP_M = 2.0
#: Kinds of route a user can follow, with their speed [m/s] (``uavdata simulate --route-kinds``).
ROUTE_KINDS = {"pedestrian": 1.4, "vehicle": 10.0}
#: The fastest a user of each kind moves [m/s]: a route faster than its kind is refused (a running pedestrian, a car
#: on a motorway are within).
ROUTE_MAX_SPEED_MPS = {"pedestrian": 4.0, "vehicle": 45.0}

ROUTES = TableSpec(
    name="routes",
    filename="routes.parquet",
    description="One row per route point: user routes for the tracking task, each point a transmitter of the .txrx "
    "traced as a user (<name>.routes.csv).",
    columns=(
        Column("route", _I32, "", "Route id", min=0, max=1e6),
        Column("order", _I32, "", "0-based position of the point along its route", min=0, max=1e6),
        Column("time_s", _F64, "s", "When the user is at the point, from the route's start", min=0, max=1e6),
        Column("tx_set_id", _I32, "", "Transmitter set project_id of the point"),
        Column("tx_point", _I32, "", "Point number within that set, 1-based", min=1),
        Column("x_m", _F64, "m", "Position x", min=XY_RANGE_M[0], max=XY_RANGE_M[1]),
        Column("y_m", _F64, "m", "Position y", min=XY_RANGE_M[0], max=XY_RANGE_M[1]),
        Column("kind", pa.string(), "", f"Kind of route: {', '.join(ROUTE_KINDS)}"),
        Column("speed_mps", _F64, "m/s", "The user's speed along the route", min=0.1, max=100.0),
    ),
)

ALL_TABLES = (RECEIVERS, TRANSMITTERS, BUILDINGS, BUILDING_PARTS, ROUTES)

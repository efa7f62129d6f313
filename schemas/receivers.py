"""Receiver outputs: the quantities uavplace reads from ray-tracer exports, and per-file metadata."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from uavplace.schemas.base import Contract


class Quantity(Contract):
    """One value column of a receiver export.

    ``sentinel`` says how the exporter marks a receiver that no path reached:
    ``ge`` (value >= ``sentinel_value``), ``le`` (value <= it), ``threshold``
    (value <= the receiving antenna's power threshold from the .setup), or
    ``none`` (the column carries no reach information).
    """

    column: str
    unit: str
    header_names: tuple[str, ...] = Field(description="Header names, lower case without spaces")
    header_units: tuple[str, ...] = Field(description="Accepted header units, lower case")
    sentinel: Literal["ge", "le", "threshold", "none"]
    sentinel_value: float | None = None


QUANTITIES: dict[str, Quantity] = {
    q.column: q
    for q in (
        Quantity(column="power_dbm", unit="dBm", header_names=("power",), header_units=("dbm",), sentinel="threshold"),
        Quantity(column="phase_deg", unit="deg", header_names=("phase",), header_units=("deg",), sentinel="none"),
        Quantity(
            column="path_loss_db",
            unit="dB",
            header_names=("pathloss",),
            header_units=("db",),
            sentinel="ge",
            sentinel_value=250.0,
        ),
        Quantity(
            column="path_gain_db",
            unit="dB",
            header_names=("pathgain",),
            header_units=("db",),
            sentinel="le",
            sentinel_value=-250.0,
        ),
        Quantity(
            column="txloss_db",
            unit="dB",
            header_names=("transmissionloss", "txloss"),
            header_units=("db",),
            sentinel="ge",
            sentinel_value=250.0,
        ),
        Quantity(
            column="delay_spread_s",
            unit="s",
            header_names=("delayspread",),
            header_units=("sec", "s"),
            sentinel="none",
        ),
        Quantity(
            column="interference_dbm",
            unit="dBm",
            header_names=("interference",),
            header_units=("dbm",),
            sentinel="none",
        ),
        Quantity(column="noise_dbm", unit="dBm", header_names=("noise",), header_units=("dbm",), sentinel="none"),
        Quantity(column="snr_db", unit="dB", header_names=("snr",), header_units=("db",), sentinel="none"),
        Quantity(column="sir_db", unit="dB", header_names=("sir",), header_units=("db",), sentinel="none"),
        Quantity(
            column="sinr_db",
            unit="dB",
            header_names=("sinr",),
            header_units=("db",),
            sentinel="le",
            sentinel_value=-250.0,
        ),
    )
}

#: Receiver-table outputs uavplace parses: InSite output type -> its value columns, in file order.
RECEIVER_OUTPUTS: dict[str, tuple[str, ...]] = {
    "power": ("power_dbm", "phase_deg"),
    "pl": ("path_loss_db",),
    "pg": ("path_gain_db",),
    "txloss": ("txloss_db",),
    "spread": ("delay_spread_s",),
    "noise": ("interference_dbm", "noise_dbm", "snr_db", "sir_db", "sinr_db"),
}

#: InSite outputs that are recognised but not parsed (per-path or per-frequency data), with the reason.
SKIPPED_OUTPUTS: dict[str, str] = {
    "paths": "per-path output (not used by uavplace)",
    "doa": "per-path direction of arrival (not used by uavplace)",
    "dod": "per-path direction of departure (not used by uavplace)",
    "cir": "complex impulse response, per path (not used by uavplace)",
    "toa": "per-path time of arrival (not used by uavplace)",
    "mtoa": "mean time of arrival (not used by uavplace)",
    "mdoa": "mean direction of arrival (not used by uavplace)",
    "mdod": "mean direction of departure (not used by uavplace)",
    "dspower": "specular/diffuse power breakdown (total power is read from the power output)",
    "inputpower": "transmitter input power record (no receivers)",
    "fspl": "free-space path loss (not a ray-traced result)",
    "fspower": "free-space power (not a ray-traced result)",
    "xpl": "cross-polarised path loss (not used by uavplace)",
    "cef": "complex electric field (not used by uavplace)",
    "exf": "electric field vs frequency (not used by uavplace)",
    "ext": "electric field vs time (not used by uavplace)",
    "pdp": "power delay profile (not used by uavplace)",
    "erms": "electric field magnitude (not used by uavplace)",
    "terrain": "terrain profile (not used by uavplace)",
}


class ReceiverSet(Contract):
    """What one parsed receiver export held."""

    source: str = Field(description="File path, relative to the city folder")
    output: str = Field(description="InSite output type, e.g. 'pl', 'power'")
    project: str = Field(description="Project name prefix of the file name")
    header_style: Literal["insite3", "insite4", "none"]
    tx_set_id: int
    tx_point: int
    tx_set_name: str | None = None
    rx_set_id: int
    rx_set_name: str | None = None
    columns: tuple[str, ...]
    num_rows: int
    num_reached: int | None = Field(description="Rows a path reached; None if the output carries no reach info")
    power_threshold_dbm: float | None = None

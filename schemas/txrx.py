"""Transmitter/receiver definitions (.txrx) and project setup (.setup)."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, model_validator

from uavplace.schemas.base import Contract

Vec3 = tuple[float, float, float]
#: An id or index of a .txrx file: the 32-bit integers InSite writes (the tables store them as int32).
Id32 = Annotated[int, Field(ge=-(2**31), le=2**31 - 1)]
#: The most receivers along one side of a grid set (side / spacing + 1): beyond it, not a receiver grid.
MAX_GRID_SIDE = 10**7


class TxRxSet(Contract):
    """One transmitter or receiver set of a .txrx file."""

    kind: str = Field(description="InSite set kind: points, grid, polygon, route, ...")
    name: str
    project_id: Id32
    active: bool = True
    is_transmitter: bool = False
    is_receiver: bool = False
    vertices_m: tuple[Vec3, ...] = Field(description="Location vertices [m]; the corner for a grid")
    side1_m: float | None = Field(default=None, description="Grid extent along x [m]")
    side2_m: float | None = Field(default=None, description="Grid extent along y [m]")
    spacing_m: float | None = Field(default=None, description="Grid or polygon receiver spacing [m]")
    tx_power_dbm: float | None = None
    tx_antenna: Id32 | None = None
    tx_waveform: Id32 | None = None
    rx_antenna: Id32 | None = None
    source: str = Field(description="File and line the set starts at")

    @model_validator(mode="after")
    def _grid_complete(self) -> TxRxSet:
        if self.kind == "grid":
            if self.side1_m is None or self.side2_m is None or self.spacing_m is None or not self.vertices_m:
                raise ValueError(f"grid '{self.name}' needs side1, side2, spacing and a corner vertex")
            if not self.spacing_m > 0:
                raise ValueError(f"grid '{self.name}' has spacing {self.spacing_m}, must be > 0")
            if not max(abs(self.side1_m), abs(self.side2_m)) / self.spacing_m < MAX_GRID_SIDE:
                raise ValueError(
                    f"grid '{self.name}' has spacing {self.spacing_m:g} m for sides {self.side1_m:g} x "
                    f"{self.side2_m:g} m: over {MAX_GRID_SIDE:,} receivers a side"
                )
        return self

    @property
    def grid_shape(self) -> tuple[int, int] | None:
        """(num_x, num_y) receivers of a grid set, x varying fastest; None for other kinds."""
        if self.kind != "grid":
            return None
        assert self.side1_m is not None and self.side2_m is not None and self.spacing_m is not None
        eps = 1e-6
        return (
            int(math.floor(self.side1_m / self.spacing_m + eps)) + 1,
            int(math.floor(self.side2_m / self.spacing_m + eps)) + 1,
        )


class Transmitter(Contract):
    """A transmitter point: a ground user in uavplace's problem."""

    tx_set_id: int
    tx_point: int = Field(ge=1)
    set_name: str | None = None
    x_m: float | None = None
    y_m: float | None = None
    z_m: float | None = None
    power_dbm: float | None = None
    frequency_hz: float | None = Field(default=None, gt=0)
    antenna: str | None = None
    source: str


class WaveformInfo(Contract):
    number: int
    name: str
    carrier_frequency_hz: float = Field(gt=0)
    bandwidth_hz: float | None = None


class AntennaInfo(Contract):
    number: int
    name: str
    type: str | None = None
    polarization: str | None = None
    power_threshold_dbm: float | None = Field(default=None, description="Power below which InSite reports no path")


class CommSystemInfo(Contract):
    """An InSite communication system: the part that computes SINR."""

    number: int
    name: str
    noise_power_density_dbm_hz: float | None = None
    uniform_interference_dbm: float | None = None
    base_stations: tuple[int, ...] = ()
    interferers: tuple[int, ...] = ()
    receivers: tuple[int, ...] = ()


class FeatureFile(Contract):
    kind: Literal["city", "terrain", "object", "floorplan", "foliage", "other"]
    filename: str
    active: bool = True


class SetupInfo(Contract):
    """What uavplace takes from an InSite .setup."""

    project_name: str
    longitude: float | None = None
    latitude: float | None = None
    waveforms: tuple[WaveformInfo, ...] = ()
    antennas: tuple[AntennaInfo, ...] = ()
    comm_systems: tuple[CommSystemInfo, ...] = ()
    features: tuple[FeatureFile, ...] = ()
    txrx_files: tuple[str, ...] = ()
    source: str

    def antenna(self, number: int | None) -> AntennaInfo | None:
        return next((a for a in self.antennas if a.number == number), None)

    def waveform(self, number: int | None) -> WaveformInfo | None:
        return next((w for w in self.waveforms if w.number == number), None)

"""What the UAV knows of a city, on one grid: the public inputs of every tier's prediction (``Scene``).

Arrays are ``[num_y, num_x]`` like the bundle's (``iy = 0`` the southern edge); cells are ``(iy, ix)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavplace.dataset.bundle import Bundle, public_settings
from uavplace.schemas.constants import CARRIER_HZ, PAPER_NOISE_DBM, TX_POWER_DBM

#: Speed of light [m/s].
C_M_S = 299_792_458.0


@dataclass(frozen=True)
class Scene:
    """What the UAV knows of a city, on one grid: the public inputs of a prediction."""

    ground_height_m: np.ndarray  # [num_y, num_x] building height above the ground [m], 0 where none
    spacing_m: float
    altitude_m: float
    frequency_hz: float
    tx_power_dbm: float
    noise_dbm: float
    floor_db: float

    @property
    def wavelength_m(self) -> float:
        return C_M_S / self.frequency_hz

    @classmethod
    def from_settings(cls, settings: dict, heights_rel_m: np.ndarray) -> Scene:
        """The scene of a city's public settings (``dataset.bundle.public_settings``) over heights ``heights_rel_m`` [num_y,
        num_x] (building height minus altitude; ``-altitude`` everywhere is open ground, the map ablation). Settings a
        bundle leaves open take the paper's: 800 MHz, 20 dBm, -104 dBm."""

        def given(name: str, default: float) -> float:
            return float(default if settings[name] is None else settings[name])

        altitude = float(settings["altitude_m"])
        ground = np.maximum(np.asarray(heights_rel_m, np.float32) + np.float32(altitude), 0).astype(np.float32)
        return cls(
            ground_height_m=ground,
            spacing_m=float(settings["spacing_m"]),
            altitude_m=altitude,
            frequency_hz=given("frequency_hz", CARRIER_HZ),
            tx_power_dbm=given("tx_power_dbm", TX_POWER_DBM),
            noise_dbm=given("noise_dbm", PAPER_NOISE_DBM),
            floor_db=float(settings["floor_db"]),
        )

    @classmethod
    def of(cls, bundle: Bundle) -> Scene:
        """The scene of ``bundle`` with its buildings: its public settings (the carrier the users', one for all; the
        power and noise the manifest's)."""
        return cls.from_settings(public_settings(bundle), bundle.height_rel_m)

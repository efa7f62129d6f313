"""The physical and task defaults, declared once: every model, command and the predictor reads them here, and the
one rule that says which cells reach the SINR target.

The paper's setting (docs/method.md): a 4 m grid at a 10 m altitude, P_T = 5 dB, 500 moves at test, users at 1.5 m
transmitting 20 dBm on an 800 MHz carrier, noise plus interference -104 dBm. The embedded cities and the shipped
agents are calibrated at -75 dBm instead (``EMBEDDED_NOISE_DBM``; docs/data.md).
"""

from __future__ import annotations

import numpy as np

#: The SINR target P_T [dB]: a cell at or above it serves the user.
P_T_DB = 5.0
#: The step budget of an evaluation episode (the paper's at test).
T_MAX = 500
#: The receiver grid's spacing [m] and the UAV's altitude above the ground [m].
GRID_M, ALTITUDE_M = 4.0, 10.0
#: The users' carrier [Hz], transmit power [dBm] and height above the ground [m].
CARRIER_HZ, TX_POWER_DBM, USER_HEIGHT_M = 800e6, 20.0, 1.5
#: Noise plus interference [dBm]: the paper's, and the level of the embedded cities and the shipped agents.
PAPER_NOISE_DBM, EMBEDDED_NOISE_DBM = -104.0, -75.0


def reaches_target(
    sinr_db: np.ndarray | float, p_t_db: float, dead: np.ndarray | None = None, legal: np.ndarray | None = None
) -> np.ndarray:
    """Which cells (or measurements) reach P_T: an SINR at or above ``p_t_db``, on a cell no path missed (``dead``
    False) that the UAV may enter (``legal``), where those are given. The one home of the rule."""
    out = np.asarray(sinr_db) >= p_t_db
    if dead is not None:
        out = out & ~np.asarray(dead)
    if legal is not None:
        out = out & np.asarray(legal)
    return out

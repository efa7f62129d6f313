"""A bundle in the formats of the neighbouring field: a RadioMapSeer-style folder and a DeepMIMO-style array file.

**RadioMapSeer-style folder** (``write_radiomapseer``; the layout of Levie et al.'s RadioMapSeer: a building map per
city, an antenna map and a radio map per transmitter, as PNG), ``OUT/<city>/``:

- ``png/buildings_complete/<city>.png``: 8-bit gray, 255 where the UAV may not enter (a building at its altitude),
  0 elsewhere;
- ``png/heights/<city>.png``: 16-bit gray, the building height above the ground in centimetres (0: open ground);
- ``png/antennas/<city>_<u>.png``: 8-bit gray, 255 at the cell of user ``u`` (the transmitter), 0 elsewhere;
- ``gain/<city>_<u>.png``: 8-bit gray, user ``u``'s SINR at the UAV altitude: 0 a dead cell (no path), else ``v``:
  the SINR ``floor + (v - 1) x step`` dB, to the nearest step (``dataset.trainmaps``' quantisation; 0.5 dB);
- ``users.csv``: ``user, x_m, y_m, row, col``: each user's position and its pixel;
- ``scale.json``: the format, the SINR scale (floor, step, what 0 means), the grid (origin, spacing, size), the
  altitude, carrier, transmit power and noise, and the frame.

Frame: x east, y north, metres, in the bundle's coordinates; pixel ``(row, col)`` is the cell whose centre is
``x = x_min + (col + 1/2) spacing``, ``y = y_max - (row + 1/2) spacing``: row 0 is the northernmost (north up, as
an image is viewed). ``read_radiomapseer`` reads such a folder back (``TrainingMaps``), so that external radio-map
data sets in this layout can train the map searcher's predictor.

**DeepMIMO-style array file** (``write_deepmimo``; DeepMIMO's per-user arrays of positions and received power),
``OUT/<city>.deepmimo.npz``: ``tx_positions_m`` [U, 3] (the users: the transmitters, 1.5 m above the ground),
``rx_positions_m`` [M, 3] (the UAV cells' centres at the altitude, the cells in row-major order of the grid, x
fastest), ``rx_power_dbm`` [U, M], ``path_loss_db`` [U, M] (transmit power minus received power) and ``sinr_db``
[U, M] (NaN where no path reached the cell), ``blocked`` [M] (the UAV may not enter), and ``meta``: JSON of the units,
frame and settings.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from uavplace.dataset.bundle import Bundle, public_settings
from uavplace.dataset.trainmaps import STEP_DB, TrainingMaps, dequantise, quantise
from uavplace.infra.files import atomic_directory, atomic_write_bytes, check_own_npz
from uavplace.ingest.radiomapseer import RADIOMAPSEER, USER_HEIGHT_M, read_folder


def _png(array: np.ndarray) -> bytes:
    """A gray PNG of a 2-D uint8 (8-bit) or uint16 (16-bit) array."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(array)).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def write_radiomapseer(bundle: Bundle, out: str | Path) -> Path:
    """Write ``bundle`` as a RadioMapSeer-style folder ``out/<city>/`` (the module's docstring; the folder replaced only
    if it is one of these, written whole or not at all)."""
    g, settings = bundle.manifest.grid, public_settings(bundle)
    floor = bundle.sinr_floor_db
    final = Path(out) / bundle.city
    with atomic_directory(final, marker="scale.json", what="RadioMapSeer-style folder") as tmp:
        for sub in ("png/buildings_complete", "png/heights", "png/antennas", "gain"):
            (tmp / sub).mkdir(parents=True)
        (tmp / "png/buildings_complete" / f"{bundle.city}.png").write_bytes(
            _png(np.flipud(bundle.blocked).astype(np.uint8) * 255)
        )
        ground = np.maximum(bundle.height_rel_m + bundle.altitude_m, 0)
        cm = np.clip(np.rint(ground * 100), 0, 65535).astype(np.uint16)
        (tmp / "png/heights" / f"{bundle.city}.png").write_bytes(_png(np.flipud(cm)))
        table = bundle.users.set_index("user")
        rows = [["user", "x_m", "y_m", "row", "col"]]
        for u in bundle.user_indices():
            iy, ix = (int(v) for v in bundle.user_cells([u])[0])
            antenna = np.zeros(g.shape, np.uint8)
            antenna[iy, ix] = 255
            (tmp / "png/antennas" / f"{bundle.city}_{u}.png").write_bytes(_png(np.flipud(antenna)))
            q, _ = quantise(bundle.sinr_db[u], bundle.dead[u], floor)
            (tmp / "gain" / f"{bundle.city}_{u}.png").write_bytes(_png(np.flipud(q)))
            rows.append([u, f"{table.at[u, 'x_m']:.3f}", f"{table.at[u, 'y_m']:.3f}", g.num_y - 1 - iy, ix])
        text = io.StringIO()
        csv.writer(text, lineterminator="\n").writerows(rows)
        (tmp / "users.csv").write_text(text.getvalue(), encoding="utf-8")
        scale = {
            "format": RADIOMAPSEER,
            "city": bundle.city,
            "bundle_version": bundle.version,
            "sinr": {
                "zero": "dead: no path reached the cell",
                "floor_db": floor,
                "step_db": STEP_DB,
                "value_db": "floor_db + (pixel - 1) * step_db",
            },
            "heights": "building height above the ground [cm], 16-bit",
            "grid": {
                "x_min_m": g.x_min_m,
                "y_min_m": g.y_min_m,
                "spacing_m": g.spacing_m,
                "num_x": g.num_x,
                "num_y": g.num_y,
            },
            "frame": "x east, y north [m]; pixel (row, col) is the cell centred at x = x_min_m + (col + 0.5) spacing_m, "
            "y = y_min_m + (num_y - row - 0.5) spacing_m: row 0 is the northernmost",
            "settings": settings,
        }
        (tmp / "scale.json").write_text(json.dumps(scale, indent=2) + "\n", encoding="utf-8")
    return final


def read_radiomapseer(folder: str | Path) -> TrainingMaps:
    """A RadioMapSeer-style folder (``write_radiomapseer``'s layout; ``ingest.radiomapseer.read_folder``) as
    ``TrainingMaps``; ``InputError`` naming the file and field of the first problem."""
    m = read_folder(folder)
    sinr, dead = dequantise(m.codes, m.floor_db, m.step_db)
    settings = m.settings | {"floor_db": m.floor_db}
    height_rel = (m.ground_m - float(m.settings["altitude_m"])).astype(np.float32)
    provenance = np.zeros(m.codes.shape, np.uint8)
    return TrainingMaps(m.city, m.version, settings, height_rel, m.blocked, m.cells, sinr, dead, provenance)


def write_deepmimo(bundle: Bundle, out: str | Path) -> Path:
    """Write ``bundle`` as a DeepMIMO-style array file ``out/<city>.deepmimo.npz`` (the module's docstring)."""
    settings = public_settings(bundle)
    users = bundle.user_indices()
    table = bundle.users.set_index("user")
    tx = np.stack([table.loc[users, "x_m"], table.loc[users, "y_m"], np.full(len(users), USER_HEIGHT_M)], axis=1)
    yy, xx = np.meshgrid(bundle.y_m, bundle.x_m, indexing="ij")
    rx = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, bundle.altitude_m)], axis=1)
    dead = bundle.dead[users].reshape(len(users), -1)
    sinr = np.where(dead, np.nan, bundle.sinr_db[users].reshape(len(users), -1)).astype(np.float32)
    noise, power = settings["noise_dbm"], settings["tx_power_dbm"]
    rx_power = (sinr + np.float32(noise)).astype(np.float32)
    meta = {
        "format": "uavplace-deepmimo/1",
        "city": bundle.city,
        "bundle_version": bundle.version,
        "units": {"positions": "m", "rx_power_dbm": "dBm", "path_loss_db": "dB", "sinr_db": "dB"},
        "frame": "x east, y north, z up [m] in the bundle's coordinates; rx cells in row-major order, x fastest",
        "no_path": "NaN",
        "received_power": "SINR + noise (noise plus background interference, the bundle's noise_dbm)",
        "settings": settings,
    }
    arrays = {
        "tx_positions_m": tx.astype(np.float64),
        "rx_positions_m": rx.astype(np.float64),
        "rx_power_dbm": rx_power,
        "path_loss_db": (np.float32(power) - rx_power).astype(np.float32) if power is not None else rx_power * np.nan,
        "sinr_db": sinr,
        "blocked": bundle.blocked.ravel(),
        "meta": np.frombuffer(json.dumps(meta).encode(), np.uint8),
    }
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    path = Path(out) / f"{bundle.city}.deepmimo.npz"
    check_own_npz(path, "uavplace-deepmimo/", "DeepMIMO-style export")
    atomic_write_bytes(path, buf.getvalue())
    return path

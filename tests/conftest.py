"""Shared test helpers: where the real Wireless InSite fixtures are, and writers of synthetic exports."""

from __future__ import annotations

import gzip
import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
FIXTURES = Path(os.environ.get("UAVPLACE_FIXTURES", REPO.parent / "shared" / "fixtures" / "wireless-insite"))


def fixture_dir(name: str) -> Path:
    """A real fixture folder; the calling test skips, saying why, if it is absent."""
    path = FIXTURES / name
    if not path.is_dir():
        pytest.skip(f"real Wireless InSite fixture {path} not found (set UAVPLACE_FIXTURES to its folder)")
    return path


@pytest.fixture
def rosslyn() -> Path:
    return fixture_dir("lasse-2018-rosslyn")


@pytest.fixture
def deepmimo() -> Path:
    return fixture_dir("deepmimo-2025-grid")


@pytest.fixture
def boxes() -> Path:
    return fixture_dir("halosnoopy-2023-boxes")


GRID_TXRX = """begin_<points> User
project_id 1
active
begin_<location>
nVertices {n_tx}
{tx_lines}
end_<location>
is_transmitter yes
is_receiver no
begin_<transmitter>
begin_<pattern>
antenna 0
waveform 0
end_<pattern>
power 20.00000
end_<transmitter>
end_<points>
begin_<grid> Drone_grid
project_id 2
active
begin_<location>
side1 {side1}
side2 {side2}
spacing {spacing}
nVertices 1
{x0} {y0} {z}
end_<location>
is_transmitter no
is_receiver yes
begin_<receiver>
begin_<pattern>
antenna 0
waveform 0
end_<pattern>
end_<receiver>
end_<grid>
"""

SETUP = """Format type:keyword version: 1.1.0
begin_<project> synthetic
begin_<globals>
longitude 0
latitude 0
end_<globals>
begin_<antenna> Half-wave dipole
antenna 0
type HalfWaveDipole
polarization vertical
power_threshold -250
end_<antenna>
begin_<Waveform> Sinusoid
waveform 0
CarrierFrequency 800000000.000
bandwidth 1000000.000
end_<Waveform>
end_<project>
"""


def write_grid_city(
    folder: Path,
    *,
    nx: int = 6,
    ny: int = 5,
    spacing: float = 4.0,
    n_tx: int = 2,
    outputs: tuple[str, ...] = ("pl",),
    gz: bool = False,
    crlf: bool = False,
    seed: int = 0,
) -> Path:
    """A small InSite-like city: a .txrx (users + one receiver grid), a .setup and receiver outputs."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    x0, y0, z = 10.0, -20.0, 10.0
    tx = [(x0 + 3.0 * i, y0 + 2.0, 1.5) for i in range(n_tx)]
    (folder / "city.txrx").write_text(
        GRID_TXRX.format(
            n_tx=n_tx,
            tx_lines="\n".join(f"{x:.6f} {y:.6f} {zz:.6f}" for x, y, zz in tx),
            side1=(nx - 1) * spacing,
            side2=(ny - 1) * spacing,
            spacing=spacing,
            x0=x0,
            y0=y0,
            z=z,
        )
    )
    (folder / "city.setup").write_text(SETUP)
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny))
    xs, ys = x0 + ix.ravel() * spacing, y0 + iy.ravel() * spacing
    for t in range(1, n_tx + 1):
        dist = np.hypot(xs - tx[t - 1][0], ys - tx[t - 1][1]) + 1.0
        pl = 40 + 20 * np.log10(dist) + rng.uniform(0, 10, dist.size)
        dead = rng.random(dist.size) < 0.2
        pl[dead] = 250.0
        for output in outputs:
            if output == "pl":
                header = "# <X(m)> <Y(m)> <Z(m)> <Distance(m)> <PathLoss(dB)>"
                values = [f"{v:g}" for v in pl]
            elif output == "power":
                header = "# <X(m)> <Y(m)> <Z(m)> <Distance(m)> <Power(dBm)> <Phase(deg)>"
                values = [("-250 0" if d else f"{20 - v:g} {rng.uniform(-180, 180):.3f}") for v, d in zip(pl, dead, strict=True)]
            else:
                raise ValueError(output)
            lines = [
                f"# <Transmitter Set: Tx: 1 User - Point {t}>",
                "# <Receiver Set: Rx: 2 Drone_grid>",
                header,
            ] + [f"{k + 1} {x:g} {y:g} {z:g} {d:g} {v}" for k, (x, y, d, v) in enumerate(zip(xs, ys, dist, values, strict=True))]
            text = ("\r\n" if crlf else "\n").join(lines) + ("\r\n" if crlf else "\n")
            name = f"city.{output}.t{t:03d}_01.r002.p2m"
            if gz:
                with gzip.open(folder / f"{name}.gz", "wt", newline="") as f:
                    f.write(text)
            else:
                (folder / name).write_bytes(text.encode())
    return folder

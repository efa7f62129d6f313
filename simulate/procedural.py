"""A seeded generator of medium-elevation urban areas: blocks, streets, lots, buildings, users.

The city is a rectangle ``[0, size_x] x [0, size_y]`` [m]. Streets cut it into
blocks; each block is split into one to four lots; most lots carry a
rectangular building set back from the lot edges (some lots stay open:
squares, car parks). A ``low_share`` of buildings is lower than the UAV
altitude (the UAV may fly over them), the rest is taller. Users stand at
1.5 m, outside buildings, spread uniformly over the open ground.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

#: Preset sizes [m] (x, y): the paper's training (~550 x 500) and test (~400 x 500) cities, a tiny one for
#: tests, and ``open``: ground only, no building (the physics check against the two-ray model).
PRESETS: dict[str, tuple[float, float]] = {
    "train": (552.0, 500.0),
    "test": (400.0, 500.0),
    "tiny": (96.0, 80.0),
    "open": (240.0, 40.0),
}
USER_HEIGHT_M = 1.5


@dataclass(frozen=True)
class CityStyle:
    """Parameters of the generator (all lengths in metres)."""

    block_m: tuple[float, float] = (36.0, 72.0)
    street_m: tuple[float, float] = (10.0, 18.0)
    setback_m: tuple[float, float] = (1.0, 4.0)
    open_lot_share: float = 0.12
    low_share: float = 0.3
    low_height_m: tuple[float, float] = (4.0, 9.0)
    high_height_m: tuple[float, float] = (12.0, 45.0)
    min_clearance_m: float = 2.0


@dataclass(frozen=True)
class City:
    size_m: tuple[float, float]
    footprints: tuple[shapely.Polygon, ...]
    heights_m: tuple[float, ...]
    users_m: np.ndarray  # [num_users, 3]


def _cuts(length: float, rng: np.random.Generator, style: CityStyle) -> list[tuple[float, float]]:
    """Block intervals along one axis, separated by streets (a half street at each edge)."""
    blocks = []
    pos = rng.uniform(*style.street_m) / 2
    while True:
        width = rng.uniform(*style.block_m)
        if pos + width > length - style.street_m[0] / 2:
            if length - style.street_m[0] / 2 - pos >= style.block_m[0] / 2:
                blocks.append((pos, length - style.street_m[0] / 2))
            break
        blocks.append((pos, pos + width))
        pos += width + rng.uniform(*style.street_m)
    return blocks


def generate_city(size_m: tuple[float, float], num_users: int, seed: int, style: CityStyle | None = None) -> City:
    """A city of ``size_m`` with ``num_users`` users; the same seed gives the same city."""
    style = style or CityStyle()
    rng = np.random.default_rng(seed)
    footprints: list[shapely.Polygon] = []
    for x0, x1 in _cuts(size_m[0], rng, style):
        for y0, y1 in _cuts(size_m[1], rng, style):
            nx = 2 if x1 - x0 > style.block_m[0] * 1.2 and rng.random() < 0.6 else 1
            ny = 2 if y1 - y0 > style.block_m[0] * 1.2 and rng.random() < 0.6 else 1
            xs = np.sort(np.r_[x0, rng.uniform(x0 + 0.4 * (x1 - x0), x0 + 0.6 * (x1 - x0), nx - 1), x1])
            ys = np.sort(np.r_[y0, rng.uniform(y0 + 0.4 * (y1 - y0), y0 + 0.6 * (y1 - y0), ny - 1), y1])
            for i in range(nx):
                for j in range(ny):
                    if rng.random() < style.open_lot_share:
                        continue
                    s = rng.uniform(*style.setback_m, size=4)
                    box = shapely.box(xs[i] + s[0], ys[j] + s[1], xs[i + 1] - s[2], ys[j + 1] - s[3])
                    if box.area > 16.0:
                        footprints.append(box)
    low = rng.random(len(footprints)) < style.low_share
    heights = np.where(low, rng.uniform(*style.low_height_m, len(footprints)), rng.uniform(*style.high_height_m, len(footprints)))
    heights = np.round(heights, 1)
    users = sample_users(size_m, footprints, num_users, rng, clearance_m=style.min_clearance_m)
    return City(size_m=size_m, footprints=tuple(footprints), heights_m=tuple(float(h) for h in heights), users_m=users)


def sample_users(
    size_m: tuple[float, float],
    footprints: list[shapely.Polygon] | tuple[shapely.Polygon, ...],
    num_users: int,
    rng: np.random.Generator,
    clearance_m: float = 2.0,
    margin_m: float = 8.0,
) -> np.ndarray:
    """``[num_users, 3]`` positions uniform over open ground (``clearance_m`` from any building), at 1.5 m."""
    blocked = shapely.union_all(list(footprints)).buffer(clearance_m) if len(footprints) else shapely.Polygon()
    out = np.empty((0, 2))
    for _ in range(100):
        cand = np.c_[
            rng.uniform(margin_m, size_m[0] - margin_m, 4 * num_users), rng.uniform(margin_m, size_m[1] - margin_m, 4 * num_users)
        ]
        free = ~shapely.contains_xy(blocked, cand[:, 0], cand[:, 1]) if not blocked.is_empty else np.ones(len(cand), bool)
        out = np.vstack([out, cand[free]])
        if len(out) >= num_users:
            break
    if len(out) < num_users:
        raise ValueError(f"could not place {num_users} users on the open ground of a {size_m[0]:g} x {size_m[1]:g} m city")
    return np.c_[out[:num_users], np.full(num_users, USER_HEIGHT_M)]

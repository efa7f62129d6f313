"""Procedural city styles (generator v2): seeded layouts beside the original box grid.

Each style lays out buildings in ``[0, size_x] x [0, size_y]`` [m] and
returns its building parts: ``(footprint, roof height above ground [m],
building index)``; a building of several parts is a stepped one (a tower on a
podium). The same style, size and seed give the same city. Every style draws
its own density, street widths and height distribution from the seed, within
ranges chosen so that the corpus spans the real cities it is meant to cover
(blocked shares of roughly 15-55 % of cells at a 10 m altitude, median
heights 8-30 m, courtyards in the perimeter style).

- ``grid``: today's generator (``procedural.generate_city``): streets, blocks, lots, box buildings.
- ``rotated``: a grid at a random angle, with irregular block sizes.
- ``perimeter``: European perimeter blocks: buildings along the block edges around open courtyards.
- ``towers``: towers on podiums, among lower buildings.
- ``organic``: Voronoi blocks of irregular shape, some left open as plazas and parks.
- ``plazas``: a grid with large open squares and parks.
- ``oldtown``: a historic centre: small irregular blocks between narrow lanes (3-9 m), a few
  piazzas, mid-rise buildings of similar height, each block split into several buildings.
- ``tiered``: the real scenes' kind of geometry (etoile, florence: a few dozen buildings in hundreds of
  roof tiers): large irregular blocks (60-120 m apart) between streets of 10-30 m, most around a
  courtyard, each block one building cut into several roof tiers of heights around its own.

``mixed`` takes the first six styles in turn by seed (seed modulo 6; ``MIXED``), so that a
corpus of consecutive seeds covers them evenly; a style added later never changes a mixed city.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import shapely
import shapely.ops

from uavplace.simulate.procedural import CityStyle, generate_city

Part = tuple[shapely.Polygon, float, int]  # footprint, roof height [m], building index
STYLES: dict[str, Callable[[tuple[float, float], np.random.Generator], list[Part]]] = {}
#: Size of a styled city when the source names none [m].
STYLE_SIZE_M = (400.0, 400.0)


def style(name: str):  # noqa: ANN201 - a decorator
    def register(fn):  # noqa: ANN001, ANN202
        STYLES[name] = fn
        return fn

    return register


def _heights(
    rng: np.random.Generator, n: int, low_share: float, low: tuple[float, float], high: tuple[float, float]
) -> np.ndarray:
    is_low = rng.random(n) < low_share
    return np.round(np.where(is_low, rng.uniform(*low, n), rng.uniform(*high, n)), 1)


def _inside(size: tuple[float, float]) -> shapely.Polygon:
    return shapely.box(0.0, 0.0, *size)


def _clean(polys, area: shapely.Polygon, min_area: float = 16.0) -> list[shapely.Polygon]:  # noqa: ANN001
    """Polygons clipped to ``area``, split into parts, small slivers dropped."""
    out = []
    for p in polys:
        for g in shapely.get_parts(shapely.intersection(p, area)):
            if g.geom_type == "Polygon" and g.area >= min_area:
                out.append(shapely.normalize(g))
    return out


def _voronoi_blocks(size: tuple[float, float], rng: np.random.Generator, spacing: float) -> list[shapely.Polygon]:
    """The Voronoi cells of seeds drawn uniformly over the city, about ``spacing`` [m] apart (two at least)."""
    n = max(2, int(size[0] * size[1] / spacing**2))
    seeds = shapely.MultiPoint(np.c_[rng.uniform(0, size[0], n), rng.uniform(0, size[1], n)])
    return list(shapely.get_parts(shapely.voronoi_polygons(seeds, extend_to=_inside(size))))


@style("grid")
def _grid(size: tuple[float, float], rng: np.random.Generator) -> list[Part]:
    params = CityStyle(
        block_m=(rng.uniform(28, 40), rng.uniform(60, 90)),
        street_m=(rng.uniform(8, 14), rng.uniform(14, 36)),
        open_lot_share=rng.uniform(0.05, 0.25),
        low_share=rng.uniform(0.15, 0.45),
        high_height_m=(12.0, rng.uniform(30, 60)),
    )
    city = generate_city(size, 0, int(rng.integers(2**31)), params)
    return [(f, h, k) for k, (f, h) in enumerate(zip(city.footprints, city.heights_m, strict=True))]


@style("rotated")
def _rotated(size: tuple[float, float], rng: np.random.Generator) -> list[Part]:
    side = float(np.hypot(*size)) + 40.0  # a grid over a square that covers the city at any angle
    inner = _grid((side, side), rng)
    angle = rng.uniform(10, 80)
    centre = shapely.Point(side / 2, side / 2)
    shift = ((size[0] - side) / 2, (size[1] - side) / 2)
    area = _inside(size)
    out: list[Part] = []
    for poly, h, k in inner:
        moved = shapely.affinity.translate(shapely.affinity.rotate(poly, angle, origin=centre), *shift)
        out += [(p, h, k) for p in _clean([moved], area)]
    return out


@style("perimeter")
def _perimeter(size: tuple[float, float], rng: np.random.Generator) -> list[Part]:
    block = (rng.uniform(50, 70), rng.uniform(80, 120))
    street = (rng.uniform(6, 10), rng.uniform(12, 24))
    depth = rng.uniform(10, 22)  # building depth from the street
    params = CityStyle(block_m=block, street_m=street)
    from uavplace.simulate.procedural import _cuts

    out: list[Part] = []
    k = 0
    for x0, x1 in _cuts(size[0], rng, params):
        for y0, y1 in _cuts(size[1], rng, params):
            outer = shapely.box(x0, y0, x1, y1)
            court = shapely.box(x0 + depth, y0 + depth, x1 - depth, y1 - depth)
            ring = outer.difference(court) if court.area > 0 and rng.random() < 0.9 else outer
            # Split the ring into buildings of varying height along the block edges.
            n = int(rng.integers(4, 10))
            angles = np.sort(rng.uniform(0, 2 * np.pi, n))
            cx, cy, r = (x0 + x1) / 2, (y0 + y1) / 2, float(np.hypot(x1 - x0, y1 - y0))
            heights = _heights(rng, n, low_share=0.1, low=(6.0, 9.5), high=(12.0, rng.uniform(20, 30)))
            for i in range(n):
                a0, a1 = angles[i], angles[(i + 1) % n] + (2 * np.pi if i == n - 1 else 0)
                arc = np.linspace(a0, a1, 8)
                wedge = shapely.Polygon([(cx, cy), *[(cx + r * np.cos(a), cy + r * np.sin(a)) for a in arc]])
                for piece in _clean([shapely.intersection(ring, wedge)], _inside(size)):
                    out.append((piece, float(heights[i]), k))
                    k += 1
    return out


@style("towers")
def _towers(size: tuple[float, float], rng: np.random.Generator) -> list[Part]:
    base = _grid(size, rng)
    out: list[Part] = []
    for poly, h, k in base:
        minx, miny, maxx, maxy = poly.bounds
        w, d = maxx - minx, maxy - miny
        if min(w, d) > 20 and rng.random() < 0.45:  # a podium with a tower on it
            podium = float(rng.uniform(6, 14))
            tw, td = w * rng.uniform(0.3, 0.5), d * rng.uniform(0.3, 0.5)
            tx, ty = rng.uniform(minx, maxx - tw), rng.uniform(miny, maxy - td)
            tower = shapely.box(tx, ty, tx + tw, ty + td)
            out.append((shapely.normalize(poly.difference(tower)), podium, k))
            out.append((tower, float(np.round(rng.uniform(35, 100), 1)), k))
        else:
            out.append((poly, h, k))
    return out


@style("organic")
def _organic(size: tuple[float, float], rng: np.random.Generator) -> list[Part]:
    area = _inside(size)
    spacing = rng.uniform(35, 60)
    n = int(size[0] * size[1] / spacing**2)
    seeds = shapely.MultiPoint(np.c_[rng.uniform(0, size[0], n), rng.uniform(0, size[1], n)])
    cells = shapely.get_parts(shapely.voronoi_polygons(seeds, extend_to=area))
    street = rng.uniform(5, 14)
    open_share = rng.uniform(0.08, 0.25)
    heights = _heights(rng, len(cells), low_share=rng.uniform(0.2, 0.5), low=(4.0, 9.5), high=(12.0, rng.uniform(25, 45)))
    out: list[Part] = []
    for k, cell in enumerate(cells):
        if rng.random() < open_share:
            continue  # a plaza or a park
        shrunk = cell.buffer(-street / 2, join_style="mitre")
        out += [(p, float(heights[k]), k) for p in _clean([shrunk], area)]
    return out


@style("plazas")
def _plazas(size: tuple[float, float], rng: np.random.Generator) -> list[Part]:
    base = _grid(size, rng)
    n = int(rng.integers(2, 5))
    squares = shapely.union_all(
        [shapely.Point(rng.uniform(0, size[0]), rng.uniform(0, size[1])).buffer(rng.uniform(25, 55)) for _ in range(n)]
    )
    return [(p, h, k) for poly, h, k in base for p in _clean([poly.difference(squares)], _inside(size))]


@style("oldtown")
def _oldtown(size: tuple[float, float], rng: np.random.Generator) -> list[Part]:
    area = _inside(size)
    cells = _voronoi_blocks(size, rng, rng.uniform(24, 40))  # small blocks
    open_share = rng.uniform(0.03, 0.12)
    top = rng.uniform(18, 28)
    out: list[Part] = []
    k = 0
    for cell in cells:
        if rng.random() < open_share:
            continue  # a piazza
        lane = rng.uniform(3, 9)  # each block has its own lanes: alleys and streets
        block = cell.buffer(-lane / 2, join_style="mitre")
        if block.is_empty:
            continue
        # Split the block into buildings by a few random cuts through it, each with its own height.
        pieces = [block]
        for _ in range(int(rng.integers(1, 4))):
            c = block.centroid
            angle = rng.uniform(0, np.pi)
            dx, dy = np.cos(angle) * 200, np.sin(angle) * 200
            cut = shapely.LineString([(c.x - dx + rng.normal(0, 4), c.y - dy), (c.x + dx, c.y + dy + rng.normal(0, 4))])
            pieces = [g for p in pieces for g in shapely.get_parts(shapely.ops.split(p, cut))]
        heights = _heights(rng, len(pieces), low_share=0.15, low=(6.0, 9.5), high=(11.0, top))
        for piece, h in zip(pieces, heights, strict=True):
            for p in _clean([piece], area):
                out.append((p, float(h), k))
                k += 1
    return out


@style("tiered")
def _tiered(size: tuple[float, float], rng: np.random.Generator) -> list[Part]:
    area = _inside(size)
    spacing = rng.uniform(60, 120)  # few large blocks, each one building of many roof tiers
    cells = _voronoi_blocks(size, rng, spacing)
    street = rng.uniform(10, 30)
    open_share = rng.uniform(0.03, 0.15)
    out: list[Part] = []
    for k, cell in enumerate(cells):
        if rng.random() < open_share:
            continue  # a square or a park
        block = cell.buffer(-street / 2, join_style="mitre")
        if block.is_empty:
            continue
        depth = rng.uniform(12, 22)
        court = block.buffer(-depth, join_style="mitre")
        if not court.is_empty and rng.random() < 0.7:  # a courtyard
            block = block.difference(court)
        pieces = [block]  # the roof tiers: the block cut by a few random lines, each piece at its own height
        for _ in range(int(rng.integers(2, 5))):
            c = block.centroid
            angle = rng.uniform(0, np.pi)
            dx, dy = np.cos(angle) * 400, np.sin(angle) * 400
            offset = rng.normal(0, spacing / 6, 2)
            cut = shapely.LineString([(c.x - dx + offset[0], c.y - dy + offset[1]), (c.x + dx + offset[0], c.y + dy + offset[1])])
            pieces = [g for p in pieces for g in shapely.get_parts(shapely.ops.split(p, cut))]
        base = rng.uniform(12, 28)
        low = rng.random(len(pieces)) < 0.15  # annexes and low wings
        heights = np.where(low, rng.uniform(4, 9, len(pieces)), np.maximum(6.0, base + rng.normal(0, 3.5, len(pieces))))
        for piece, h in zip(pieces, np.round(heights, 1), strict=True):
            out += [(p, float(h), k) for p in _clean([piece], area)]
    return out


#: The styles ``mixed`` takes in turn by seed (frozen: the corpus's recipe names its cities by seed).
MIXED = ("grid", "organic", "perimeter", "plazas", "rotated", "towers")


def styled_city(name: str, size: tuple[float, float], seed: int) -> tuple[str, list[Part]]:
    """(the style used, its parts) of a seeded city; ``mixed`` takes the ``MIXED`` styles in turn by seed."""
    rng = np.random.default_rng([seed, 7])
    if name == "mixed":  # styles in turn, so that any run of seeds covers them evenly
        name = MIXED[seed % len(MIXED)]
    if name not in STYLES:
        raise KeyError(name)
    return name, STYLES[name](size, rng)

"""What a radio map misses, completed: the fills of ``RayTraceConfig.gap_fill_method`` (``fill``): ``geodesic``
(the exact straight path through the walls and a short walk from the hit cells), or the earlier fills from coarser
maps, ``smooth`` and ``parent``; each cell's provenance code says which gave it (``schemas.provenance``)."""

from __future__ import annotations

import numpy as np

from uavplace.schemas.provenance import COARSE_MAP, EXACT_PATHS, RAY_TRACED, STRAIGHT_PATH, UNREACHED, WALKED
from uavplace.simulate.raytrace import RayTraceConfig

#: The walks of the geodesic fill (``RayTraceConfig.gap_fill_walk``).
WALKS = ("euclidean", "4-neighbour")


def _expand(coarse: np.ndarray, factor: int, shape: tuple[int, int]) -> np.ndarray:
    """A coarse map [..., cy, cx] repeated onto the fine grid [..., ny, nx] (same corner)."""
    ny, nx = shape
    return np.repeat(np.repeat(coarse, factor, axis=-2), factor, axis=-1)[..., :ny, :nx]


def fill_gaps(fine: np.ndarray, coarse: np.ndarray, factor: int) -> np.ndarray:
    """Cells of ``fine`` [U, ny, nx] that no ray hit take the mean path gain of their ``coarse`` parent cell.

    ``coarse`` is [U, ceil(ny / factor), ceil(nx / factor)] over the same corner. A cell
    no ray hit in a map whose cells hold ``factor**2`` times more rays is a Monte Carlo gap
    there only if its parent got rays; cells whose parent got none stay at 0 (unreached).
    """
    return np.where(fine > 0, fine, _expand(coarse, factor, fine.shape[-2:]))


def fill_smooth(
    fine: np.ndarray, coarse: list[np.ndarray], factors: tuple[int, ...], open_cells: np.ndarray, d2: np.ndarray
) -> np.ndarray:
    """Fill Monte Carlo gaps: the level of the coarse map, the variation of the nearest hit cells.

    A cell no ray hit is live when a coarser map (``coarse[k]`` at ``factors[k]``) got rays in
    its parent cell; otherwise it stays 0 (unreached, as InSite leaves it). Then:

    1. shape: on the gain relative to free space, ``gain * d2`` (``d2`` [U, ny, nx]: squared
       distance from the user to the cell centre [m^2]), each live gap takes the geometric mean
       of its already known 4-neighbours, front by front outward from the hit cells; values
       spread only through ``open_cells`` [ny, nx] (no building at or above the plane), so a
       shadow is never filled from the lit side of a building. Gaps no front reaches (an
       enclosed court) take their parent's relative gain.
    2. level: the gaps of each parent cell are scaled together so that their mean is the
       parent's mean gain (the finest coarse map that saw rays there; it counts ``factor**2``
       times more rays than a fine cell). Hit cells stay exactly as traced.

    No two cells are copies, so the maps hold no constant 4 x 4 patches. ``fine`` [U, ny, nx];
    returns the filled map of the same shape.
    """
    shape = fine.shape[-2:]
    live = fine > 0
    for c, f in zip(coarse, factors, strict=True):
        live |= _expand(c, f, shape) > 0
    known = fine > 0
    value = log_relative_gain(fine, d2)
    gap = live & ~known
    _walk_fronts(value, known, gap, np.broadcast_to(open_cells, fine.shape), sum(shape))
    relative = np.where(known, np.exp(value), 0.0)
    for c, f in zip(coarse, factors, strict=True):  # gaps no front reached: the finest parent that saw rays
        relative = np.where(known, relative, _expand(c * _block_mean(d2, f), f, shape))
        known |= relative > 0
    out = np.where(fine > 0, fine, np.where(live, relative / d2, 0.0))  # hit cells exactly as traced
    return _to_parent_level(out, fine, coarse, factors)


def log_relative_gain(fine: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """The natural log of each hit cell's gain relative to free space (gain x ``d2``, the squared user-to-cell
    distance), where a walk from the hit cells starts; 0 where no ray hit (``fine`` == 0)."""
    known = fine > 0
    return np.where(known, np.log(np.where(known, fine * d2, 1.0)), 0.0)


def _walk_fronts(
    value: np.ndarray,
    known: np.ndarray,
    targets: np.ndarray,
    spread: np.ndarray,
    fronts: int,
    step_ln: float = 0.0,
    front: np.ndarray | None = None,
) -> None:
    """In place, front by front outward from the ``known`` cells (at most ``fronts`` fronts): each cell of ``targets``
    with known 4-neighbours in ``spread`` takes their mean ``value`` (a log gain) less ``step_ln``, and becomes known.
    Only cells of ``spread`` pass a value on, so nothing crosses a building. ``front`` (an int array of the same shape),
    when given, records the number of the front that reached each cell (1, 2, ...; untouched elsewhere): its walk
    through ``spread`` in cells, since the known neighbours in ``spread`` of a cell of front k are all of front k - 1."""
    for k in range(1, fronts + 1):
        src = known & spread
        total = np.zeros_like(value)
        count = np.zeros(value.shape, np.int32)
        for axis, step in ((-1, 1), (-1, -1), (-2, 1), (-2, -1)):
            total += _shifted(np.where(src, value, 0.0), step, axis)
            count += _shifted(src.astype(np.int32), step, axis)
        new = targets & ~known & (count > 0)
        if not new.any():
            break
        value[new] = total[new] / count[new] - step_ln
        known |= new
        if front is not None:
            front[new] = k


def _to_parent_level(filled: np.ndarray, fine: np.ndarray, coarse: list[np.ndarray], factors: tuple[int, ...]) -> np.ndarray:
    """Scale the gaps of each parent cell together so that their mean is the parent's (finest parent with rays first)."""
    shape = fine.shape[-2:]
    gap = (fine == 0) & (filled > 0)
    out = filled.copy()
    done = ~gap
    for c, f in zip(coarse, factors, strict=True):
        todo = gap & ~done & (_expand(c, f, shape) > 0)
        count = _block_sum(todo.astype(float), f)
        total = _block_sum(np.where(todo, out, 0.0), f)
        scale = np.where((total > 0) & (c > 0), c * count / np.maximum(total, 1e-300), 1.0)
        out = np.where(todo, out * _expand(scale, f, shape), out)
        done |= todo
    return out


def _block_sum(a: np.ndarray, f: int) -> np.ndarray:
    """Sum of ``a`` [..., ny, nx] over blocks of ``f`` x ``f`` cells (the last ones may be partial)."""
    ny, nx = a.shape[-2:]
    cy, cx = -(-ny // f), -(-nx // f)
    pad = np.pad(a, [(0, 0)] * (a.ndim - 2) + [(0, cy * f - ny), (0, cx * f - nx)])
    return pad.reshape(*a.shape[:-2], cy, f, cx, f).sum(axis=(-3, -1))


def _block_mean(a: np.ndarray, f: int) -> np.ndarray:
    """Mean of ``a`` [..., ny, nx] over blocks of ``f`` x ``f`` cells (the last ones may be partial)."""
    return _block_sum(a, f) / _block_sum(np.ones(a.shape), f)


def _shifted(a: np.ndarray, step: int, axis: int) -> np.ndarray:
    """``a`` moved by ``step`` cells along ``axis``, zeros shifted in (no wrap-around)."""
    out = np.zeros_like(a)
    src = [slice(None)] * a.ndim
    dst = [slice(None)] * a.ndim
    if step > 0:
        src[axis], dst[axis] = slice(None, -step), slice(step, None)
    else:
        src[axis], dst[axis] = slice(-step, None), slice(None, step)
    out[tuple(dst)] = a[tuple(src)]
    return out


#: What the radio map misses: ``geodesic`` (the default, ``fill_geodesic``: exact straight paths through the walls and a
#: short walk from the hit cells), ``smooth`` (``fill_smooth``) and ``parent`` (``fill_gaps``: the coarse cell copied).
FILL_METHODS = ("geodesic", "smooth", "parent")


#: The Euclidean walk's moves (dy, dx), with the cells each passes between, which must be open too (no corner of a
#: building cut): the 16 moves of lengths 1, sqrt 2 and sqrt 5 cells, whose ways are within 3 % of a straight line.
_MOVES: tuple[tuple[tuple[int, int], tuple[tuple[int, int], ...]], ...] = tuple(
    (
        (dy, dx),
        ()
        if abs(dy) + abs(dx) == 1
        else ((dy, 0), (0, dx))
        if abs(dy) == abs(dx) == 1
        else ((dy // 2 if abs(dy) == 2 else 0, dx // 2 if abs(dx) == 2 else 0), (dy // abs(dy), dx // abs(dx))),
    )
    for dy in range(-2, 3)
    for dx in range(-2, 3)
    if (abs(dy), abs(dx)) in {(0, 1), (1, 0), (1, 1), (1, 2), (2, 1)}
)


def _moved(a: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``a`` [..., ny, nx] moved by ``dy`` rows and ``dx`` columns (``out[y, x] = a[y - dy, x - dx]``), zeros shifted in."""
    out = a
    for step, axis in ((dy, -2), (dx, -1)):
        if step:
            out = _shifted(out, step, axis)
    return out


def _walk_euclidean(
    value: np.ndarray, known: np.ndarray, spread: np.ndarray, reach_m: float, cell_m: float, decay_ln_per_m: float
) -> np.ndarray:
    """In place, the geodesic fill's walk with a Euclidean reach: every cell of ``spread`` [ny, nx] (open ground) within
    ``reach_m`` of a ``known`` cell [U, ny, nx], measured along the shortest way through ``spread`` in the moves of
    ``_MOVES``, takes the mean over its known neighbours on such ways of their ``value`` (a log relative gain) less
    ``decay_ln_per_m`` for each metre between them, nearest cells first; they become known. Returns the distance walked
    to each cell [m] (0 at the known cells, inf where the walk does not go)."""
    open2 = np.asarray(spread, bool)
    allowed = []  # per move: the target cell, the cell it comes from and the cells it passes between are all open
    for (dy, dx), between in _MOVES:
        ok = open2 & _moved(open2, dy, dx)
        for by, bx in between:
            ok &= _moved(open2, dy - by, dx - bx)
        allowed.append((dy, dx, float(np.hypot(dy, dx)) * cell_m, ok))
    dist = np.where(known & open2, 0.0, np.inf)
    for _ in range(int(reach_m // cell_m) * 2 + 2):  # relax until no way shortens (a way within reach has few steps)
        before = dist
        for dy, dx, length, ok in allowed:
            shifted = _moved(np.where(np.isfinite(dist), dist, -1.0), dy, dx)
            dist = np.where(ok & (shifted >= 0), np.minimum(dist, shifted + length), dist)
        if np.array_equal(dist, before):
            break
    dist = np.where(dist <= reach_m + 1e-9, dist, np.inf)
    todo = np.isfinite(dist) & ~known
    walked = np.where(np.isfinite(dist), dist, 0.0)
    sources = [(dy, dx, ok, _moved(walked, dy, dx)) for dy, dx, _, ok in allowed]
    for level in np.unique(dist[todo]):
        at = todo & (dist == level)
        total = np.zeros(value.shape)
        count = np.zeros(value.shape)
        for dy, dx, ok, came in sources:
            src = _moved(known, dy, dx) & ok
            total += np.where(src, _moved(value, dy, dx) + decay_ln_per_m * came, 0.0)
            count += src
        at &= count > 0  # always: the way to a cell within reach comes from a nearer one
        value[at] = total[at] / count[at] - decay_ln_per_m * level
        known |= at
    return dist


def fill_geodesic(
    fine: np.ndarray,
    direct: np.ndarray,
    open_cells: np.ndarray,
    d2: np.ndarray,
    *,
    reach_m: float,
    decay_db_per_m: float,
    cell_m: float,
    walk: str = "euclidean",
) -> tuple[np.ndarray, np.ndarray]:
    """Complete the radio map ``fine`` [U, ny, nx] without coarse maps, so without their lattice: (gain, the
    provenance code of each cell, ``schemas.provenance``).

    1. A cell no ray hit takes the exact straight path through the walls, ``direct`` [U, ny, nx] (0 where
       there is none); a hit cell keeps at least its power (the sum of all paths is never below one of them).
    2. The radio map samples diffraction only at edges the user sees, so the paths that reflect and then
       diffract into a side street reach few cells. Cells within ``reach_m`` of a hit cell, walking through
       ``open_cells`` [ny, nx] (no building at or above the plane: never from the lit side of a wall), take the
       geometric mean of their already known neighbours' gain relative to free space (gain x ``d2``, the
       squared user-to-cell distance), nearest first, less ``decay_db_per_m`` for each metre walked. ``walk``
       (``WALKS``): "euclidean" measures the way in steps of 1, sqrt 2 and sqrt 5 cells (``_walk_euclidean``),
       "4-neighbour" in steps along the axes (isolated lit patches are diamonds). Beyond that, cells stay
       unreached, as InSite leaves them.

    A cell takes the larger of its walked and straight-path values, and its code says which: ray-traced (hit),
    walked, straight path, or unreached.
    """
    if walk not in WALKS:
        raise ValueError(f"unknown walk {walk!r} ({', '.join(WALKS)})")
    hit = fine > 0
    known = hit.copy()
    value = log_relative_gain(fine, d2)
    spread = np.broadcast_to(open_cells, fine.shape)
    decay_ln_per_m = decay_db_per_m * np.log(10) / 10
    if walk == "euclidean":
        _walk_euclidean(value, known, open_cells, reach_m, cell_m, decay_ln_per_m)
    else:
        _walk_fronts(value, known, spread, spread, int(reach_m // cell_m + 1e-9), decay_ln_per_m * cell_m)
    walked = np.where(known & ~hit, np.exp(value) / d2, 0.0)
    gain = np.maximum(np.where(hit, fine, walked), direct)
    code = np.select([hit, (walked > 0) & (walked >= direct), direct > 0], [RAY_TRACED, WALKED, STRAIGHT_PATH], UNREACHED)
    return gain, code.astype(np.uint8)


def check_fill(config: RayTraceConfig) -> None:
    """A ``ValueError`` when the fill method and the coarse maps do not go together."""
    if config.gap_fill_method not in FILL_METHODS:
        raise ValueError(f"unknown gap fill method {config.gap_fill_method!r} ({', '.join(FILL_METHODS)})")
    if config.gap_fill_method != "geodesic" and not config.gap_fill_factors:
        raise ValueError(f"the {config.gap_fill_method!r} fill takes its levels from coarse maps: give --gap-fill, e.g. 4,16")
    if config.gap_fill_walk not in WALKS:
        raise ValueError(f"unknown walk {config.gap_fill_walk!r} ({', '.join(WALKS)})")


def fill(
    maps: dict[int | str, np.ndarray], config: RayTraceConfig, open_cells: np.ndarray, d2: np.ndarray, cell_m: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """The raw maps of ``path_gain_maps`` (by cell factor) completed by ``config.gap_fill_method``: (gain, the
    provenance code of every cell, ``schemas.provenance``: ray-traced, walked, straight path, coarse map or unreached);
    with ``config.solver == "paths"`` the maps are exact paths at every open cell and are returned as they are, nothing
    filled (exact paths or unreached).

    ``geodesic`` also takes ``maps["direct"]`` [U, ny, nx] (``direct_gains``) and the cell size ``cell_m``. ``open_cells`` [ny, nx]: no building at or above the plane; ``d2`` [U, ny, nx]:
    squared user-to-cell distances [m^2].
    """
    check_fill(config)
    fine = maps[1]
    if config.solver == "paths":  # exact paths at every open cell (``exact_path_maps``): nothing to fill
        return fine, np.where(fine > 0, EXACT_PATHS, UNREACHED).astype(np.uint8)
    if config.gap_fill_method == "geodesic":
        return fill_geodesic(
            fine,
            maps["direct"],
            open_cells,
            d2,
            reach_m=config.gap_fill_reach_m,
            walk=config.gap_fill_walk,
            decay_db_per_m=config.gap_fill_decay_db_per_m,
            cell_m=cell_m,
        )
    factors = tuple(config.gap_fill_factors)
    coarse = [maps[f] for f in factors]
    if config.gap_fill_method == "smooth":
        gain = fill_smooth(fine, coarse, factors, open_cells, d2)
    else:
        gain = fine
        for f, c in zip(factors, coarse, strict=True):
            gain = fill_gaps(gain, c, f)
    code = np.select([fine > 0, gain > 0], [RAY_TRACED, COARSE_MAP], UNREACHED)
    return gain, code.astype(np.uint8)

"""Measures of a radio map's faithfulness that need no reference: does the gap fill's lattice show?

The radio maps were once filled from maps of 16 m and 64 m cells (4 and 16 cells of 4 m): a cell
was dead exactly when its 64 m parent got no ray, and a filled cell took its parent's level. Both
leave marks on the lattice lines of those coarse cells, measured here on a map of cells:

- ``lattice_boundary_shares``: of all the boundaries between a dead and a live open cell, the share
  that lies on the lines between 64 m (16 m) blocks. A map whose dead regions follow buildings and
  shadows puts about 1 in 16 (1 in 4) there;
- ``lattice_step_ratios``: the mean absolute step [dB] between neighbouring live cells across those
  lines, over the step between neighbours elsewhere (1.0 when the lines are invisible).

The lattice starts at the grid's corner, as the coarse maps did. Cells [..., ny, nx], x along the last axis.
"""

from __future__ import annotations

import numpy as np

#: The coarse cells of the old gap fill, in 4 m cells: 16 m and 64 m.
LATTICES = {"16 m": 4, "64 m": 16}


def _pairs(shape: tuple[int, ...], period: int) -> list[tuple[tuple[slice, ...], tuple[slice, ...], np.ndarray, int]]:
    """The neighbour pairs along x and y: (slice of the first cells, slice of the second, on-lattice [n-1], axis)."""
    nd = len(shape)
    out = []
    for axis in (nd - 1, nd - 2):
        n = shape[axis]
        a = [slice(None)] * nd
        b = [slice(None)] * nd
        a[axis], b[axis] = slice(0, n - 1), slice(1, n)
        line = (np.arange(1, n) % period) == 0  # the line between cell i-1 and i lies at i * cell
        out.append((tuple(a), tuple(b), line, axis))
    return out


def _along(line: np.ndarray, axis: int, ndim: int) -> np.ndarray:
    shape = [1] * ndim
    shape[axis] = len(line)
    return line.reshape(shape)


def lattice_boundary_shares(live: np.ndarray, open_cells: np.ndarray) -> dict[str, float]:
    """Share of the dead/live boundaries between open cells that lie on each lattice's lines (``LATTICES``).

    ``live`` [..., ny, nx] bool; ``open_cells`` [ny, nx] (cells the UAV may occupy). NaN when there is no boundary.
    """
    live = np.asarray(live, bool)
    opened = np.broadcast_to(open_cells, live.shape)
    out = {}
    for name, period in LATTICES.items():
        on = total = 0
        for a, b, line, axis in _pairs(live.shape, period):
            edge = (live[a] != live[b]) & opened[a] & opened[b]
            total += int(edge.sum())
            on += int((edge & _along(line, axis, live.ndim)).sum())
        out[name] = on / total if total else float("nan")
    return out


def lattice_step_ratios(value_db: np.ndarray, live: np.ndarray, open_cells: np.ndarray) -> dict[str, float]:
    """Mean |step| [dB] between neighbouring live open cells across each lattice's lines, over the mean step
    between neighbours on no 16 m line. NaN when a set of pairs is empty."""
    value_db = np.asarray(value_db, float)
    ok_cells = np.asarray(live, bool) & np.broadcast_to(open_cells, value_db.shape)
    sums = {name: [0.0, 0] for name in (*LATTICES, "off")}
    finest = min(LATTICES.values())
    for a, b, _, axis in _pairs(value_db.shape, 1):
        n = value_db.shape[axis]
        index = np.arange(1, n)
        ok = ok_cells[a] & ok_cells[b]
        step = np.abs(value_db[a] - value_db[b])
        groups = {name: (index % period) == 0 for name, period in LATTICES.items()}
        groups["off"] = (index % finest) != 0
        for name, mask in groups.items():
            sel = ok & _along(mask, axis, value_db.ndim)
            sums[name][0] += float(step[sel].sum())
            sums[name][1] += int(sel.sum())
    off = sums["off"][0] / sums["off"][1] if sums["off"][1] else float("nan")
    return {name: (s / c / off if c and off > 0 else float("nan")) for name, (s, c) in sums.items() if name != "off"}


def error_quantiles(estimate: np.ndarray, reference: np.ndarray, select: np.ndarray) -> dict[str, float]:
    """|error| [dB] of linear gains over the pairs in ``select`` where the reference is live: count, median, p90.

    A pair the estimate calls dead (0) while the reference is live counts as an infinite error, so that a map cannot
    look accurate by leaving its hard cells dead.
    """
    sel = np.asarray(select, bool) & (reference > 0)
    est, ref = estimate[sel], reference[sel]
    with np.errstate(divide="ignore"):
        err = np.where(est > 0, np.abs(10 * np.log10(np.where(est > 0, est, 1.0)) - 10 * np.log10(ref)), np.inf)
    if not err.size:
        return {"pairs": 0, "median_db": float("nan"), "p90_db": float("nan")}
    q = np.quantile(err, [0.5, 0.9], method="inverted_cdf")  # no interpolation with an infinite error
    return {"pairs": int(err.size), "median_db": float(q[0]), "p90_db": float(q[1])}


#: The embedded level (simulate's 20 dBm, the main job's -75 dBm of noise plus interference, build's -40 dB floor),
#: at which ``fill_scores`` measures the SINR error as the agent sees it: a dead cell reads the floor, weaker paths too.
SINR_OFFSET_DB, SINR_FLOOR_DB = 20.0 + 75.0, -40.0


def sinr_db(gain: np.ndarray) -> np.ndarray:
    """SINR [dB] of path gains (linear) at the embedded level, the floor where dead or below."""
    with np.errstate(divide="ignore"):
        db = np.where(gain > 0, SINR_OFFSET_DB + 10 * np.log10(np.where(gain > 0, gain, 1.0)), SINR_FLOOR_DB)
    return np.maximum(db, SINR_FLOOR_DB)


def fill_scores(estimate: np.ndarray, reference: np.ndarray, hit: np.ndarray) -> dict[str, float]:
    """A filled map against exact paths over the same (user, cell) pairs (arrays of one shape; ``hit``: the pairs the
    radio map's rays hit): ``error_quantiles`` of the hit and of the missed pairs, the SINR error at the embedded level
    (median and p90 of each part, mean and p90 of all) and the dead/live agreement."""
    hit = np.asarray(hit, bool)
    on_hit, on_missed = error_quantiles(estimate, reference, hit), error_quantiles(estimate, reference, ~hit)
    sinr_err = np.abs(sinr_db(estimate) - sinr_db(reference))
    out = {
        "hit_pairs": on_hit["pairs"],
        "hit_median_db": on_hit["median_db"],
        "hit_p90_db": on_hit["p90_db"],
        "missed_pairs": on_missed["pairs"],
        "missed_median_db": on_missed["median_db"],
        "missed_p90_db": on_missed["p90_db"],
    }
    for part, sel in (("hit", hit), ("missed", ~hit)):
        err = sinr_err[sel]
        out[f"sinr_{part}_median_db"] = float(np.median(err)) if err.size else float("nan")
        out[f"sinr_{part}_p90_db"] = float(np.percentile(err, 90)) if err.size else float("nan")
    out["sinr_mean_db"], out["sinr_p90_db"] = float(sinr_err.mean()), float(np.percentile(sinr_err, 90))
    out["dead_live_agreement"] = float(((estimate > 0) == (reference > 0)).mean())
    return out

"""``<name>.routes.csv``: user routes for the tracking task, checked against the .txrx and the buildings.

One row per route point (``CSV_COLUMNS``), each point a transmitter of the .txrx (a points set,
``Route`` in what ``uavdata simulate --routes`` writes) whose receiver outputs are its radio map.
A route is refused, with the file, line and field, unless: its rows are consecutive in the file with
``order`` 0, 1, 2, ...; it has at least two points; consecutive points are at most
``ROUTE_MAX_STEP_M`` apart (no jump longer than the sampling); ``time_s`` starts at 0 and grows as the
distance walked over ``speed_mps``; every point is a transmitter of the .txrx at that position, used
by one route only; and no point lies inside a building footprint, nor any step crosses one.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import shapely

from uavplace.infra.files import regular_file_bytes
from uavplace.infra.limits import check_limit
from uavplace.schemas import ROUTES, InputError
from uavplace.schemas.tables import ROUTE_KINDS, ROUTE_MAX_SPEED_MPS, ROUTE_MAX_STEP_M

#: The header of a routes file, in order.
CSV_COLUMNS = ("route", "order", "time_s", "tx_set", "tx_point", "x_m", "y_m", "kind", "speed_mps")
#: Tolerances: a point on its .txrx position [m], a step over the sampling [m], time against distance / speed [s].
POSITION_TOL_M, STEP_TOL_M, TIME_TOL_S = 1e-2, 1e-3, 1e-2


def _number(text: str, kind: type, source: str, line: int, field: str) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise InputError(
            source, f"{text!r} is not {'an integer' if kind is int else 'a number'}", line=line, field=field
        ) from None
    if not math.isfinite(value):
        raise InputError(source, f"{text!r} is not finite", line=line, field=field)
    return value


def csv_rows(reader, source: str):  # noqa: ANN001, ANN202 - a csv.reader; yields its rows
    """``reader``'s rows; a row the csv module refuses (a field over its size limit, a NUL) is an ``InputError`` naming
    its line."""
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise InputError(source, f"not a CSV row ({exc})", line=reader.line_num, field="row") from None
        yield row


def read_routes(path: Path, source: str, transmitters: pa.Table, footprints: list[shapely.Geometry]) -> pa.Table:
    """The ``ROUTES`` table of a routes file; ``InputError`` naming the file, line and field of the first problem.
    ``transmitters``: the ingest's transmitters table; ``footprints``: the building footprints at ground level."""
    data = regular_file_bytes(path, source, "text_bytes")
    try:
        text = data.decode("utf-8-sig")  # a byte-order mark is accepted, as in every other export
    except UnicodeDecodeError as exc:
        raise InputError(source, f"not UTF-8 text ({exc.reason} at byte {exc.start})", field="encoding") from None
    reader = csv.reader(io.StringIO(text, newline=""))
    rows = csv_rows(reader, source)
    header = next(rows, None)
    if header is None or tuple(h.strip() for h in header) != CSV_COLUMNS:
        raise InputError(source, f"header {header}: expected {', '.join(CSV_COLUMNS)}", line=1, field="header")
    columns: dict[str, list] = {c: [] for c in CSV_COLUMNS}
    lines: list[int] = []
    for row in rows:
        line = reader.line_num
        if not row or all(not c.strip() for c in row):
            continue
        check_limit("route_points", len(lines) + 1, source, "route points", line=line)
        if len(row) != len(CSV_COLUMNS):
            raise InputError(source, f"{len(row)} fields, expected {len(CSV_COLUMNS)}", line=line, field="row")
        for c, cell in zip(CSV_COLUMNS, row, strict=True):
            cell = cell.strip()
            if c == "kind":
                if cell not in ROUTE_KINDS:
                    raise InputError(source, f"{cell!r}: expected one of {', '.join(ROUTE_KINDS)}", line=line, field=c)
                columns[c].append(cell)
            else:
                columns[c].append(_number(cell, int if c in ("route", "order", "tx_set", "tx_point") else float, source, line, c))
        lines.append(line)
    if not lines:
        raise InputError(source, "no route point", line=1, field="rows")
    a = {c: np.array(v) for c, v in columns.items()}
    _check_routes(a, np.array(lines), source)
    _check_points(a, np.array(lines), source, transmitters, footprints)
    table = pa.table(
        {
            "route": a["route"],
            "order": a["order"],
            "time_s": a["time_s"],
            "tx_set_id": a["tx_set"],
            "tx_point": a["tx_point"],
            "x_m": a["x_m"],
            "y_m": a["y_m"],
            "kind": a["kind"],
            "speed_mps": a["speed_mps"],
        }
    )
    return ROUTES.conform(table, source)


def _check_routes(a: dict[str, np.ndarray], lines: np.ndarray, source: str) -> None:
    """Each route's rows consecutive, ordered 0, 1, ...; at least two points; steps within the sampling; time as the
    distance walked over the speed; one speed and kind per route."""
    starts = np.r_[0, np.flatnonzero(np.diff(a["route"])) + 1]
    seen: set[int] = set()
    for s, e in zip(starts, np.r_[starts[1:], len(lines)], strict=True):
        route = int(a["route"][s])
        if route in seen:
            raise InputError(source, f"route {route} continues after another route's rows", line=int(lines[s]), field="route")
        seen.add(route)
        order = a["order"][s:e]
        wrong = np.flatnonzero(order != np.arange(e - s))
        if len(wrong):
            k = s + int(wrong[0])
            raise InputError(
                source, f"order {int(a['order'][k])} of route {route}: expected {k - s}", line=int(lines[k]), field="order"
            )
        if e - s < 2:
            raise InputError(source, f"route {route} has one point", line=int(lines[s]), field="route")
        for c in ("kind", "speed_mps"):
            other = np.flatnonzero(a[c][s:e] != a[c][s])
            if len(other):
                k = s + int(other[0])
                raise InputError(source, f"route {route} changes its {c}", line=int(lines[k]), field=c)
        kind, speed = str(a["kind"][s]), float(a["speed_mps"][s])
        if speed > ROUTE_MAX_SPEED_MPS[kind]:
            raise InputError(
                source,
                f"route {route}: a {kind} at {speed:g} m/s, faster than a {kind} moves (at most "
                f"{ROUTE_MAX_SPEED_MPS[kind]:g} m/s): its kind or speed is wrong",
                line=int(lines[s]),
                field="speed_mps",
            )
        xy = np.c_[a["x_m"][s:e], a["y_m"][s:e]]
        step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        far = np.flatnonzero(step > ROUTE_MAX_STEP_M + STEP_TOL_M)
        if len(far):
            k = s + int(far[0]) + 1
            raise InputError(
                source,
                f"a jump of {step[far[0]]:.3f} m from the point before, more than the sampling of {ROUTE_MAX_STEP_M:g} m",
                line=int(lines[k]),
                field="x_m",
            )
        expected = np.r_[0.0, np.cumsum(step)] / a["speed_mps"][s]
        off = np.flatnonzero(np.abs(a["time_s"][s:e] - expected) > TIME_TOL_S + 1e-4 * expected)
        if len(off):
            k = s + int(off[0])
            raise InputError(
                source,
                f"time {a['time_s'][k]:g} s, but {expected[off[0]]:.3f} s at {a['speed_mps'][s]:g} m/s along the route",
                line=int(lines[k]),
                field="time_s",
            )


def _check_points(
    a: dict[str, np.ndarray], lines: np.ndarray, source: str, transmitters: pa.Table, footprints: list[shapely.Geometry]
) -> None:
    """Every point a transmitter of the .txrx at its position, in one route only; none inside a building, no step
    across one."""
    tx = {
        (int(s), int(p)): (x, y)
        for s, p, x, y in zip(*(transmitters.column(c).to_pylist() for c in ("tx_set_id", "tx_point", "x_m", "y_m")), strict=True)
    }
    used: dict[tuple[int, int], int] = {}
    for k, key in enumerate(zip(a["tx_set"].tolist(), a["tx_point"].tolist(), strict=True)):
        line = int(lines[k])
        if key in used:
            raise InputError(
                source,
                f"transmitter t{key[1]:03d}_{key[0]:02d} is also the point of line {used[key]}",
                line=line,
                field="tx_point",
            )
        used[key] = line
        where = tx.get(key)
        if where is None:
            raise InputError(source, f"no transmitter t{key[1]:03d}_{key[0]:02d} in the .txrx", line=line, field="tx_point")
        if where[0] is not None and max(abs(where[0] - a["x_m"][k]), abs(where[1] - a["y_m"][k])) > POSITION_TOL_M:
            raise InputError(
                source,
                f"({a['x_m'][k]:g}, {a['y_m'][k]:g}), but the .txrx puts t{key[1]:03d}_{key[0]:02d} at "
                f"({where[0]:g}, {where[1]:g})",
                line=line,
                field="x_m",
            )
    if not footprints:
        return
    union = shapely.union_all(footprints)
    inside = shapely.contains_xy(union, a["x_m"], a["y_m"])
    if inside.any():
        k = int(np.argmax(inside))
        raise InputError(
            source, f"point ({a['x_m'][k]:g}, {a['y_m'][k]:g}) is inside a building", line=int(lines[k]), field="x_m"
        )
    same = np.flatnonzero(np.diff(a["route"]) == 0)  # steps within a route
    steps = shapely.linestrings(
        np.stack([np.c_[a["x_m"][same], a["y_m"][same]], np.c_[a["x_m"][same + 1], a["y_m"][same + 1]]], axis=1)
    )
    crossing = shapely.intersects(steps, union)
    if crossing.any():
        k = int(same[np.argmax(crossing)]) + 1
        raise InputError(source, "the step from the point before crosses a building", line=int(lines[k]), field="x_m")

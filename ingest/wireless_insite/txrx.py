"""Transmitter and receiver sets (.txrx).

Each set is a top-level block: ``begin_<points> BS1``, ``begin_<grid> UE_grid``,
``begin_<polygon> ...``, with ``project_id N`` (the number in output file
names), a ``begin_<location>`` holding ``nVertices`` and the vertices, and for
a grid ``side1``, ``side2`` and ``spacing`` [m] (corner = the one vertex,
x varying fastest in outputs). ``begin_<transmitter>`` holds ``power`` [dBm]
and the pattern's ``antenna`` / ``waveform`` numbers (defined in the .setup).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import ValidationError

from uavplace.ingest.wireless_insite.keyword import Block, parse_keyword_file
from uavplace.schemas import InputError, TxRxSet
from uavplace.schemas.base import validation_message
from uavplace.schemas.tables import TRANSMITTERS, XY_RANGE_M
from uavplace.schemas.txrx import MAX_GRID_SIDE

#: Block kinds that define transmitter/receiver sets.
SET_KINDS = ("points", "grid", "polygon", "route", "trajectory", "arc", "cylinder", "sphere", "xyzgrid", "areagrid")


def _pattern_numbers(block: Block | None) -> tuple[int | None, int | None]:
    if block is None:
        return None, None
    patterns = block.blocks("pattern")
    if not patterns:
        return None, None
    return patterns[0].number("antenna", int), patterns[0].number("waveform", int)  # type: ignore[return-value]


def _location_vertices(block: Block) -> tuple[tuple[float, float, float], ...]:
    locations = block.blocks("location")
    if not locations:
        raise InputError(block.path, f"set '{block.name}' has no location", line=block.line, field="location")
    loc = locations[0]
    holder = loc if loc.find_entry("nVertices") else next(iter(loc.walk("face")), loc)
    return tuple(tuple(float(v) for v in row) for row in holder.vertices())  # type: ignore[misc]


def parse_txrx_set(block: Block) -> TxRxSet:
    pid = block.number("project_id", int)
    if pid is None:
        raise InputError(block.path, f"set '{block.name}' has no project_id", line=block.line, field="project_id")
    loc = block.blocks("location")
    loc_block = loc[0] if loc else block
    tx = block.blocks("transmitter")
    rx = block.blocks("receiver")
    tx_antenna, tx_waveform = _pattern_numbers(tx[0] if tx else None)
    rx_antenna, _ = _pattern_numbers(rx[0] if rx else None)
    lengths = {key: loc_block.number(key) for key in ("side1", "side2", "spacing")}
    for key, value in lengths.items():
        if value is not None and not (0 < value <= XY_RANGE_M[1]) and not (key != "spacing" and value == 0):
            line = loc_block.find_entry(key)[0]  # type: ignore[index]
            what = "> 0" if key == "spacing" else ">= 0"
            raise InputError(block.path, f"{key} {value:g} m: must be {what} and finite", line=line, field=key)
    spacing, sides = lengths["spacing"], [v for k, v in lengths.items() if k != "spacing" and v is not None]
    if spacing is not None and sides and not max(sides) / spacing < MAX_GRID_SIDE:
        line = loc_block.find_entry("spacing")[0]  # type: ignore[index]
        raise InputError(
            block.path,
            f"spacing {spacing:g} m for a side of {max(sides):g} m: over {MAX_GRID_SIDE:,} receivers a side: not a receiver grid",
            line=line,
            field="spacing",
        )
    try:
        return TxRxSet(
            kind=block.kind,
            name=block.name,
            project_id=int(pid),
            active=not block.has_word("inactive"),
            is_transmitter=bool(block.yes("is_transmitter")) if block.yes("is_transmitter") is not None else bool(tx),
            is_receiver=bool(block.yes("is_receiver")) if block.yes("is_receiver") is not None else bool(rx),
            vertices_m=_location_vertices(block),
            side1_m=lengths["side1"],
            side2_m=lengths["side2"],
            spacing_m=lengths["spacing"],
            tx_power_dbm=tx[0].number("power", column=TRANSMITTERS.column("power_dbm")) if tx else None,
            tx_antenna=tx_antenna,
            tx_waveform=tx_waveform,
            rx_antenna=rx_antenna,
            source=block.where(),
        )
    except ValidationError as exc:  # pydantic's cross-field checks
        field, message = validation_message(exc)
        raise InputError(block.path, message, line=block.line, field=field) from None


def read_txrx(path: str | Path, display: str | None = None) -> list[TxRxSet]:
    """All transmitter/receiver sets of a .txrx, in file order; duplicate project_ids are errors."""
    root = parse_keyword_file(path, display)
    sets: list[TxRxSet] = []
    seen: dict[int, str] = {}
    for block in root.children:
        if block.kind not in SET_KINDS:
            continue
        s = parse_txrx_set(block)
        if s.project_id in seen:
            raise InputError(
                block.path,
                f"project_id {s.project_id} already used by the set at {seen[s.project_id]}",
                line=block.line,
                field="project_id",
            )
        seen[s.project_id] = s.source
        sets.append(s)
    return sets

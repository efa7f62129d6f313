"""The trace cache of ``uavdata simulate``: raw radio maps kept by the key of everything that made them (the
simulation's geometry, grid and users, the solver's settings, the package versions), and checked whenever they are
read: an entry that fails its digest is traced again, never used."""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
import zlib
from dataclasses import asdict
from pathlib import Path

import numpy as np

from uavplace.infra.files import ARCHIVE_ERRORS
from uavplace.infra.limits import limits
from uavplace.schemas import InputError
from uavplace.schemas.base import uavplace_version
from uavplace.simulate.config import SimulationSpec
from uavplace.simulate.raytrace import (
    RayTraceConfig,
    raytrace_record,
)
from uavplace.simulate.scene import ALL_CONCRETE, parse_mix

#: Settings that only change how the traced maps are filled or completed: a trace cache entry serves any of their values.
FILL_ONLY = ("gap_fill_reach_m", "gap_fill_decay_db_per_m", "gap_fill_walk", "complete_missed_samples")


def trace_key(spec: SimulationSpec, config: RayTraceConfig) -> str:
    """What a city's traced maps depend on: its spec and the ray-trace settings, less ``FILL_ONLY``."""
    settings = {k: v for k, v in raytrace_record(config).items() if k not in FILL_ONLY}
    return json.dumps({"spec": spec_record(spec), "raytrace": settings, "uavplace": uavplace_version()}, sort_keys=True)


def spec_record(spec: SimulationSpec) -> dict:
    """``spec`` as simulation.json records it: without the route settings when it has no routes (as before routes)."""
    doc = asdict(spec)
    if not spec.surround_m:  # as before --surround: a crop's buildings only
        del doc["surround_m"]
    if parse_mix(spec.materials) == ALL_CONCRETE:  # as before --materials: every building concrete
        del doc["materials"]
    return doc if spec.routes else {k: v for k, v in doc.items() if not k.startswith("route")}


def _entry_digest(key: str, arrays: dict[str, np.ndarray]) -> str:
    """The sha256 a trace cache entry carries: of its key (what made it) and of every array's name, type, shape and
    bytes."""
    h = hashlib.sha256(key.encode("utf-8"))
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def read_cache_entry(path: Path, key: str, max_bytes: float | None = None) -> tuple[dict[str, np.ndarray] | None, str]:
    """A trace cache entry's arrays, or None and why it is not used: not a regular file, not a readable archive, an
    array over the limits or of objects, arrays that together hold more than ``max_bytes`` (what the simulation can
    make: read from the headers before anything is decompressed), another key (other settings), or arrays that do
    not match the sha256 the entry carries (damaged or altered). Never raises on a damaged entry."""
    bound = limits().array_bytes
    total = 0
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                with archive.open(info) as member:
                    version = np.lib.format.read_magic(member)
                    read_header = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
                    if version not in read_header:
                        return None, f"{info.filename}: .npy format {version}"
                    shape, _, dtype = read_header[version](member)  # the header only, before anything is decompressed
                size = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
                if dtype.hasobject or size > bound:
                    return None, f"{info.filename}: {dtype} {shape} is over the limit array_bytes or not numbers"
                total += size
                if max_bytes is not None and total > max_bytes:
                    return None, f"its arrays hold over {max_bytes:,.0f} bytes, more than this simulation makes"
        with np.load(path, allow_pickle=False) as z:
            if "key" not in z.files or str(z["key"]) != key:
                return None, "made with other settings"
            arrays = {k: z[k] for k in z.files if k not in ("key", "sha256")}
            carried = str(z["sha256"]) if "sha256" in z.files else ""
    except (*ARCHIVE_ERRORS, KeyError, zlib.error) as exc:
        return None, f"unreadable ({type(exc).__name__}: {str(exc)[:120]})"
    if carried != _entry_digest(key, arrays):
        return None, "its arrays do not match the sha256 it carries (damaged or altered)"
    return arrays, "used"


def cached_traces(cache: Path | None, name: str, key: str, trace, max_bytes: float | None = None) -> tuple[dict, str]:  # noqa: ANN001
    """``trace()``'s maps, or those kept in ``cache/<name>.npz`` under the same key (``trace_key``; arrays only, no
    pickle, checked by ``read_cache_entry``, at most ``max_bytes`` in all); (maps, what became of the entry: ``used``,
    ``none``, or why it was traced again). A new trace is kept there with its sha256, written atomically."""
    path = None if cache is None else Path(cache) / f"{name}.npz"
    status = "none"
    if path is not None and (path.is_symlink() or (path.exists() and not path.is_file())):  # before minutes of tracing
        raise InputError(path, "exists and is not a regular file: not a trace cache entry; move it away", field="trace_cache")
    if path is not None and path.exists():
        arrays, status = read_cache_entry(path, key, max_bytes)
        if arrays is not None:
            return {(int(k[1:]) if k[0] == "f" and k[1:].isdigit() else k): v for k, v in arrays.items()}, status
        status = f"traced again: the entry was {status}" if status.startswith("made") else f"traced again: {status}"
    maps = trace()
    if path is not None:
        write_cache_entry(path, key, {(f"f{k}" if isinstance(k, int) else k): v for k, v in maps.items()})
    return maps, status


def write_cache_entry(path: Path, key: str, arrays: dict[str, np.ndarray]) -> None:
    """A trace cache entry: ``arrays`` with the ``key`` that made them and their sha256, written atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, key=np.array(key), sha256=np.array(_entry_digest(key, arrays)), **arrays)
    os.replace(tmp, path)

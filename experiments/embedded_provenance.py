"""Provenance side files for cities simulated before `uavdata simulate` wrote them (issue 51), their maps unchanged.

For each city folder with a simulation.json and no ``<city>.provenance.csv.gz``:

- an exact-path city (``--solver paths``): every reached receiver "exact paths", from its own .p2m files;
- a radio-map city: its traced maps from the trace cache (``--traces``, filled by ``experiments/embedded_data.sh``
  with the same settings: ``TRACES=runs/traces bash experiments/embedded_data.sh runs/retrace``), filled again with
  the settings its simulation.json records. Ray tracing on the CPU does not reproduce a trace exactly: a few rays
  take other branches. A live receiver whose power the fill reproduces within ``--tol-db`` takes the code the
  re-trace gives it (ray-traced, straight path, walked); one it does not reproduce is "not recorded"; a dead one
  "unreached". Each code is thus vouched for by its own receiver; a city where more than ``--max-share`` (half) of
  the live receivers do not reproduce is left alone, its re-trace taken for one made otherwise.

The maps themselves are not rewritten, so the embedded data keeps its values (and git its history); the side file
is what `uavdata simulate` writes today (``simulate.insite.write_provenance``).

    python experiments/embedded_provenance.py [--raw data/raw] [--traces runs/traces] [--tol-db 0.01] [--max-share 0.5]
        [--city NAME ...] [--dry-run]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from uavplace.ingest.wireless_insite.p2m import read_p2m
from uavplace.schemas.provenance import EXACT_PATHS, NOT_RECORDED, SIDE_FILE_SUFFIX, UNREACHED, code_name
from uavplace.simulate.config import SimulationSpec
from uavplace.simulate.fill import fill
from uavplace.simulate.insite import write_provenance
from uavplace.simulate.pipeline import (
    GRID_SET,
    PROVENANCE,
    as_written,
    open_cells,
    receiver_grid,
    squared_distances,
    transmitter_of,
)
from uavplace.simulate.raytrace import config_of_record
from uavplace.simulate.sources import load_geometry
from uavplace.simulate.trace_cache import read_cache_entry, trace_key


def receiver_power(path: Path) -> np.ndarray:
    """Received power [dBm] of every receiver of one power file (NaN where unreached)."""
    return read_p2m(path)[1].column("power_dbm").to_numpy(zero_copy_only=False).astype(float)


def committed_power(folder: Path, spec: SimulationSpec, sources: int, users: int) -> np.ndarray:
    """The committed export's received power [sources, cells] (dBm; NaN where unreached)."""
    out = []
    for s in range(sources):
        (tx_set, _), point = transmitter_of(s, users)
        out.append(receiver_power(folder / f"{spec.name}.power.t{point:03d}_{tx_set:02d}.r{GRID_SET[0]:03d}.p2m.gz"))
    return np.stack(out)


def side_file(folder: Path, traces: Path, tol_db: float, max_share: float) -> tuple[dict | None, str]:
    """The codes of a city's receivers ``{(tx_set, tx_point): codes}`` and what was found, or None and why not."""
    record = json.loads((folder / PROVENANCE).read_text())
    fields = SimulationSpec.__dataclass_fields__
    spec = SimulationSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in record["spec"].items() if k in fields})
    config = config_of_record(record["raytrace"])
    users = len(record["users_m"])
    sources = users + record.get("routes", {}).get("points", 0)
    power = committed_power(folder, spec, sources, users)
    if config.solver == "paths":
        codes = np.where(np.isnan(power), UNREACHED, EXACT_PATHS).astype(np.uint8)
        why = "exact paths at every open cell (from its .p2m files)"
    else:
        arrays, status = read_cache_entry(traces / f"{spec.name}.npz", trace_key(spec, config)) if (
            traces / f"{spec.name}.npz").is_file() else (None, "no trace cache entry")  # fmt: skip
        if arrays is None:
            return None, f"not written: {status}"
        blocks, bounds, _ = load_geometry(spec.source, spec.seed, spec.crop_m)
        grid = receiver_grid(bounds, spec)
        placed = np.asarray(record["users_m"], float)
        every = placed if sources == users else None
        if every is None:  # the route points, in the .txrx's order after the users
            from uavplace.ingest.wireless_insite.txrx import read_txrx

            sets = read_txrx(folder / f"{spec.name}.txrx")
            every = np.concatenate([np.asarray(s.vertices_m, float) for s in sets if s.is_transmitter])
        maps = {(int(k[1:]) if k[0] == "f" and k[1:].isdigit() else k): v for k, v in arrays.items()}
        gain, source = fill(maps, config, open_cells(blocks, grid), squared_distances(every, grid), cell_m=grid.spacing_m)
        again, codes = as_written(gain, source, spec.tx_dbm)
        codes = codes.reshape(len(codes), -1)
        live = ~np.isnan(power)
        with np.errstate(invalid="ignore"):
            same = live & (np.abs(np.round(again, 4) - power) <= tol_db)  # NaN (dead again): not the same
        if same.sum() < (1 - max_share) * live.sum():
            return None, f"not written: only {same.sum()} of {live.sum()} live receivers reproduced within {tol_db:g} dB"
        codes = np.where(live, np.where(same, codes, NOT_RECORDED), UNREACHED).astype(np.uint8)
        why = (f"re-traced and filled again: {int(same.sum())} of {int(live.sum())} live receivers reproduced within "
               f"{tol_db:g} dB ({int(live.sum() - same.sum())} not: 'not recorded')")  # fmt: skip
    counts = np.bincount(codes.ravel(), minlength=EXACT_PATHS + 8)
    why += "; " + ", ".join(f"{code_name(c)} {n}" for c, n in enumerate(counts) if n)
    return {(transmitter_of(s, users)[0][0], transmitter_of(s, users)[1]): codes[s] for s in range(sources)}, why


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--raw", type=Path, default=Path("data/raw"), help="folder of city exports")
    ap.add_argument("--traces", type=Path, default=Path("runs/traces"), help="trace cache of the re-trace")
    ap.add_argument("--tol-db", type=float, default=0.01, help="largest power difference of a reproduced receiver [dB]")
    ap.add_argument("--max-share", type=float, default=0.5, help="largest share of live receivers left 'not recorded'")
    ap.add_argument("--city", action="append", default=[], help="only these cities (repeatable; default: every one)")
    ap.add_argument("--dry-run", action="store_true", help="check, write nothing")
    args = ap.parse_args()
    for folder in sorted(p.parent for p in args.raw.glob(f"*/{PROVENANCE}")):
        if args.city and folder.name not in args.city:
            continue
        if (folder / f"{folder.name}{SIDE_FILE_SUFFIX}").exists():
            print(f"{folder.name}: has a side file")
            continue
        codes, why = side_file(folder, args.traces, args.tol_db, args.max_share)
        if codes is not None and not args.dry_run:
            p2m = [p for p in folder.iterdir() if p.name.lower().endswith((".p2m", ".p2m.gz"))]
            write_provenance(folder, folder.name, GRID_SET[0], codes, p2m)  # the sha256 of the export it describes
        print(f"{folder.name}: {why}", flush=True)


if __name__ == "__main__":
    main()

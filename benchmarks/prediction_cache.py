"""How long the map searcher's predicted maps take to build, cold, per city: wall and CPU seconds, and their size.

For each city, the canvas the report plays (symmetry 0) with the buildings and open (the ablation), into a fresh
temporary cache (or into ``--cache``, which the report then reads warm). Prints one line per canvas and the total.
Timings only: nothing is chosen from them.

    python benchmarks/prediction_cache.py --city test --city etoile --city florence
    python benchmarks/prediction_cache.py --city test --predictor data/agents/searcher/unet
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from uavplace.rl.belief import PredictionCache
from uavplace.rl.config import DEFAULT_PREDICTOR, SearchConfig
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.view import PublicMaps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", required=True, help="City (repeatable)")
    ap.add_argument("--predictor", type=Path, default=DEFAULT_PREDICTOR, help="Constants' JSON or a learned tier's folder")
    ap.add_argument("--cache", type=Path, default=None, help="Cache folder to fill (default: a fresh temporary one)")
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    args = ap.parse_args()
    predictor = load_predictor(args.predictor)
    with tempfile.TemporaryDirectory() as tmp:
        cache = PredictionCache(args.cache or Path(tmp))
        total_wall = total_cpu = 0.0
        for city in args.city:
            public = PublicMaps.of(MapSet.load(city, EnvConfig(rotate=False), root=str(args.root)))
            for buildings in (True, False):
                policy = MapSearchPolicy(predictor, SearchConfig(buildings=buildings), cache)
                wall, cpu = time.perf_counter(), time.process_time()
                maps = policy.canvas_maps(public, 0)
                wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
                total_wall, total_cpu = total_wall + wall, total_cpu + cpu
                size = sum(p.stat().st_size for p in cache.folder.iterdir()) / 2**20
                print(f"{city} ({'buildings' if buildings else 'open ground'}): {len(maps.cells)} candidates x "
                      f"{len(maps.legal)} cells in {wall:.1f} s wall, {cpu:.1f} s CPU; cache now {size:.0f} MiB",
                      flush=True)  # fmt: skip
        print(f"total: {total_wall:.1f} s wall, {total_cpu:.1f} s CPU ({predictor.tier} tier {predictor.version()})")


if __name__ == "__main__":
    main()

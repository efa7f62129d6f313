"""Difficulty of an ingested city against the noise-plus-interference level: where does the genie's median fall?

For each level, rasterises the city as `uavdata build` would (nothing is
written) and prints the share of legal cells at or above P_T, the dead share
and the BFS steps from every valid start to the nearest target cell (the
genie's path length). The paper's test city had a genie median of 14 steps.

    python experiments/calibrate_difficulty.py --city train --noise-dbm -104 -80 -70 -65 -60 -55
"""

from __future__ import annotations

import argparse

import pandas as pd

from uavplace.dataset.build import rasterise
from uavplace.dataset.difficulty import difficulty
from uavplace.dataset.ingested import read_ingested
from uavplace.schemas.bundle import BuildConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", required=True, help="ingested city (repeatable)")
    ap.add_argument("--root", default="data/processed", help="processed-data root")
    ap.add_argument("--noise-dbm", type=float, nargs="+", default=[-104.0, -80.0, -70.0, -65.0, -60.0, -55.0])
    ap.add_argument("--p-t-db", type=float, default=5.0, help="SINR target P_T [dB]")
    ap.add_argument("--grid", type=float, default=4.0)
    ap.add_argument("--alt", type=float, default=10.0)
    args = ap.parse_args()
    rows = []
    for city in args.city:
        ing = read_ingested(city, args.root)
        for noise in args.noise_dbm:
            cfg = BuildConfig(grid_m=args.grid, altitude_m=args.alt, noise_dbm=noise, p_t_db=args.p_t_db)
            _, arrays, *_ = rasterise(ing, cfg)
            d = difficulty(arrays["blocked"], arrays["dead"], arrays["sinr_db"], args.p_t_db)
            rows.append({"city": city, "noise+interference [dBm]": noise, **{k: v for k, v in d.items() if k != "p_t_db"}})
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.3f}"))


if __name__ == "__main__":
    main()

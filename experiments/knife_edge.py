"""Behind a knife edge: Sionna's radio map and its exact paths against ITU-R P.526 (``simulate.knife_edge``).

Prints, at 12, 44, 92 and 156 m behind a 12 m conducting screen (user 50 m in front at 1.5 m,
receivers at 10 m, isotropic antennas, 800 MHz): the path gain P.526's single knife-edge loss
predicts, the exact paths' (``point_path_gains``: PathSolver, edge diffraction on) and the radio
map's (``RadioMapSolver``, 4 m cells, diffraction and edge diffraction on), in dB.

    python experiments/knife_edge.py [--samples 2e7]
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace

import numpy as np

from uavplace.simulate.knife_edge import BEHIND_M, EXACT_CONFIG, p526_path_gain_db, points, write_knife_edge_scene
from uavplace.simulate.raytrace import path_gain_maps_isolated, point_path_gains_isolated


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=float, default=2e7, help="rays of the radio map (the exact paths take 1e6)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        job = write_knife_edge_scene(tmp)
        exact = point_path_gains_isolated(job, points(), EXACT_CONFIG)[0]
        map_cfg = replace(EXACT_CONFIG, samples_per_tx=int(args.samples), gap_fill_factors=())
        raw = path_gain_maps_isolated(job, map_cfg, edge_diffraction=True)[1][0]
    cells = raw[job_rows(job)][:, (BEHIND_M // job.cell_m).astype(int)].mean(axis=0)  # the two rows around y = 0
    with np.errstate(divide="ignore"):
        rows = {"ITU-R P.526": p526_path_gain_db(BEHIND_M, EXACT_CONFIG.frequency_hz), "exact paths": 10 * np.log10(exact),
                "radio map": 10 * np.log10(cells)}  # fmt: skip
    print("| behind the screen [m] | " + " | ".join(f"{d:g}" for d in BEHIND_M) + " |")
    print("|---|" + "---|" * len(BEHIND_M))
    for name, v in rows.items():
        print(f"| {name} [dB] | " + " | ".join(f"{x:.1f}" for x in v) + " |")


def job_rows(job) -> slice:  # noqa: ANN001
    """The rows of cells that touch y = 0 on the job's plane."""
    ny = int(round(job.size_m[1] / job.cell_m))
    return slice(ny // 2 - 1, ny // 2 + 1)


if __name__ == "__main__":
    main()

"""Sionna RT radio maps: path gain from every user to every cell of a horizontal grid at the UAV altitude.

Needs the ``raytrace`` extra (``pip install -e .[raytrace]``). On a CPU, Dr.Jit
needs LLVM >= 16; Debian's ``libllvm19`` works: it is found through
``DRJIT_LIBLLVM_PATH`` (set here to ``/usr/lib/x86_64-linux-gnu/libLLVM-19.so``
when that file exists and the variable is unset).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

LLVM_19 = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"


@dataclass(frozen=True)
class RayTraceConfig:
    """Solver settings (Sionna ``RadioMapSolver``)."""

    frequency_hz: float = 800e6
    samples_per_tx: int = 1_000_000
    max_depth: int = 5
    diffraction: bool = True
    refraction: bool = True
    seed: int = 0
    antenna: str = "hw_dipole"  # vertical half-wave dipole at the users; Sionna's radio map takes an isotropic receiver
    users_per_call: int = 8
    #: Coarser maps traced as well (cell size x factor, so factor**2 more rays per cell) to fill Monte
    #: Carlo gaps; () for none. Each costs about one more solver call (measured: fewer samples for the
    #: coarse maps saved only ~20 % of the time and left 1.7 x more cells unreached).
    gap_fill_factors: tuple[int, ...] = (4, 16)


def fill_gaps(fine: np.ndarray, coarse: np.ndarray, factor: int) -> np.ndarray:
    """Cells of ``fine`` [U, ny, nx] that no ray hit take the mean path gain of their ``coarse`` parent cell.

    ``coarse`` is [U, ceil(ny / factor), ceil(nx / factor)] over the same corner. A cell
    no ray hit in a map whose cells hold ``factor**2`` times more rays is a Monte Carlo gap
    there only if its parent got rays; cells whose parent got none stay at 0 (unreached).
    """
    ny, nx = fine.shape[-2:]
    parent = np.repeat(np.repeat(coarse, factor, axis=-2), factor, axis=-1)[..., :ny, :nx]
    return np.where(fine > 0, fine, parent)


@dataclass(frozen=True)
class RadioMapJob:
    """What to trace: a scene, the users (transmitters) and the horizontal plane of cells."""

    scene_xml: str
    users_m: tuple[tuple[float, float, float], ...]  # [num_users, 3]
    center_m: tuple[float, float, float]  # plane centre; z is the altitude
    size_m: tuple[float, float]
    cell_m: float


def sionna_versions() -> dict[str, str]:
    out = {}
    for pkg in ("sionna-rt", "mitsuba", "drjit"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def import_sionna():
    """Import sionna.rt with a CPU LLVM variant; a clear error when the extra or LLVM is missing."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and Path(LLVM_19).exists():
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM_19
    try:
        import mitsuba as mi
        import sionna.rt as rt
    except ImportError as exc:
        raise RuntimeError(
            f"Sionna RT is not installed ({exc}): pip install -e '.[raytrace]' (and on a CPU: apt-get install libllvm19)"
        ) from None
    return mi, rt


def path_gain_maps(
    job: RadioMapJob, config: RayTraceConfig, on_batch: Callable[[int, int], None] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Path gain (linear) ``[num_users, num_y, num_x]`` of the job's plane.

    Cell ``(iy, ix)`` is centred at ``center - size / 2 + (i + 0.5) * cell``. A cell no ray reached holds 0.
    With ``config.gap_fill_factors``, each factor traces one more map of coarser cells over the same corner
    and fills the gaps (``fill_gaps``), finest first; the second array returned marks the filled cells.
    ``on_batch(done, total)`` reports progress in users.
    """
    mi, rt = import_sionna()
    scene = rt.load_scene(job.scene_xml)
    scene.frequency = config.frequency_hz
    scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern=config.antenna, polarization="V")
    scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern=config.antenna, polarization="V")
    solver = rt.RadioMapSolver()
    users = np.asarray(job.users_m, dtype=float)
    center_m, size_m, cell_m = job.center_m, job.size_m, job.cell_m
    out, filled = [], []
    for start in range(0, len(users), config.users_per_call):
        for name in list(scene.transmitters):
            scene.remove(name)
        batch = users[start : start + config.users_per_call]
        for k, (x, y, z) in enumerate(batch):
            scene.add(rt.Transmitter(name=f"user{start + k}", position=mi.Point3f(float(x), float(y), float(z)), power_dbm=0.0))
        corner = (center_m[0] - size_m[0] / 2, center_m[1] - size_m[1] / 2)
        maps = []
        for factor in (1, *config.gap_fill_factors):
            cell = cell_m * factor
            # A whole number of coarse cells from the same corner (the last row/column may overhang).
            size = (float(np.ceil(size_m[0] / cell - 1e-6) * cell), float(np.ceil(size_m[1] / cell - 1e-6) * cell))
            rm = solver(
                scene,
                center=mi.Point3f(float(corner[0] + size[0] / 2), float(corner[1] + size[1] / 2), float(center_m[2])),
                orientation=mi.Point3f(0.0, 0.0, 0.0),
                size=mi.Point2f(float(size[0]), float(size[1])),
                cell_size=mi.Point2f(float(cell), float(cell)),
                samples_per_tx=int(config.samples_per_tx),
                max_depth=config.max_depth,
                diffraction=config.diffraction,
                refraction=config.refraction,
                seed=config.seed + start + 7919 * factor,
            )
            maps.append(np.asarray(rm.path_gain.numpy(), dtype=np.float64))
        gain = maps[0]
        for factor, coarse in zip(config.gap_fill_factors, maps[1:], strict=True):
            gain = fill_gaps(gain, coarse, factor)
        out.append(gain)
        filled.append((maps[0] == 0) & (gain > 0))
        if on_batch is not None:
            on_batch(min(start + config.users_per_call, len(users)), len(users))
    return np.concatenate(out, axis=0), np.concatenate(filled, axis=0)


def path_gain_maps_isolated(
    job: RadioMapJob, config: RayTraceConfig, on_batch: Callable[[int, int], None] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``path_gain_maps`` in a child Python process.

    Dr.Jit/Mitsuba can crash while the interpreter shuts down (heap errors at exit after a
    correct run, seen here intermittently on the LLVM backend); running the solver in a child
    keeps that out of the caller. The child writes its result atomically and reports progress
    on stdout; a missing result is an error carrying the child's output.
    """
    with tempfile.TemporaryDirectory(prefix="uavplace-rt-") as tmp:
        job_file = Path(tmp) / "job.json"
        result = Path(tmp) / "result.npz"
        job_file.write_text(json.dumps({"job": asdict(job), "config": asdict(config), "result": str(result)}))
        proc = subprocess.Popen(
            [sys.executable, "-m", "simulate.raytrace", str(job_file)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        log = []
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.startswith("progress ") and on_batch is not None:
                done, total = map(int, line.split()[1:3])
                on_batch(done, total)
            else:
                log.append(line)
        proc.wait()
        if not result.is_file():
            raise RuntimeError(f"Sionna RT child process failed (exit {proc.returncode}):\n{''.join(log[-30:])}")
        with np.load(result) as npz:
            return npz["gain"], npz["filled"]


def _child(job_path: str) -> None:
    doc = json.loads(Path(job_path).read_text())
    j = doc["job"]
    job = RadioMapJob(j["scene_xml"], tuple(map(tuple, j["users_m"])), tuple(j["center_m"]), tuple(j["size_m"]), j["cell_m"])
    config = RayTraceConfig(**doc["config"] | {"gap_fill_factors": tuple(doc["config"]["gap_fill_factors"])})
    gain, filled = path_gain_maps(job, config, on_batch=lambda d, t: print(f"progress {d} {t}", flush=True))
    tmp = Path(doc["result"]).with_suffix(".tmp.npz")
    np.savez(tmp, gain=gain, filled=filled)
    os.replace(tmp, doc["result"])
    sys.stdout.flush()
    # Skip interpreter teardown: the result is on disk, and Dr.Jit's shutdown is what can crash.
    os._exit(0)


if __name__ == "__main__":
    _child(sys.argv[1])

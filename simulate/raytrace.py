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

from uavplace.infra.device import pick
from uavplace.schemas.constants import CARRIER_HZ

LLVM_19 = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"


#: The solvers ``RayTraceConfig.solver`` names: Sionna's ``RadioMapSolver`` (a map of every cell per solver call,
#: gaps filled by ``gap_fill_method``), or ``PathSolver`` at every open cell (``exact_path_maps``: every path found,
#: as InSite computes them, nothing filled; about a second a cell and user on the 2 reference cores).
SOLVERS = ("radio-map", "paths")
#: Mitsuba's variants the ray tracer runs in, by device.
VARIANTS = {"cuda": "cuda_ad_mono_polarized", "cpu": "llvm_ad_mono_polarized"}


@dataclass(frozen=True)
class RayTraceConfig:
    """Solver settings (Sionna ``RadioMapSolver``, or ``PathSolver`` with ``solver="paths"``): the record of
    ``simulation.json``'s ``raytrace`` and of the trace cache, made from a call's settings by
    ``simulate.config.Simulation.raytrace``; the solver's own defaults (refraction, antenna, users per call) are here."""

    frequency_hz: float = CARRIER_HZ
    samples_per_tx: int = 1_000_000
    max_depth: int = 5
    diffraction: bool = True
    refraction: bool = True
    seed: int = 0
    antenna: str = "hw_dipole"  # vertical half-wave dipole at the users; Sionna's radio map takes an isotropic receiver
    users_per_call: int = 8
    #: Coarser maps traced as well (cell size x factor, so factor**2 more rays per cell), which the ``smooth`` and
    #: ``parent`` fills take their levels from; () for none (``geodesic`` needs none). Each costs about one more
    #: solver call (measured: fewer samples for the coarse maps saved only ~20 % of the time and left 1.7 x more
    #: cells unreached).
    gap_fill_factors: tuple[int, ...] = ()
    #: What the radio map misses: "geodesic" (``fill_geodesic``: the exact straight path through the walls,
    #: ``simulate.transmission``, and a short walk from the hit cells), or the earlier fills from the coarse maps: "smooth" (the coarse level with the
    #: variation of the nearest hit cells, see ``fill_smooth``) or "parent" (the coarse cell's mean, copied: a mosaic).
    gap_fill_method: str = "geodesic"
    #: ``geodesic``: how far from a hit cell [m] a cell no ray hit is walked to, and the decay on the way [dB/m]
    #: (chosen on the validation cities' exact paths, ``experiments/fidelity.py``); reach 0: direct paths only.
    gap_fill_reach_m: float = 24.0
    gap_fill_decay_db_per_m: float = 3.0
    #: ``geodesic``: how the walk measures its reach (``WALKS``): "euclidean" (the shortest way through open cells in
    #: steps of 1, sqrt 2 and sqrt 5 cells, within 3 % of the straight line: what it lights follows the streets) or
    #: "4-neighbour" (steps along the axes only: an isolated lit patch is a diamond; the fill before this option).
    gap_fill_walk: str = "euclidean"
    #: Exact paths at every open cell the radio map missed (``simulate.complete``), PathSolver's rays per user for each
    #: (2e6 is the exact-path reference's); 0: off, the fill estimates them.
    complete_missed_samples: int = 0
    #: ``SOLVERS``: "radio-map" (the default), or "paths": every open cell from exact paths, no radio map and no fill
    #: (``samples_per_tx`` then is PathSolver's ``samples_per_src``).
    solver: str = "radio-map"
    #: Mitsuba's variant (``VARIANTS``, ``mitsuba_variant``): LLVM on the CPU, CUDA on a GPU, where the two may trace
    #: other rays (a trace cache entry is the variant's).
    variant: str = VARIANTS["cpu"]


#: The settings a record leaves out when they hold these values: what every city simulated before the choice had.
_EARLIER = {"solver": "radio-map", "gap_fill_walk": "4-neighbour", "complete_missed_samples": 0, "variant": VARIANTS["cpu"]}


def raytrace_record(config: RayTraceConfig) -> dict:
    """``config`` as ``simulation.json`` and the trace cache record it: without ``solver`` when it is the radio map's,
    without ``gap_fill_walk`` when it is the 4-neighbour walk, without ``complete_missed_samples`` when it is off and
    without ``variant`` when it is the CPU's (as before there was a choice, so that the cities simulated then stay up
    to date)."""
    return {k: v for k, v in asdict(config).items() if _EARLIER.get(k, object()) != v}


def config_of_record(record: dict) -> RayTraceConfig:
    """The ``RayTraceConfig`` a ``raytrace_record`` (simulation.json's ``raytrace``) was made from."""
    return RayTraceConfig(**_EARLIER | record | {"gap_fill_factors": tuple(record.get("gap_fill_factors", ()))})


#: The largest gain of each of Sionna's antenna patterns (linear, over isotropic): a vertical half-wave dipole's
#: 2.15 dBi, a short dipole's 1.76 dBi, an isotropic one's 0, 3GPP TR 38.901's element 8 dBi.
ANTENNA_GAIN = {"hw_dipole": 1.64, "dipole": 1.5, "iso": 1.0, "tr38901": 6.31}
#: Paths adding in phase raise a sum above free space by at most this [dB] (two equal paths: +6 dB).
IN_PHASE_DB = 6.0


def free_space_cap(d2: np.ndarray, frequency_hz: float, antenna: str) -> np.ndarray:
    """The largest path gain (linear) a cell at squared distance ``d2`` [m^2] from its user can have: free space with
    the user antenna's largest gain (``ANTENNA_GAIN``) and ``IN_PHASE_DB`` for paths in phase. A radio map's cell
    above it is a Monte Carlo artifact (a ray grazing the plane counts as 1 / cos of its angle), never physics."""
    wavelength = 299_792_458.0 / frequency_hz
    gain = ANTENNA_GAIN.get(antenna, max(ANTENNA_GAIN.values()))
    return gain * 10 ** (IN_PHASE_DB / 10) * (wavelength / (4 * np.pi)) ** 2 / np.maximum(d2, 1e-6)


def constant_patch_share(gain: np.ndarray, live: np.ndarray, size: int = 4) -> float:
    """Share of ``live`` cells [U, ny, nx] inside a ``size`` x ``size`` patch of exactly equal value (a mosaic)."""
    from numpy.lib.stride_tricks import sliding_window_view

    if gain.shape[-1] < size or gain.shape[-2] < size:
        return 0.0
    win = sliding_window_view(gain, (size, size), axis=(-2, -1))
    lw = sliding_window_view(live, (size, size), axis=(-2, -1))
    flat = (win == win[..., :1, :1]).all(axis=(-2, -1)) & lw.all(axis=(-2, -1))  # [U, ny-s+1, nx-s+1]
    marked = np.zeros(gain.shape, bool)
    for dy in range(size):
        for dx in range(size):
            marked[..., dy : dy + flat.shape[-2], dx : dx + flat.shape[-1]] |= flat
    return float((marked & live).sum() / max(live.sum(), 1))


@dataclass(frozen=True)
class RadioMapJob:
    """What to trace: a scene, the users (transmitters) and the horizontal plane of cells."""

    scene_xml: str
    users_m: tuple[tuple[float, float, float], ...]  # [num_users, 3]
    center_m: tuple[float, float, float]  # plane centre; z is the altitude
    size_m: tuple[float, float]
    cell_m: float

    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``: the plane's cells."""
        nx, ny = (round(s / self.cell_m) for s in self.size_m)
        return ny, nx

    def cell_centres(self) -> np.ndarray:
        """``[ny * nx, 3]`` the centres of the plane's cells at its height, x fastest (the order of ``map.ravel()``)."""
        ny, nx = self.shape
        corner = (self.center_m[0] - self.size_m[0] / 2, self.center_m[1] - self.size_m[1] / 2)
        ix, iy = np.meshgrid(np.arange(nx), np.arange(ny))
        return np.c_[
            corner[0] + (ix.ravel() + 0.5) * self.cell_m,
            corner[1] + (iy.ravel() + 0.5) * self.cell_m,
            np.full(ix.size, self.center_m[2]),
        ]


def sionna_versions() -> dict[str, str]:
    out = {}
    for pkg in ("sionna-rt", "mitsuba", "drjit"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "not installed"
    return out


#: The modules of the ``raytrace`` extra the ray tracer needs, with the package that brings each.
RAYTRACE_MODULES = {"sionna.rt": "sionna-rt", "mitsuba": "mitsuba", "drjit": "drjit"}


def require_raytrace() -> None:
    """``RuntimeError`` naming the extra and the packages when the ray tracer's modules are missing (checked before
    any child process starts, so that the error is one line, not a child's traceback)."""
    import importlib.util

    missing = []
    for module, package in RAYTRACE_MODULES.items():
        try:
            found = importlib.util.find_spec(module) is not None
        except ImportError:  # the parent package itself is missing
            found = False
        if not found:
            missing.append(package)
    if missing:
        raise RuntimeError(
            f"the ray tracer needs the raytrace extra (missing: {', '.join(missing)}): pip install -e '.[raytrace]' "
            "(on a CPU also apt-get install libllvm19)"
        )


def mitsuba_variant(device: str = "auto", cuda_available: bool | None = None) -> str:
    """The Mitsuba variant for ``device`` (``infra.device``'s rule: ``auto`` is CUDA where Dr.Jit finds a GPU, else
    LLVM on the CPU); ``ValueError`` for ``cuda`` without a GPU. ``cuda_available`` overrides the look (None: ask
    Dr.Jit)."""
    return VARIANTS[pick(device, _cuda_available() if cuda_available is None else cuda_available, "Dr.Jit")]


def _cuda_available() -> bool:
    if "DRJIT_LIBLLVM_PATH" not in os.environ and Path(LLVM_19).exists():
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM_19
    try:
        import drjit as dr
    except ImportError:
        return False
    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # noqa: BLE001 - Dr.Jit raises on a machine without the CUDA driver
        return False


def import_sionna(variant: str | None = None):
    """Import sionna.rt, in Mitsuba's ``variant`` when given (``llvm_ad_mono_polarized`` on a CPU,
    ``cuda_ad_mono_polarized`` on a GPU; None: Sionna's own choice); a clear error when the extra or LLVM is missing."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and Path(LLVM_19).exists():
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM_19
    try:
        import mitsuba as mi

        if variant is not None:
            mi.set_variant(variant)
        import sionna.rt as rt
    except ImportError as exc:
        raise RuntimeError(
            f"Sionna RT is not installed ({exc}): pip install -e '.[raytrace]' (and on a CPU: apt-get install libllvm19)"
        ) from None
    return mi, rt


def _scene(job: RadioMapJob, config: RayTraceConfig, variant: str | None = None):  # noqa: ANN202 - (mitsuba, sionna.rt, Scene)
    """The scene with the users' antenna (``config.antenna``) and an isotropic receiver, which is what Sionna's
    radio map assumes; exact paths take the same receiver, so that both estimate the same path gain. ``variant``:
    Mitsuba's (``import_sionna``; None: ``config.variant``)."""
    mi, rt = import_sionna(variant or config.variant)
    scene = rt.load_scene(job.scene_xml)
    scene.frequency = config.frequency_hz
    scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern=config.antenna, polarization="V")
    scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    return mi, rt, scene


def _set_users(mi, rt, scene, users: np.ndarray, start: int) -> None:  # noqa: ANN001
    for name in list(scene.transmitters):
        scene.remove(name)
    for k, (x, y, z) in enumerate(users):
        scene.add(rt.Transmitter(name=f"user{start + k}", position=mi.Point3f(float(x), float(y), float(z)), power_dbm=0.0))


def path_gain_maps(
    job: RadioMapJob,
    config: RayTraceConfig,
    on_batch: Callable[[int, int], None] | None = None,
    edge_diffraction: bool = False,
    variant: str | None = None,
) -> dict[int, np.ndarray]:
    """Raw path gain maps (linear), by cell factor: ``{1: [num_users, num_y, num_x], f: [num_users, cy, cx], ...}``.

    Cell ``(iy, ix)`` is centred at ``center - size / 2 + (i + 0.5) * cell``. A cell no ray reached holds 0.
    Besides the grid (factor 1), each of ``config.gap_fill_factors`` traces a map of cells that many times
    larger over the same corner (``fill`` uses them). ``on_batch(done, total)`` reports progress in users.
    ``edge_diffraction``: free edges diffract too (a screen's top; a city's extruded buildings have none).
    ``variant``: Mitsuba's (``import_sionna``; None: ``config.variant``).
    """
    mi, rt, scene = _scene(job, config, variant)
    solver = rt.RadioMapSolver()
    users = np.asarray(job.users_m, dtype=float)
    center_m, size_m, cell_m = job.center_m, job.size_m, job.cell_m
    out: dict[int, list[np.ndarray]] = {}
    for start in range(0, len(users), config.users_per_call):
        _set_users(mi, rt, scene, users[start : start + config.users_per_call], start)
        corner = (center_m[0] - size_m[0] / 2, center_m[1] - size_m[1] / 2)
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
                edge_diffraction=edge_diffraction and config.diffraction,
                refraction=config.refraction,
                seed=config.seed + start + 7919 * factor,
            )
            out.setdefault(factor, []).append(np.asarray(rm.path_gain.numpy(), dtype=np.float64))
        if on_batch is not None:
            on_batch(min(start + config.users_per_call, len(users)), len(users))
    return {f: np.concatenate(v, axis=0) for f, v in out.items()}


#: Exact paths: capacity of Sionna's path buffer per receiver point. The buffer is shared by all receivers of a
#: call (``max_num_paths_per_src``, 1e6 in all by default): with that default, 300 points of the procedural test
#: city lost paths (94 % live against 99 %, gains a median 4.9 dB apart); 33 k and 133 k per point agree within
#: 0.2 dB (median; p90 1.8 dB). Memory grows with it: 9.9 GB for 4e7 in all.
PATHS_PER_POINT = 100_000


def point_path_gains(
    job: RadioMapJob,
    points_m: np.ndarray,
    config: RayTraceConfig,
    on_batch: Callable[[int, int], None] | None = None,
    paths_per_point: int = PATHS_PER_POINT,
) -> np.ndarray:
    """Exact path gain (linear) from every user to every point [num_users, num_points], with Sionna's
    ``PathSolver`` (a receiver per point, every path found, as InSite computes them): the incoherent sum
    of the paths' powers, which is what a radio map estimates. 0 where no path was found. The path
    buffer holds ``paths_per_point`` candidates per point (``PATHS_PER_POINT``), at least Sionna's default 1e6."""
    mi, rt, scene = _scene(job, config)
    solver = rt.PathSolver()
    users = np.asarray(job.users_m, dtype=float)
    for k, (x, y, z) in enumerate(np.asarray(points_m, dtype=float)):
        scene.add(rt.Receiver(name=f"rx{k}", position=mi.Point3f(float(x), float(y), float(z))))
    out = np.zeros((len(users), len(points_m)))
    for u in range(len(users)):
        _set_users(mi, rt, scene, users[u : u + 1], u)
        paths = solver(
            scene,
            max_depth=config.max_depth,
            max_num_paths_per_src=max(1_000_000, int(paths_per_point) * len(points_m)),
            samples_per_src=int(config.samples_per_tx),
            diffraction=config.diffraction,
            edge_diffraction=config.diffraction,  # free edges too (a screen's top): every path, as InSite finds them
            refraction=config.refraction,
            seed=config.seed,
        )
        re, im = (np.asarray(x.numpy()) for x in paths.a)  # [num_rx, rx_ant, num_tx, tx_ant, num_paths]
        out[u] = (re**2 + im**2).reshape(len(points_m), -1).sum(axis=1)
        if on_batch is not None:
            on_batch(u + 1, len(users))
    return out


def direct_gains(
    job: RadioMapJob,
    config: RayTraceConfig,
    walls: dict[str, dict],
    on_batch: Callable[[int, int], None] | None = None,
    variant: str | None = None,
) -> dict[str, np.ndarray]:
    """The exact straight path through the walls from each user to each cell of the job's grid
    (``simulate.transmission``; ``walls``: each building shape's radio material as ``Material.at`` gives it, by shape
    id, ``transmission.EVERY_SHAPE`` for every shape but the ground: ``scene.walls_of``):
    ``{"direct": gain [U, ny, nx], "crossings": walls crossed [U, ny, nx]}`` (``max_depth + 1`` where too many)."""
    from uavplace.simulate.transmission import complex_permittivity, direct_path_gains

    mi, _, scene = _scene(job, config, variant)
    ny, nx = job.shape
    cells = job.cell_centres()
    slabs = {
        shape: (complex_permittivity(m["relative_permittivity"], m["conductivity_s_m"], config.frequency_hz), m["thickness_m"])
        for shape, m in walls.items()
    }
    gains, crossings = [], []
    users = np.asarray(job.users_m, float)
    for u, user in enumerate(users):
        g, n = direct_path_gains(
            mi,
            scene.mi_scene,
            user,
            cells,
            slabs,
            3e8 / config.frequency_hz,
            pattern=config.antenna,
            max_crossings=config.max_depth,
        )
        gains.append(g.reshape(ny, nx))
        crossings.append(n.reshape(ny, nx))
        if on_batch is not None:
            on_batch(u + 1, len(users))
    return {"direct": np.stack(gains), "crossings": np.stack(crossings)}


def _isolated(kind: str, payload: dict, on_batch: Callable[[int, int], None] | None) -> dict[str, np.ndarray]:
    """Run ``kind`` (``maps`` or ``points``) in a child Python process; its arrays by name.

    Dr.Jit/Mitsuba can crash while the interpreter shuts down (heap errors at exit after a
    correct run, seen here intermittently on the LLVM backend); running the solver in a child
    keeps that out of the caller. The child writes its result atomically and reports progress
    on stdout; a missing result is an error carrying the child's output.
    """
    require_raytrace()
    with tempfile.TemporaryDirectory(prefix="uavplace-rt-") as tmp:
        job_file = Path(tmp) / "job.json"
        result = Path(tmp) / "result.npz"
        job_file.write_text(json.dumps(payload | {"kind": kind, "result": str(result)}))
        proc = subprocess.Popen(
            [sys.executable, "-m", "uavplace.simulate.raytrace", str(job_file)],
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
            return {k: npz[k] for k in npz.files}


def path_gain_maps_isolated(
    job: RadioMapJob,
    config: RayTraceConfig,
    on_batch: Callable[[int, int], None] | None = None,
    edge_diffraction: bool = False,
    variant: str | None = None,
    walls: dict[str, dict] | None = None,
    threads: int | None = None,
) -> dict[int | str, np.ndarray]:
    """``path_gain_maps`` in a child Python process (see ``_isolated``); with ``walls`` (``direct_gains``') also the
    straight paths through the walls, ``direct_gains``'s ``"direct"`` and ``"crossings"``, in the same process (one
    start of the ray tracer). ``threads``: Dr.Jit's CPU threads in the child (None: all; 1: the
    radio map's sums in one order, so the same rays give the same map to the bit, which several threads' atomic
    additions do not)."""
    payload = {"job": asdict(job), "config": asdict(config), "edge_diffraction": edge_diffraction, "variant": variant}
    payload["threads"] = threads
    arrays = _isolated("maps", payload | ({"walls": walls} if walls is not None else {}), on_batch)
    return {(int(k.removeprefix("f")) if k.startswith("f") else k): v for k, v in arrays.items()}


def point_path_gains_isolated(
    job: RadioMapJob, points_m: np.ndarray, config: RayTraceConfig, on_batch: Callable[[int, int], None] | None = None
) -> np.ndarray:
    """``point_path_gains`` in a child Python process (see ``_isolated``)."""
    payload = {"job": asdict(job), "config": asdict(config), "points_m": np.asarray(points_m, float).tolist()}
    return _isolated("points", payload, on_batch)["gain"]


def exact_path_maps(
    job: RadioMapJob,
    config: RayTraceConfig,
    open_cells: np.ndarray,
    on_batch: Callable[[int, int], None] | None = None,
    cells_per_call: int = 128,
) -> np.ndarray:
    """Path gain maps [U, ny, nx] of ``job`` from exact paths alone (``point_path_gains``: PathSolver, a receiver at the
    centre of every cell of ``open_cells`` [ny, nx] at the plane's height, every path found); 0 where no path reaches a
    cell and at every cell with a building at or above the plane, as InSite leaves them. The cells go to child
    processes ``cells_per_call`` at a time (the path buffer grows with the receivers); ``on_batch(done, total)``
    counts cells."""
    if open_cells.shape != job.shape:
        raise ValueError(f"open_cells {open_cells.shape} is not the job's grid {job.shape}")
    chosen = np.flatnonzero(open_cells.ravel())
    cells = job.cell_centres()[chosen]
    out = np.zeros((len(job.users_m), open_cells.size))
    for start in range(0, len(cells), cells_per_call):
        part = slice(start, start + cells_per_call)
        out[:, chosen[part]] = point_path_gains_isolated(job, cells[part], config)
        if on_batch is not None:
            on_batch(min(start + cells_per_call, len(cells)), len(cells))
    return out.reshape(len(job.users_m), *job.shape)


def direct_gains_isolated(
    job: RadioMapJob, config: RayTraceConfig, walls: dict[str, dict], on_batch: Callable[[int, int], None] | None = None
) -> dict[str, np.ndarray]:
    """``direct_gains`` in a child Python process (see ``_isolated``)."""
    return _isolated("direct", {"job": asdict(job), "config": asdict(config), "walls": walls}, on_batch)


def _child(job_path: str) -> None:
    doc = json.loads(Path(job_path).read_text())
    if doc.get("threads"):
        import drjit as dr

        dr.set_thread_count(int(doc["threads"]))
    j = doc["job"]
    job = RadioMapJob(j["scene_xml"], tuple(map(tuple, j["users_m"])), tuple(j["center_m"]), tuple(j["size_m"]), j["cell_m"])
    config = RayTraceConfig(**doc["config"] | {"gap_fill_factors": tuple(doc["config"]["gap_fill_factors"])})

    def report(d: int, t: int) -> None:
        print(f"progress {d} {t}", flush=True)

    if doc["kind"] == "maps":
        maps = path_gain_maps(
            job, config, on_batch=report, edge_diffraction=doc.get("edge_diffraction", False), variant=doc.get("variant")
        )
        arrays = {f"f{k}": v for k, v in maps.items()}
        if doc.get("walls") is not None:
            arrays |= direct_gains(job, config, doc["walls"], variant=doc.get("variant"))
    elif doc["kind"] == "direct":
        arrays = direct_gains(job, config, doc["walls"], on_batch=report)
    else:
        arrays = {"gain": point_path_gains(job, np.asarray(doc["points_m"]), config, on_batch=report)}
    tmp = Path(doc["result"]).with_suffix(".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, doc["result"])
    sys.stdout.flush()
    # Skip interpreter teardown: the result is on disk, and Dr.Jit's shutdown is what can crash.
    os._exit(0)


if __name__ == "__main__":
    _child(sys.argv[1])

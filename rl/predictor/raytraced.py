"""The ray-traced tier: Sionna RT over what the UAV knows of the city, its public 3D map.

For a scene (``Scene``: the building heights on the grid, the altitude, the carrier, the user's power, the noise and
the floor) the tier writes a Mitsuba scene of the map alone (``map_blocks``: each run of cells of one height a
prism, every wall and roof of one declared generic material, a ground plane), never a user's map, the city's raw
export or its scene. Each candidate user is a transmitter ``user_height_m`` above the ground at its cell's centre;
Sionna's radio map gives the path gain at every cell of the UAV's plane with ``samples`` rays (``simulate.raytrace``,
in a child process: Dr.Jit may crash at interpreter exit). The cells the rays missed are walked to from the hit ones
(``simulate.fill.fill_geodesic``: the embedded cities' own completion, the straight path through the walls of the
material and a walk from the hit cells), and what stays unreached takes the fallback tier's prediction (``fallback``:
the physics tier, or the shipped learned tier).

SINR = power + gain - noise. The spread of its errors and the dead-cell probability are calibrated on training
cities' users (``calibrate``): a logistic in the traced SINR where the trace reached, another in the fallback's SINR
where it did not. Mitsuba's CUDA variant traces where a GPU is present (``simulate.raytrace.mitsuba_variant``), the LLVM one on a CPU; each
solver call on one Dr.Jit thread (the same rays, the same map to the bit), the cores used by Ray tasks
(``traced_gain``). The settings and the calibration are the tier's model card (``RayTracedModel``, ``model.json`` in its folder).

Arrays are ``[num_y, num_x]`` like the bundle's; cells ``(iy, ix)``; the scene's frame puts cell ``(iy, ix)``'s centre
at ``((ix + 0.5) s, (iy + 0.5) s)`` for a cell of ``s`` metres.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import numpy as np
import shapely
from pydantic import Field

from uavplace.infra.device import DEVICE_HELP, Device
from uavplace.infra.files import read_model_json, write_model_json
from uavplace.rl.predictor.base import code_digest, version_of
from uavplace.rl.predictor.physics import PhysicsConstants, PhysicsPredictor
from uavplace.rl.predictor.scene import Scene
from uavplace.schemas.base import Contract
from uavplace.simulate.raytrace import mitsuba_variant

#: The gain [linear] below which a cell counts as unreached (Sionna leaves a cell no ray hit at exactly 0).
UNREACHED_GAIN = 1e-30


class RayTracedModel(Contract):
    """``model.json`` of a ray-traced tier: its settings and its calibration (fitted on training cities). The defaults
    of the fallback and the spread are those the validation cities chose (docs/raytraced.md); the rays are a cost."""

    tier: Literal["raytraced"] = "raytraced"
    samples: int = Field(default=100_000, ge=1_000, le=100_000_000, description="Rays per candidate user")
    max_depth: int = Field(default=5, ge=1, le=10, description="Interactions a path may have")
    diffraction: bool = Field(default=True, description="Rays diffract at the buildings' edges")
    material: Literal["concrete"] = Field(
        default="concrete", description="The one generic material of every wall and roof (simulate/scene.py's CONCRETE)"
    )
    user_height_m: float = Field(default=1.5, ge=0, le=10, description="The user's antenna above the ground [m]")
    users_per_call: int = Field(default=32, ge=1, le=512, description="Candidates a solver call traces at once")
    walk_reach_m: float = Field(default=24.0, ge=0, le=200, description="How far a missed cell is walked to [m]")
    walk_decay_db_per_m: float = Field(default=3.0, ge=0, le=20, description="The walk's loss [dB per metre]")
    straight_path: bool = Field(
        default=True, description="A cell no ray hit takes the straight path through the walls of the material"
    )
    seed: int = Field(default=0, ge=0, description="The rays' seed (each call adds its first candidate's index)")
    device: Device = Field(default="auto", description=f"Where the rays are traced: {DEVICE_HELP}")
    constants: PhysicsConstants = Field(description="The physics tier (the fallback's, where it is physics)")
    fallback: Literal["physics", "learned"] = Field(
        default="learned",
        description="The tier that predicts the cells no ray reached: physics (the constants above) or learned (the "
        "shipped learned tier, data/agents/searcher/unet)",
    )
    error_db: float = Field(default=6.0, gt=0, description="Std of (measured - predicted) SINR on live cells [dB]")
    spread_estimator: Literal["std", "robust"] = Field(
        default="robust",
        description="How error_db is estimated: std, or robust (1.4826 x the median absolute deviation: the core of "
        "heavy-tailed errors, the likelihood's outlier share holding the tail)",
    )
    spread_cells: Literal["all", "reached"] = Field(
        default="all",
        description="The live cells error_db is calibrated on: all (the fallback's too) or those a ray or the walk reached",
    )
    dead_level_db: float = Field(default=-10.0, description="Traced SINR at which a reached cell is dead with p 1/2 [dB]")
    dead_scale_db: float = Field(default=3.0, gt=0, description="Width of the reached cells' dead logistic [dB]")
    unreached_level_db: float = Field(
        default=-10.0, description="The fallback tier's SINR at which a cell no ray reached is dead with p 1/2 [dB]"
    )
    unreached_scale_db: float = Field(default=3.0, gt=0, description="Width of the unreached cells' dead logistic [dB]")
    calibrated_on: list[str] = Field(default_factory=list, description="city@version of the calibration bundles")
    calibration_users: int = Field(default=0, ge=0, description="Training users the calibration was fitted on")
    scores: dict[str, dict[str, float]] = Field(default_factory=dict, description="Per validation city: scores_of")
    made_by: list[str] = Field(default_factory=list, description="The commands that made it, in order")


def map_blocks(scene: Scene) -> list:
    """The UAV's 3D map as prisms (``simulate.scene.Block``): per distinct building height, the union of its cells'
    squares, one prism per polygon of it, from the ground to that height. Heights are the scene's own (rounded to
    the centimetre so that a height map's float noise does not split a roof)."""
    from uavplace.simulate.scene import Block

    h = np.round(scene.ground_height_m.astype(np.float64), 2)
    s = scene.spacing_m
    blocks = []
    for value in np.unique(h[h > 0]):
        iy, ix = np.nonzero(h == value)
        boxes = shapely.box(ix * s, iy * s, (ix + 1) * s, (iy + 1) * s)
        merged = shapely.union_all(boxes)
        for part in shapely.get_parts(merged):
            blocks.append(Block(part, 0.0, float(value)))
    return blocks


def cell_centres_m(cells: np.ndarray, spacing_m: float) -> np.ndarray:
    """``[N, 2]`` (x, y) [m] of cells ``(iy, ix)`` in the scene's frame."""
    cells = np.asarray(cells, np.float64).reshape(-1, 2)
    return np.stack([(cells[:, 1] + 0.5) * spacing_m, (cells[:, 0] + 0.5) * spacing_m], axis=1)


def parts(num_users: int, workers: int, users_per_call: int) -> list[tuple[int, int]]:
    """``[(start, stop), ...]``: ``num_users`` in at most ``workers`` runs of whole solver calls (``users_per_call``
    each but the last): the calls, and so the rays, are those of one run whatever the number of parts."""
    calls = max(1, -(-num_users // users_per_call))
    per = -(-calls // max(1, min(workers, calls))) * users_per_call
    return [(a, min(a + per, num_users)) for a in range(0, num_users, per)] or [(0, 0)]


def traced_gain(
    scene: Scene,
    users: np.ndarray,
    model: RayTracedModel,
    on_batch: Callable[[int, int], None] | None = None,
    workers: int = 1,
) -> np.ndarray:
    """``[U, num_y, num_x]`` the path gain (linear) from a user at each of ``users`` [U, 2] to every cell of the UAV's
    plane, traced over the scene's map and completed (0 where nothing reached). With ``workers`` > 1 the users are
    traced in ``parts`` as Ray tasks on the Ray this process has joined (``infra.cluster.start_ray``: local, or a
    cluster by address), each writing the map's scene where it runs; the maps are the same as in one run."""
    users = np.asarray(users, np.int64).reshape(-1, 2)
    runs = parts(len(users), workers, model.users_per_call)
    if len(runs) == 1:
        raw = [_trace_part(scene, users, model, 0, on_batch)]
    else:
        import ray

        task = ray.remote(num_cpus=1, max_retries=0)(_trace_part)
        scene_ref = ray.put(scene)
        refs = [task.remote(scene_ref, users[a:b], model, a, None) for a, b in runs]
        raw = []
        for ref, (_, b) in zip(refs, runs, strict=True):
            raw.append(ray.get(ref))
            if on_batch is not None:
                on_batch(b, len(users))
    fine = np.concatenate([r[0] for r in raw])
    direct = np.concatenate([r[1] for r in raw])
    ny, nx = scene.ground_height_m.shape
    s = scene.spacing_m
    xy = cell_centres_m(users, s)
    centres = cell_centres_m(np.argwhere(np.ones((ny, nx), bool)), s).reshape(ny, nx, 2)
    d2 = (centres[None, :, :, 0] - xy[:, 0, None, None]) ** 2 + (centres[None, :, :, 1] - xy[:, 1, None, None]) ** 2
    d2 = d2 + (scene.altitude_m - model.user_height_m) ** 2
    from uavplace.simulate.fill import fill_geodesic
    from uavplace.simulate.raytrace import RayTraceConfig, free_space_cap

    fine = np.minimum(fine, free_space_cap(d2, scene.frequency_hz, RayTraceConfig.antenna))  # grazing rays' artifacts
    gain, _ = fill_geodesic(
        fine,
        direct,
        scene.ground_height_m < scene.altitude_m,
        d2,
        reach_m=model.walk_reach_m,
        decay_db_per_m=model.walk_decay_db_per_m,
        cell_m=s,
        walk="4-neighbour",
    )
    return gain


def _trace_part(
    scene: Scene, users: np.ndarray, model: RayTracedModel, first: int, on_batch: Callable[[int, int], None] | None
) -> tuple[np.ndarray, np.ndarray]:
    """(the radio map's gain, the straight paths' gain), each ``[U, num_y, num_x]``, of ``users`` (the ``first``-th
    of a larger set onwards: their calls' seeds are those of the whole set's), the map's scene written in a
    temporary folder here, the ray tracer in a child process on one thread (the same rays give the same map to the
    bit; ``workers`` Ray tasks use the cores)."""
    from uavplace.simulate.raytrace import RadioMapJob, RayTraceConfig, path_gain_maps_isolated
    from uavplace.simulate.scene import walls_of, write_scene

    ny, nx = scene.ground_height_m.shape
    s = scene.spacing_m
    xy = cell_centres_m(users, s)
    config = RayTraceConfig(
        frequency_hz=scene.frequency_hz,
        samples_per_tx=model.samples,
        max_depth=model.max_depth,
        diffraction=model.diffraction,
        seed=model.seed + first,
        users_per_call=model.users_per_call,
    )
    with tempfile.TemporaryDirectory(prefix="uavplace-map-") as tmp:
        xml, materials = write_scene(tmp, map_blocks(scene), (0.0, 0.0, nx * s, ny * s), scene.frequency_hz)
        job = RadioMapJob(
            scene_xml=str(xml),
            users_m=tuple((float(x), float(y), float(model.user_height_m)) for x, y in xy),
            center_m=(nx * s / 2, ny * s / 2, float(scene.altitude_m)),
            size_m=(nx * s, ny * s),
            cell_m=s,
        )
        walls = walls_of(materials) if model.straight_path else None
        traced = path_gain_maps_isolated(
            job, config, on_batch=on_batch, variant=mitsuba_variant(model.device), walls=walls, threads=1
        )
    fine = np.where(traced[1] > UNREACHED_GAIN, traced[1], 0.0)
    return fine, (traced["direct"] if model.straight_path else np.zeros_like(fine))


#: This process's traces (``RayTracedPredictor.traced_sinr``), oldest first, at most ``TRACES_KEPT``.
TRACES: dict[str, np.ndarray] = {}
TRACES_KEPT = 64
#: The model's fields a trace depends on (the rest is calibration, fallback and how it runs).
TRACE_FIELDS = (
    "samples",
    "max_depth",
    "diffraction",
    "material",
    "user_height_m",
    "users_per_call",
    "walk_reach_m",
    "walk_decay_db_per_m",
    "straight_path",
    "seed",
)


def trace_key(scene: Scene, users: np.ndarray, model: RayTracedModel) -> str:
    """The sha256 of what a trace depends on: the scene's arrays and settings, the users, the trace's settings, the
    variant and the family's code."""
    import hashlib
    import json

    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(scene.ground_height_m).tobytes())
    digest.update(np.ascontiguousarray(users).tobytes())
    settings = {f: getattr(model, f) for f in TRACE_FIELDS}
    others = [scene.spacing_m, scene.altitude_m, scene.frequency_hz, scene.tx_power_dbm, scene.noise_dbm]
    digest.update(json.dumps([settings, others, mitsuba_variant(model.device), code_digest()], sort_keys=True).encode())
    return digest.hexdigest()


class RayTracedPredictor:
    """The ray-traced tier as a predictor of many users' maps (the ``Predictor`` protocol)."""

    tier = "raytraced"

    def __init__(self, model: RayTracedModel, workers: int = 1) -> None:
        self.model = model
        self.error_db = model.error_db
        self.fallback = fallback_tier(model)
        #: Ray tasks a call's candidates are traced in (1: in this process; the maps are the same either way).
        self.workers = workers
        #: Told ``(users done, users)`` as a call's candidates are traced, or None.
        self.on_batch: Callable[[int, int], None] | None = None

    def version(self) -> str:
        """12 hex digits of the settings, the calibration, the physics tier's constants, the family's code, the ray
        tracer's packages and the variant that traces (the device it resolves to, not the setting): a cache of its
        maps' key."""
        from uavplace.simulate.raytrace import sionna_versions

        doc = self.model.model_dump(mode="json", exclude={"scores", "made_by", "calibrated_on", "device"})
        return version_of(
            {
                "tier": self.tier,
                "model": doc,
                "fallback": self.fallback.version(),
                "variant": mitsuba_variant(self.model.device),
                "code": code_digest(),
                "packages": sionna_versions(),
            }
        )

    def traced_sinr(self, scene: Scene, users: np.ndarray) -> np.ndarray:
        """``[U, num_y, num_x]`` the traced SINR [dB] of each user (``-inf`` where nothing reached). The traces of this
        process are kept in memory (``TRACES``), keyed by the scene, the users and the trace's settings (not the
        calibration): tiers that differ only in their calibration or fallback trace once."""
        users = np.asarray(users, np.int64).reshape(-1, 2)
        key = trace_key(scene, users, self.model)
        if key not in TRACES:
            gain = traced_gain(scene, users, self.model, self.on_batch, self.workers)
            with np.errstate(divide="ignore"):
                TRACES[key] = (scene.tx_power_dbm + 10 * np.log10(gain) - scene.noise_dbm).astype(np.float32)
            while len(TRACES) > TRACES_KEPT:
                TRACES.pop(next(iter(TRACES)))
        return TRACES[key]

    def predict(self, scene: Scene, users: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``mu``, ``p_dead``), each ``[U, M]`` float32: the traced SINR at ``cells`` [M, 2] where a ray or the walk
        reached, the fallback tier's elsewhere, and the calibrated probability that the cell is dead or at the
        floor."""
        users = np.asarray(users, np.int64).reshape(-1, 2)
        cells = np.asarray(cells, np.int64).reshape(-1, 2)
        traced = self.traced_sinr(scene, users)[:, cells[:, 0], cells[:, 1]]  # [U, M]
        return self.combine(traced, self.fallback.predict(scene, users, cells)[0])

    def combine(self, traced: np.ndarray, fallback_mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``mu``, ``p_dead``) from the traced SINR [U, M] (``-inf``: unreached) and the fallback tier's [U, M]: a
        reached cell's traced value and its logistic, an unreached cell's fallback value and the unreached logistic."""
        m = self.model
        reached = np.isfinite(traced)
        mu = np.where(reached, traced, fallback_mu).astype(np.float32)
        level = np.where(reached, m.dead_level_db, m.unreached_level_db)
        scale = np.where(reached, m.dead_scale_db, m.unreached_scale_db)
        z = np.clip((mu - level) / scale, -60, 60)
        return mu, (1.0 / (1.0 + np.exp(z))).astype(np.float32)


def calibrate(
    model: RayTracedModel, traced: np.ndarray, fallback_mu: np.ndarray, measured: np.ndarray, low: np.ndarray
) -> RayTracedModel:
    """``model`` with its spread and its two dead logistics fitted on training users' cells: ``traced`` [R] the traced
    SINR (``-inf`` unreached), ``fallback_mu`` [R] the fallback tier's, ``measured`` [R] the embedded SINR, ``low``
    [R] dead or at the floor. The logistics by maximum likelihood (``logistic``), in the traced
    SINR on the reached cells and in the fallback's on the unreached ones (where the trace missed, a cell is dead far
    more often than the fallback alone says); the spread is the std of (measured - predicted) on the live cells
    (``RayTracedModel.spread_cells``: all of them, or the reached ones), the prediction the tier's own (traced, else
    the fallback's)."""
    reached = np.isfinite(traced)
    live = ~low
    for name, cells in (("reached", reached), ("unreached", ~reached)):
        if (cells & live).sum() < 10 or (cells & low).sum() < 1:
            raise ValueError(
                f"too few {name} cells to calibrate on: {int((cells & live).sum())} live, {int((cells & low).sum())} low"
            )
    mu = np.where(reached, traced, fallback_mu)
    spread = live & reached if model.spread_cells == "reached" else live
    residual = measured[spread] - mu[spread]
    if model.spread_estimator == "robust":
        error = float(1.4826 * np.median(np.abs(residual - np.median(residual))))
    else:
        error = float(np.std(residual))
    level, scale = logistic(traced[reached], low[reached])
    u_level, u_scale = logistic(fallback_mu[~reached], low[~reached])
    update = {"error_db": max(error, 0.1), "dead_level_db": level, "dead_scale_db": scale}
    return model.model_copy(update=update | {"unreached_level_db": u_level, "unreached_scale_db": u_scale})


def logistic(x_db: np.ndarray, event: np.ndarray) -> tuple[float, float]:
    """(level, width) [dB] of ``P(event) = 1 / (1 + exp((x - level) / width))`` of least cross-entropy
    (``scores.platt_scaling`` on ``x / 10``, Newton's steps halved until the loss falls: rare events and heavy tails
    do not throw it off); a width of 1000 dB when the event does not fall with ``x``."""
    from uavplace.rl.predictor.scores import platt_scaling

    a, b = platt_scaling(-np.asarray(x_db, np.float64) / 10.0, event)
    if a <= 0:
        return float(np.median(x_db)), 1000.0
    return float(10.0 * b / a), float(max(10.0 / a, 1e-3))


def fallback_tier(model: RayTracedModel):  # noqa: ANN201 - a Predictor
    """The tier that predicts the cells no ray reached (``RayTracedModel.fallback``): the physics tier of the model's
    constants, or the shipped learned tier (never a folder a model card names: a card is data)."""
    if model.fallback == "physics":
        return PhysicsPredictor(model.constants)
    from uavplace.rl.config import DEFAULT_PREDICTOR
    from uavplace.rl.predictor.learned import load_learned

    return load_learned(DEFAULT_PREDICTOR)


def load_raytraced(folder: str | Path) -> RayTracedPredictor:
    """The ray-traced tier in ``folder`` (its ``model.json``); ``InputError`` naming the file when unreadable or
    invalid."""
    what = "a ray-traced predictor's description (`uavrl calibrate-raytraced` writes it)"
    return RayTracedPredictor(read_model_json(Path(folder) / "model.json", RayTracedModel, what))


def save_raytraced(folder: Path, model: RayTracedModel) -> None:
    """Write ``model.json`` into ``folder`` (created)."""
    folder.mkdir(parents=True, exist_ok=True)
    write_model_json(model, folder / "model.json")

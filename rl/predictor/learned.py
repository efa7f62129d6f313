"""The learned tier of the radio-map predictor: a small U-Net that corrects the physics tier.

Input planes of a user at cell ``(iy, ix)``, each ``[num_y, num_x]``, all public (``input_planes``): the building
height and the cells the UAV may not enter, the user's cell, and the physics tier's features and prediction of
that user's map (``physics.path_features``: log distance, walls crossed, Deygout's loss; the predicted SINR over
the floor and the dead-cell probability). The network (``MapUNet``: ``len(widths)`` levels, two 3 x 3 convolutions
each, max-pooling down, transposed convolutions up, skip connections) outputs two planes: a correction of the
physics SINR, in units of ``SCALE_DB``, and a correction of the dead-cell logit. With both corrections zero it is the
physics tier.

Training (``train_learned``): the legal cells of the training corpus's users, random crops of ``crop`` cells under
the eight symmetries of the square; the loss is a Huber loss on the live cells above the floor plus the binary
cross-entropy of the dead-or-at-floor call on every legal cell. The weights are saved as tensors only
(``weights.pt``, read with ``torch.load(weights_only=True)``) beside ``model.json`` (``LearnedModel``: the settings,
the physics constants it refines, the residual's spread and the scores it was measured at) and a model card.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from pydantic import Field
from torch import nn
from torch.nn import functional as F

from uavplace.dataset.bundle import Bundle
from uavplace.dataset.export import read_radiomapseer
from uavplace.dataset.trainmaps import TrainingMaps, read_pack, select_packs
from uavplace.infra.cluster import ray_driver
from uavplace.infra.files import read_model_json, sha256_file, write_model_json
from uavplace.infra.limits import check_limit
from uavplace.infra.tensors import save_tensors
from uavplace.rl.config import UNetConfig
from uavplace.rl.predictor.base import code_digest, version_of
from uavplace.rl.predictor.physics import PhysicsConstants, dead_probability, path_features, sinr_from_features
from uavplace.rl.predictor.scene import Scene
from uavplace.rl.predictor.scores import platt_scaling
from uavplace.rl.predictor.weights import load_weights
from uavplace.schemas.base import Contract

#: The learned tier's files in its folder.
MODEL_JSON, WEIGHTS, MODEL_CARD = "model.json", "weights.pt", "MODEL_CARD.md"
#: The input planes, in order.
PLANES = ("ground", "blocked", "user", "log_d", "walls", "diffraction", "physics_sinr", "physics_dead")
#: SINR [dB] per unit of the network's first output plane and of the SINR input plane.
SCALE_DB = 20.0


class LearnedModel(Contract):
    """``model.json``: how a learned tier was made and what it scored."""

    config: UNetConfig
    constants: PhysicsConstants = Field(description="The physics tier whose maps it corrects")
    error_db: float = Field(gt=0, description="Std of (measured - predicted) SINR on the training users' live cells")
    fitted_on: list[str] = Field(default_factory=list, description="city@version of the training bundles")
    users: int = Field(ge=0, description="Training users")
    train_seconds: float = Field(ge=0)
    final_loss: float
    weights_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    scores: dict[str, dict[str, float]] = Field(
        default_factory=dict, description="Per validation city: prediction_scores of this tier and of the physics tier"
    )
    calibration: tuple[float, float] = Field(
        default=(1.0, 0.0),
        description="(scale, bias) of the dead-cell logit: p_dead = sigmoid(scale * logit + bias), fitted on held-out "
        "training users ((1, 0): uncalibrated)",
    )
    calibration_users: int = Field(default=0, ge=0, description="Training users held out to fit the calibration")
    calibrated_on: list[str] = Field(
        default_factory=list,
        description="city@version of the training-maps packs the calibration was fitted on by `uavrl calibrate-predictor` "
        "(cities the network was not trained on); empty: fitted on the held-out training users",
    )
    made_by: list[str] = Field(default_factory=list, description="The commands that made it, in order")
    reliability: dict[str, list[list[float]]] = Field(
        default_factory=dict,
        description="Per validation city: this tier's reliability diagram of the dead probability, rows [mean p, "
        "observed frequency, cells] of ten equal-width bins (rl/predictor/scores.py, reliability)",
    )


class MapUNet(nn.Module):
    """A U-Net of ``widths`` channels per level: ``len(PLANES)`` planes in, two out (SINR and dead-logit corrections)."""

    def __init__(self, widths: list[int]) -> None:
        super().__init__()

        def block(c_in: int, c_out: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv2d(c_in, c_out, 3, padding=1), nn.ReLU(), nn.Conv2d(c_out, c_out, 3, padding=1), nn.ReLU()
            )

        self.down = nn.ModuleList()
        c = len(PLANES)
        for w in widths:
            self.down.append(block(c, w))
            c = w
        self.up = nn.ModuleList(nn.ConvTranspose2d(widths[i + 1], widths[i], 2, stride=2) for i in range(len(widths) - 1))
        self.merge = nn.ModuleList(block(2 * widths[i], widths[i]) for i in range(len(widths) - 1))
        self.head = nn.Conv2d(widths[0], 2, 1)
        nn.init.zeros_(self.head.weight)  # starts as the physics tier
        nn.init.zeros_(self.head.bias)

    @property
    def multiple(self) -> int:
        """Input sides must be a multiple of this."""
        return 2 ** (len(self.down) - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, block in enumerate(self.down):
            if i:
                x = F.max_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        for i in reversed(range(len(self.up))):
            x = self.merge[i](torch.cat([skips[i], self.up[i](x)], dim=1))
        return self.head(x)


def input_planes(scene: Scene, constants: PhysicsConstants, user: tuple[int, int]) -> np.ndarray:
    """``[len(PLANES), num_y, num_x]`` float32: the network's input for a user at cell ``user`` (module docstring)."""
    f = path_features(scene, user, constants.user_height_m)
    sinr = sinr_from_features(f, scene, constants)
    onehot = np.zeros_like(scene.ground_height_m)
    onehot[int(user[0]), int(user[1])] = 1.0
    planes = [
        np.minimum(scene.ground_height_m / 20.0, 5.0),
        (scene.ground_height_m >= scene.altitude_m).astype(np.float32),
        onehot,
        f["log_d"] - 2.0,
        np.minimum(f["walls"], constants.max_walls) / constants.max_walls,
        f["diffraction_db"] / SCALE_DB,
        (sinr - scene.floor_db) / SCALE_DB,
        dead_probability(sinr, constants),
    ]
    return np.stack(planes).astype(np.float32)


def _padded_planes(scene: Scene, constants: PhysicsConstants, users: np.ndarray, ny: int, nx: int) -> np.ndarray:
    """``[len(users), len(PLANES), ny, nx]``: ``input_planes`` of each of ``users``, padded to ``ny`` x ``nx`` (a batch's
    input, made here or in a Ray task)."""
    return np.stack([_pad_to(input_planes(scene, constants, (int(u[0]), int(u[1]))), ny, nx) for u in users])


def _physics_logit(planes: torch.Tensor) -> torch.Tensor:
    p = planes[:, PLANES.index("physics_dead")].clamp(1e-6, 1 - 1e-6)
    return torch.log(p) - torch.log1p(-p)


def _outputs(net: MapUNet, planes: torch.Tensor, floor_db: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(mu [B, H, W] dB, dead logit [B, H, W]) of a batch of input planes ``[B, P, H, W]``."""
    out = net(planes)
    physics = planes[:, PLANES.index("physics_sinr")] * SCALE_DB + floor_db.view(-1, 1, 1)
    return physics + SCALE_DB * out[:, 0], _physics_logit(planes) + out[:, 1]


def _padded(ny: int, nx: int, multiple: int) -> tuple[int, int]:
    """The least sides from ``(ny, nx)`` up that are multiples of ``multiple``."""
    return -(-ny // multiple) * multiple, -(-nx // multiple) * multiple


def _pad_to(a: np.ndarray, ny: int, nx: int) -> np.ndarray:
    pad = [(0, 0)] * (a.ndim - 2) + [(0, ny - a.shape[-2]), (0, nx - a.shape[-1])]
    return np.pad(a, pad)


class LearnedPredictor:
    """The learned tier as a predictor of many users' maps (the ``Predictor`` protocol)."""

    tier = "learned"

    def __init__(self, model: LearnedModel, net: MapUNet, batch: int = 16) -> None:
        self.model, self.net, self.batch = model, net.eval(), batch
        self.constants = model.constants
        self.error_db = model.error_db

    def version(self) -> str:
        return version_of(
            {
                "tier": self.tier,
                "weights": self.model.weights_sha256,
                "constants": self.constants.version(),
                "config": self.model.config.model_dump(mode="json"),
                "code": code_digest(),
                "calibration": list(self.model.calibration),
            }
        )

    def _planes(self, scene: Scene, users: np.ndarray, ny: int, nx: int):  # noqa: ANN202 - a generator of arrays
        """Each batch's padded input planes, in order. In the driver of a Ray it has joined, the batches' planes (the
        physics tier's path features, two thirds of a prediction) are Ray tasks, a few ahead of the batch the network
        reads here: the same arrays, and the network runs here on them as it would alone."""
        starts = range(0, len(users), self.batch)
        if not ray_driver() or len(starts) < 2:
            for i in starts:
                yield _padded_planes(scene, self.constants, users[i : i + self.batch], ny, nx)
            return
        import ray

        task = ray.remote(num_cpus=1, max_retries=0)(_padded_planes)
        ahead = 2 * max(1, int(ray.cluster_resources().get("CPU", 1)))
        scene_ref = ray.put(scene)
        refs, submitted = [], 0
        try:
            for _ in starts:
                while submitted < len(starts) and len(refs) < ahead:
                    k = starts[submitted]
                    refs.append(task.remote(scene_ref, self.constants, users[k : k + self.batch], ny, nx))
                    submitted += 1
                yield np.array(ray.get(refs.pop(0)))  # a writable copy of the store's read-only array
        finally:
            for ref in refs:
                ray.cancel(ref, force=True)

    @torch.no_grad()
    def _chunks(self, scene: Scene, users: np.ndarray, cells: np.ndarray):  # noqa: ANN202 - a generator of tensors
        """Per chunk of at most ``batch`` users: (its first row, ``mu`` [b, M], the uncalibrated dead logit [b, M])."""
        ny, nx = scene.ground_height_m.shape
        py, px = _padded(ny, nx, self.net.multiple)
        floor = torch.tensor([scene.floor_db], dtype=torch.float32)
        for i, x in zip(range(0, len(users), self.batch), self._planes(scene, users, py, px), strict=True):
            mu_b, logit_b = _outputs(self.net, torch.from_numpy(x), floor.expand(len(x)))
            yield i, mu_b[:, cells[:, 0], cells[:, 1]], logit_b[:, cells[:, 0], cells[:, 1]]

    def predict(self, scene: Scene, users: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``mu``, ``p_dead``), each ``[U, M]`` float32, as ``PhysicsPredictor.predict``."""
        users, cells = np.asarray(users, np.int64).reshape(-1, 2), np.asarray(cells, np.int64).reshape(-1, 2)
        scale, bias = (float(v) for v in self.model.calibration)
        mu = np.empty((len(users), len(cells)), np.float32)
        p_dead = np.empty_like(mu)
        for i, mu_b, logit_b in self._chunks(scene, users, cells):
            mu[i : i + len(mu_b)] = mu_b.numpy()
            p_dead[i : i + len(mu_b)] = torch.sigmoid(scale * logit_b + bias).numpy()
        return mu, p_dead

    def dead_logits(self, scene: Scene, users: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """``[U, M]`` float32: the dead-cell logit before the calibration (what Platt scaling is fitted on)."""
        users, cells = np.asarray(users, np.int64).reshape(-1, 2), np.asarray(cells, np.int64).reshape(-1, 2)
        out = np.empty((len(users), len(cells)), np.float32)
        for i, _mu, logit_b in self._chunks(scene, users, cells):
            out[i : i + len(logit_b)] = logit_b.numpy()
        return out


def load_learned(folder: str | Path) -> LearnedPredictor:
    """The learned tier in ``folder`` (``model.json`` and ``weights.pt``); ``InputError`` naming the file when
    unreadable, invalid, or when the weights are not the ones ``model.json`` names."""
    folder = Path(folder)
    what = "a learned predictor's description (`uavrl train-predictor` writes it)"
    model = read_model_json(folder / MODEL_JSON, LearnedModel, what)
    net = MapUNet(model.config.widths)
    load_weights(net, folder / WEIGHTS, model.weights_sha256, f"widths {model.config.widths}")
    return LearnedPredictor(model, net)


def training_maps(
    bundles: list[Bundle], users: list, folders: tuple[Path, ...] = (), patterns: tuple[str, ...] = ()
) -> list[TrainingMaps]:
    """The maps a predictor trains on: ``users`` of each of ``bundles``, then the packs of each folder of packs whose
    city matches one of ``patterns`` (``select_packs``; every pack without one), or one RadioMapSeer-style city folder
    (`uavdata export`: it has a ``scale.json``); a folder or pack given twice is read once."""
    maps = [TrainingMaps.of_bundle(b, u) for b, u in zip(bundles, users, strict=True)]
    folders = tuple({Path(f).resolve(): Path(f) for f in folders}.values())  # a folder given twice is read once
    exported = [f for f in folders if (f / "scale.json").is_file()]
    maps += [read_radiomapseer(f) for f in exported]
    return maps + [read_pack(p) for p in select_packs([f for f in folders if f not in exported], patterns)]


def training_examples(maps: list[TrainingMaps], constants: PhysicsConstants) -> list[tuple]:
    """Per training user: (planes [P, H, W], sinr [H, W], live-above-floor [H, W], low [H, W], legal [H, W], floor)."""
    out = []
    for m in maps:
        scene = Scene.from_settings(m.settings, m.height_rel_m)
        legal = ~m.blocked
        for i, (iy, ix) in enumerate(m.users):
            planes = input_planes(scene, constants, (int(iy), int(ix)))
            sinr, dead = m.sinr_db[i].astype(np.float32), m.dead[i]
            live = ~dead & (sinr > scene.floor_db + 1e-3) & legal
            out.append((planes, sinr, live, (~live) & legal, legal, scene.floor_db))
    return out


def _symmetry(a: np.ndarray, k: int) -> np.ndarray:
    """``a`` [..., H, W] under the k-th of the square's eight symmetries."""
    a = np.rot90(a, k % 4, axes=(-2, -1))
    return a[..., ::-1] if k >= 4 else a


def _batch(examples: list[tuple], config: UNetConfig, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
    c = config.crop
    xs, ys, lives, lows, legals, floors = [], [], [], [], [], []
    for _ in range(config.batch):
        planes, sinr, live, low, legal, floor = examples[int(rng.integers(len(examples)))]
        h, w = sinr.shape
        y0, x0 = int(rng.integers(max(h - c, 0) + 1)), int(rng.integers(max(w - c, 0) + 1))
        k = int(rng.integers(8))
        for target, a in ((xs, planes), (ys, sinr), (lives, live), (lows, low), (legals, legal)):
            target.append(_pad_to(_symmetry(a[..., y0 : y0 + c, x0 : x0 + c], k), c, c))
        floors.append(floor)
    x, y = torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(ys))
    live_t, low_t, legal_t = (torch.from_numpy(np.stack(a)) for a in (lives, lows, legals))
    return x, y, live_t, low_t, legal_t, torch.tensor(floors, dtype=torch.float32)


def _loss(net: MapUNet, batch: tuple[torch.Tensor, ...], dead_weight: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, residuals of the live cells [dB])."""
    x, y, live, low, legal, floor = batch
    mu, logit = _outputs(net, x, floor)
    residual = (mu - y)[live]
    reg = F.huber_loss(residual / SCALE_DB, torch.zeros_like(residual), delta=0.5) if residual.numel() else mu.sum() * 0
    bce = F.binary_cross_entropy_with_logits(logit[legal], low[legal].float()) if legal.any() else mu.sum() * 0
    return reg + dead_weight * bce, residual.detach()


def train_learned(
    maps: list[TrainingMaps],
    constants: PhysicsConstants,
    config: UNetConfig,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[MapUNet, dict]:
    """Train the U-Net on the users of ``maps`` (module docstring; ``TrainingMaps.of_bundle`` or packs), less
    ``config.calibration_share`` of them held out (a seeded draw) to fit the dead probability's calibration. Returns
    (network, facts: ``error_db`` the residual std on the training users' live cells, ``train_seconds``,
    ``final_loss``, ``users``, ``calibration``, ``calibration_users``)."""
    what = "activations of one training step, --batch x --crop x --widths [bytes]"
    check_limit("predictor_step_bytes", step_bytes(config), None, what, field="widths")  # before any map is read
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    rng = np.random.default_rng(config.seed)
    examples = training_examples(maps, constants)
    if not examples:
        raise ValueError("train_learned: no user to train on")
    held = int(config.calibration_share * len(examples))
    if held:
        order = np.random.default_rng([config.seed, 1]).permutation(len(examples))
        calibration = [examples[i] for i in sorted(order[:held])]
        examples = [examples[i] for i in sorted(order[held:])]
    net = MapUNet(config.widths)
    if config.crop % net.multiple:
        raise ValueError(f"crop {config.crop} is not a multiple of {net.multiple} ({len(config.widths)} levels)")
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, config.steps, eta_min=config.lr / 20)
    t0, recent = time.perf_counter(), []
    for step in range(config.steps):
        loss, _ = _loss(net, _batch(examples, config, rng), config.dead_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        recent = (recent + [loss.item()])[-50:]
        if progress is not None:
            progress(step + 1, float(np.mean(recent)))
    train_s = time.perf_counter() - t0
    net.eval()
    residuals = []
    for mu, _logit, sinr, live, _low, _legal in _whole_maps(net, examples):  # the searcher's likelihood width
        residuals.append((mu - sinr)[live])
    error = float(np.std(np.concatenate(residuals)))
    return net, {
        "error_db": error,
        "train_seconds": train_s,
        "final_loss": float(np.mean(recent)),
        "users": len(examples),
        "calibration": fit_calibration(net, calibration) if held else (1.0, 0.0),
        "calibration_users": held,
    }


def step_bytes(config: UNetConfig) -> int:
    """About what one training step holds in memory: per crop, each level's cells (a quarter of the level above's)
    times its channels, for the convolutions down and up, forward and backward, in float32 (32 bytes a value and
    channel, measured near 4.9 GB at 1024 crops of 64 cells and the default widths)."""
    cells = sum((config.crop // 2**level) ** 2 * w for level, w in enumerate(config.widths))
    return 32 * config.batch * cells


def _whole_maps(net: MapUNet, examples: list[tuple]):  # noqa: ANN202 - a generator of arrays
    """Per example, over its whole map (no crop): (mu, dead logit, sinr, live, low, legal), each [H, W]."""
    with torch.no_grad():
        for planes, sinr, live, low, legal, floor in examples:
            h, w = sinr.shape
            ph, pw = _padded(h, w, net.multiple)
            mu, logit = _outputs(net, torch.from_numpy(_pad_to(planes, ph, pw))[None], torch.tensor([floor]))
            yield mu[0, :h, :w].numpy(), logit[0, :h, :w].numpy(), sinr, live, low, legal


def fit_calibration(net: MapUNet, examples: list[tuple]) -> tuple[float, float]:
    """Platt scaling of the dead-cell logit on ``examples``' legal cells: the (scale, bias) of least binary
    cross-entropy of ``sigmoid(scale * logit + bias)`` against the cells dead or at the floor (Newton's method on the
    two parameters: ``scores.platt_scaling``)."""
    logits, lows = [], []
    for _mu, logit, _sinr, _live, low, legal in _whole_maps(net, examples):
        logits.append(logit[legal].astype(np.float64))
        lows.append(low[legal].astype(np.float64))
    return platt_scaling(np.concatenate(logits), np.concatenate(lows))


def pack_calibration(predictor: LearnedPredictor, maps: list[TrainingMaps]) -> tuple[float, float]:
    """Platt scaling of ``predictor``'s uncalibrated dead-cell logit fitted on every user of ``maps`` (training-maps
    packs the network was not trained on), at their legal cells, against the cells dead or at the SINR floor
    (``scores.platt_scaling``). Whatever calibration ``predictor`` carries is not used: fitting twice gives the
    same numbers."""
    logits, lows = [], []
    for m in maps:
        scene = Scene.from_settings(m.settings, m.height_rel_m)
        cells = np.argwhere(~m.blocked)
        logits.append(predictor.dead_logits(scene, m.users, cells).astype(np.float64).ravel())
        sinr, dead = m.sinr_db[:, cells[:, 0], cells[:, 1]], m.dead[:, cells[:, 0], cells[:, 1]]
        lows.append((dead | (sinr <= scene.floor_db + 1e-3)).ravel())
    if not logits:
        raise ValueError("pack_calibration: no map to fit on")
    return platt_scaling(np.concatenate(logits), np.concatenate(lows))


def save_learned(folder: Path, net: MapUNet, model_fields: dict) -> LearnedModel:
    """Write ``weights.pt`` (tensors only) and ``model.json`` into ``folder`` (a fresh folder that the caller
    publishes); returns the description."""
    save_tensors({k: v.detach().clone() for k, v in net.state_dict().items()}, folder / WEIGHTS)
    model = LearnedModel(weights_sha256=sha256_file(folder / WEIGHTS), **model_fields)
    write_model_json(model, folder / MODEL_JSON)
    return model


def model_card(model: LearnedModel, command: str) -> str:
    """The model card of a learned tier: data, settings, error and speed, from ``model.json``'s facts."""
    rows = [
        "| city | tier | median \\|error\\| [dB] | p90 \\|error\\| [dB] | dead/live agreement | calibration error | ms per map |",
        "|---|---|---|---|---|---|---|",
    ]
    for city, s in model.scores.items():
        for tier in ("learned", "physics"):
            ece = s.get(f"{tier}_calibration_error")
            rows.append(
                f"| {city} | {tier} | {s[f'{tier}_median_error_db']:.1f} | {s[f'{tier}_p90_error_db']:.1f} | "
                f"{100 * s[f'{tier}_dead_live_agreement']:.1f} % | {'-' if ece is None else f'{ece:.3f}'} | "
                f"{s[f'{tier}_ms_per_map']:.0f} |"
            )
    bins = ["| city | " + " | ".join(f"{b / 10:.1f}-{(b + 1) / 10:.1f}" for b in range(10)) + " |", "|---" * 11 + "|"]
    for city, diagram in model.reliability.items():
        cells = {min(int(m * 10), 9): f"{f:.2f} ({m:.2f})" for m, f, _ in diagram}
        bins.append(f"| {city} | " + " | ".join(cells.get(b, "-") for b in range(10)) + " |")
    scale, bias = model.calibration
    params = sum(p.numel() for p in MapUNet(model.config.widths).parameters())
    return "\n".join(
        [
            "# Model card: the map searcher's learned radio-map predictor",
            "",
            "Written by `uavrl train-predictor` and `uavrl calibrate-predictor` (rl/predictor/learned.py); every number below is",
            'measured by the commands under "Made by".',
            "",
            "- **What it predicts**: the SINR map [dB] at the UAV plane of a ground user at a given cell, and the",
            "  probability that each cell is dead or at the SINR floor, from public inputs only (building heights, grid,",
            "  altitude, carrier, transmit power, noise level, floor) and the physics tier's map (rl/predictor/physics.py).",
            f"- **Network**: a U-Net of widths {model.config.widths} ({params} parameters), {len(PLANES)} input planes "
            f"({', '.join(PLANES)}), two outputs correcting the physics tier's SINR and dead-cell logit.",
            f"- **Data**: {model.users} users of {len(model.fitted_on)} training bundles ({', '.join(model.fitted_on)}), "
            "the legal cells of their ray-traced maps, random crops under the eight symmetries of the square.",
            f"- **Training**: {model.config.steps} Adam steps of {model.config.batch} crops of {model.config.crop} cells, "
            f"lr {model.config.lr:g}, seed {model.config.seed}: {model.train_seconds:.0f} s on {model.config.threads} CPU "
            f"threads; final loss {model.final_loss:.4f}; residual std on the training users' live cells "
            f"{model.error_db:.1f} dB.",
            f"- **Calibration**: the dead-cell logit scaled by {scale:.3f} and shifted by {bias:+.3f} (Platt scaling on "
            + (
                f"the legal cells of every user of {len(model.calibrated_on)} training-maps packs the network was not "
                f"trained on: {', '.join(model.calibrated_on)}; `uavrl calibrate-predictor`)."
                if model.calibrated_on
                else f"the legal cells of {model.calibration_users} training users held out of the gradient steps; 1 and "
                "0: none)."
            ),
            "- **Weights**: `weights.pt`, tensors only (loaded with `torch.load(weights_only=True)`), sha256 "
            f"`{model.weights_sha256}`.",
            "",
            "## Error on the validation cities' users (legal cells; the prediction floored, the floor where it says dead)",
            "",
            *rows,
            "",
            "The calibration error is the expected calibration error of the dead probability (ten equal-width bins)",
            "against what it predicts, a cell dead or at the SINR floor. Its reliability diagram on the same cells, per",
            "bin of the predicted probability: the observed frequency (the bin's mean prediction):",
            "",
            *(bins if model.reliability else ["(no validation city)"]),
            "",
            "## Made by",
            "",
            "```bash",
            *(model.made_by or [command]),
            "```",
            "",
        ]
    )

"""A calibration of the dead-cell probability on features the UAV knows, beside Platt scaling: tried, not kept.

Logistic regression of the event the dead probability predicts (a cell dead or at the SINR floor) on the predictor's
uncalibrated dead logit plus public features of the cell and the city: walls crossed, log distance and Deygout's loss
of the straight path (``rl.predictor.path_features``), the share of building cells in the 7-cell square around the
cell and around the user (and the 15-cell square around the user), the city's building cover and mean building
height. Fitted on the tiered packs alone, or on every pack with the tiered and the mixed packs weighted equally
(``--maps``: cities the predictor was never trained on; a sample of cells a user); scored on every validation city
(expected calibration error / dead/live agreement). Newton's method with halved steps and a ridge of 1e-3.

    python experiments/calibration_features.py [--predictor data/agents/searcher/unet] [--maps data/trainmaps]
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from common import VALIDATION, validation_parser

from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.trainmaps import list_packs, read_pack
from uavplace.rl.config import DEFAULT_PREDICTOR
from uavplace.rl.predictor import Scene, load_predictor, path_features, reliability

FEATURES = ("logit", "walls", "log_d", "diffraction", "cell density 7", "user density 7", "user density 15", "cover",
            "mean height")  # fmt: skip
VARIANTS = {  # name: (packs, features, weigh the tiered and the mixed packs equally)
    "Platt, tiered packs": ("tt-", FEATURES[:1], False),
    "all features, tiered packs": ("tt-", FEATURES, False),
    "local features, tiered packs": ("tt-", FEATURES[:7], False),
    "Platt, all packs weighted": ("", FEATURES[:1], True),
    "all features, all packs weighted": ("", FEATURES, True),
    "local features, all packs weighted": ("", FEATURES[:7], True),
    "city features, all packs weighted": ("", (FEATURES[0], *FEATURES[7:]), True),
}


def box_mean(a: np.ndarray, side: int) -> np.ndarray:
    """The mean of ``a`` over the ``side`` x ``side`` square around each cell, zeros beyond the edge."""
    r = side // 2
    c = np.pad(a, r).cumsum(0).cumsum(1)
    c = np.pad(c, ((1, 0), (1, 0)))
    ny, nx = a.shape
    return (
        c[side:, side:][:ny, :nx] - c[:-side, side:][:ny, :nx] - c[side:, :-side][:ny, :nx] + c[:-side, :-side][:ny, :nx]
    ) / side**2


def features(predictor: object, scene: Scene, users: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """``[U * M, len(FEATURES)]``: every user's features at every cell."""
    z = predictor.dead_logits(scene, users, cells)
    built = (scene.ground_height_m > 0).astype(np.float64)
    dens7, dens15 = box_mean(built, 7), box_mean(built, 15)
    heights = scene.ground_height_m[scene.ground_height_m > 0]
    city = (built.mean(), heights.mean() / 20 if len(heights) else 0.0)
    rows = []
    for i, (uy, ux) in enumerate(users):
        f = path_features(scene, (int(uy), int(ux)), predictor.constants.user_height_m, cells)
        m = len(cells)
        rows.append(np.stack([z[i], np.minimum(f["walls"], 3) / 3, f["log_d"] - 2, f["diffraction_db"] / 20,
                              dens7[cells[:, 0], cells[:, 1]], np.full(m, dens7[uy, ux]), np.full(m, dens15[uy, ux]),
                              np.full(m, city[0]), np.full(m, city[1])], axis=1))  # fmt: skip
    return np.concatenate(rows)


def fit(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted logistic regression of ``y`` on ``x`` and a constant."""
    a = np.concatenate([x, np.ones((len(x), 1))], axis=1)
    theta = np.zeros(a.shape[1])
    theta[0] = 1.0

    def loss(t: np.ndarray) -> float:
        v = a @ t
        return float(np.sum(w * (np.logaddexp(0, v) - y * v)))

    current = loss(theta)
    for _ in range(100):
        p = 1 / (1 + np.exp(-np.clip(a @ theta, -50, 50)))
        step = np.linalg.solve((a * (w * p * (1 - p))[:, None]).T @ a + 1e-3 * np.eye(a.shape[1]), a.T @ (w * (p - y)))
        shrink = 1.0
        while shrink > 1e-6 and loss(theta - shrink * step) > current:
            shrink /= 2
        theta = theta - shrink * step
        new = loss(theta)
        if current - new < 1e-9 * abs(current):
            break
        current = new
    return theta


def main() -> None:
    ap = validation_parser(__doc__, episodes=0)
    ap.add_argument("--predictor", type=Path, default=DEFAULT_PREDICTOR)
    ap.add_argument("--maps", type=Path, default=Path("data/trainmaps"))
    ap.add_argument("--cells", type=int, default=400, help="Cells drawn a user of the tiered packs (150 of the others)")
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    args = ap.parse_args()
    predictor = load_predictor(args.predictor)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    packs = {}  # prefix -> (features, outcomes)
    for path in list_packs(args.maps):
        m = read_pack(path)
        scene = Scene.from_settings(m.settings, m.height_rel_m)
        cells = np.argwhere(~m.blocked)
        x = features(predictor, scene, m.users, cells)
        y = (m.dead[:, cells[:, 0], cells[:, 1]] | (m.sinr_db[:, cells[:, 0], cells[:, 1]] <= scene.floor_db + 1e-3)).ravel()
        tiered = m.city.startswith("tt-")
        pick = rng.choice(len(y), min(len(y), (args.cells if tiered else args.cells * 3 // 8) * len(m.users)), replace=False)
        xs, ys = packs.setdefault("tt-" if tiered else "other", ([], []))
        xs.append(x[pick])
        ys.append(y[pick])
    packs = {k: (np.concatenate(xs), np.concatenate(ys).astype(np.float64)) for k, (xs, ys) in packs.items()}
    print(f"packs: {', '.join(f'{k} {len(v[1]):,} cells' for k, v in packs.items())} ({time.perf_counter() - t0:.0f} s)")
    cities = {}
    for city in args.city or list(VALIDATION):
        b = load_bundle(city, root=args.root)
        if b.manifest.config.role == "test":
            ap.error(f"{city} is a test city: nothing is learnt from it")
        scene, cells, users = Scene.of(b), np.argwhere(~b.blocked), b.user_indices()
        dead = b.dead[np.asarray(users)[:, None], cells[None, :, 0], cells[None, :, 1]].ravel()
        sinr = b.sinr_db[np.asarray(users)[:, None], cells[None, :, 0], cells[None, :, 1]].ravel()
        cities[city] = (features(predictor, scene, b.user_cells(users), cells), dead, dead | (sinr <= scene.floor_db + 1e-3))
    print("| calibration | " + " | ".join(cities) + " |")
    print("|---" * (len(cities) + 1) + "|")
    for name, (prefix, names, balanced) in VARIANTS.items():
        cols = [FEATURES.index(f) for f in names]
        parts = [packs["tt-"]] if prefix else list(packs.values())
        x, y = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        w = np.concatenate([np.full(len(p[1]), len(y) / (len(parts) * len(p[1])) if balanced else 1.0) for p in parts])
        theta = fit(x[:, cols], y, w)
        cells_out = []
        for xv, dead, low in cities.values():
            p = 1 / (1 + np.exp(-(np.concatenate([xv[:, cols], np.ones((len(xv), 1))], axis=1) @ theta)))
            cells_out.append(f"{reliability(p, low)[0]:.3f} / {100 * ((p > 0.5) == dead).mean():.1f} %")
        print(f"| {name} | " + " | ".join(cells_out) + " |")


if __name__ == "__main__":
    main()

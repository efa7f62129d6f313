"""How the learned predictor's errors are alike from cell to cell: the fit behind ``SearchConfig.error_share`` and
``error_range_cells`` (docs/searcher.md, "Kriging the predictor's errors").

For users of training cities (never a test city), each user's error latent at every legal cell
(``rl.belief.BeliefModel.error_latent``: where the ray-traced value falls in the predicted distribution of a user at
the user's own cell, as a standard normal), then the correlation of the latents of two cells ``d`` cells apart along
a row or a column, pooled over users, for ``d`` in ``--lags``; then the least-squares fit of ``share * exp(-d /
range)`` to them. Prints the table and the fit; ``--city`` picks other cities (validation cities to check the fit).

    python experiments/error_correlation.py [--city corpus-000 ...] [--users 20] [--predictor data/agents/searcher/unet]
"""

from __future__ import annotations

import argparse

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.infra.console import markdown_table
from uavplace.rl.belief import BeliefModel, CandidateMaps
from uavplace.rl.config import DEFAULT_PREDICTOR
from uavplace.rl.predictor import Scene, load_predictor

#: The searcher's training cities (the learned tier's; docs/searcher.md).
TRAINING = tuple(f"corpus-{i:03d}" for i in range(16)) + tuple(f"oldtown-{i:03d}" for i in range(5)) + ("train",)


def latents(model: BeliefModel, city: str, users: int) -> list[np.ndarray]:
    """Each of the first ``users`` users' error latents [num_y, num_x] of ``city`` (NaN where the UAV may not go)."""
    bundle = load_bundle(city)
    scene = Scene.of(bundle)
    cells = np.argwhere(~bundle.blocked)
    chosen = bundle.user_indices()[:users]
    mu, p_dead = model.predictor.predict(scene, bundle.user_cells(chosen), cells)
    out = []
    for i, u in enumerate(chosen):
        values = np.where(bundle.dead[u], scene.floor_db, bundle.sinr_db[u])[cells[:, 0], cells[:, 1]]
        one = CandidateMaps(cells[:1], cells, np.zeros((1, 1), np.int64), mu[i : i + 1], p_dead[i : i + 1], mu[i : i + 1])
        grid = np.full(bundle.blocked.shape, np.nan)
        grid[cells[:, 0], cells[:, 1]] = model.error_latent(one, np.arange(len(cells)), values, scene.floor_db)[0]
        out.append(grid)
    return out


def correlation_by_lag(grids: list[np.ndarray], lags: list[int]) -> np.ndarray:
    """The correlation of the values of two cells ``d`` cells apart along a row or a column, pooled over ``grids``."""
    out = []
    for lag in lags:
        pairs = []
        for g in grids:
            for a, b in ((g[:, :-lag], g[:, lag:]), (g[:-lag], g[lag:])):
                a, b = a.ravel(), b.ravel()
                ok = np.isfinite(a) & np.isfinite(b)
                pairs.append(np.stack([a[ok], b[ok]]))
        out.append(np.corrcoef(np.concatenate(pairs, axis=1))[0, 1])
    return np.array(out)


def fit(lags: list[int], corr: np.ndarray) -> tuple[float, float]:
    """The ``(share, range)`` of ``share * exp(-d / range)`` nearest ``corr`` in least squares (a grid of ranges, the
    share solved for each)."""
    d = np.asarray(lags, np.float64)
    best = (np.inf, 0.0, 0.0)
    for scale in np.arange(1.0, 40.0, 0.1):
        shape = np.exp(-d / scale)
        share = float(shape @ corr / (shape @ shape))
        err = float(((share * shape - corr) ** 2).sum())
        best = min(best, (err, share, scale))
    return best[1], best[2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", default=None, help="City (repeatable; default: the training cities)")
    ap.add_argument("--users", type=int, default=20, help="Users a city (its first)")
    ap.add_argument("--lags", default="1,2,3,4,6,8,12,16", help="Distances [cells], comma-separated")
    ap.add_argument("--predictor", default=str(DEFAULT_PREDICTOR), help="The learned tier's folder")
    args = ap.parse_args()
    lags = [int(x) for x in args.lags.split(",")]
    model = BeliefModel(load_predictor(args.predictor))
    grids, rows = [], []
    for city in args.city or TRAINING:
        mine = latents(model, city, args.users)
        grids += mine
        rows.append([city, *(f"{c:.2f}" for c in correlation_by_lag(mine, lags))])
    pooled = correlation_by_lag(grids, lags)
    rows.append(["all", *(f"{c:.2f}" for c in pooled)])
    print(markdown_table([["city", *(f"d = {d}" for d in lags)], *rows]))
    share, scale = fit(lags, pooled)
    print(f"fit: error_share = {share:.2f}, error_range_cells = {scale:.1f}")


if __name__ == "__main__":
    main()

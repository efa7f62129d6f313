"""Radio maps predicted from the buildings: what a searcher can know of a user's map before measuring it.

The physics tier (``PhysicsPredictor``) needs only what the UAV knows: the building heights of the bundle, its grid,
the UAV altitude, the carrier, the user's transmit power, the noise level and the SINR floor, and a candidate user
cell. For every UAV cell it follows the straight path from the user (``user_height_m`` above the ground) to the UAV
over the height raster, sampled once per cell length, and reads three features off its vertical profile:

- ``log_d``: log10 of the path's 3D length [m] (free space: 20 dB a decade);
- ``walls``: the building edges the path enters below a roof (a wall crossed), counted;
- ``diffraction_db``: the knife-edge loss of the profile by Deygout's construction (ITU-R P.526-15, section 4.5.1:
  the edge of largest Fresnel parameter nu, then the largest edge on each side of it, each lost by ``knife_edge_db``).

The path gain is linear in them, ``gain_db = intercept_db + log_d_db * log_d + wall_db * walls + diffraction_weight
* diffraction_db``, with constants fitted on the training corpus (``fit_constants``) and saved as data
(``PhysicsConstants``, data/agents/searcher/predictor.json). SINR = transmit power + gain - noise. A cell is dead (no
path reached it) with the probability ``dead_probability``, a logistic in the predicted SINR, fitted too.

Arrays are ``[num_y, num_x]`` like the bundle's (``iy = 0`` the southern edge); cells are ``(iy, ix)``.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
from pydantic import Field

from uavplace.dataset.bundle import Bundle
from uavplace.rl.predictor.base import code_digest, version_of
from uavplace.rl.predictor.scene import Scene
from uavplace.schemas.base import Contract

#: The version of the features' code: a cache of predicted maps is keyed by it and by the constants.
FEATURES_VERSION = 3
#: Below this Fresnel parameter a knife edge costs nothing (ITU-R P.526-15, eq. 31's domain).
NU_MIN = -0.78


def knife_edge_db(nu: np.ndarray) -> np.ndarray:
    """The loss of one knife edge [dB] for Fresnel-Kirchhoff parameters ``nu`` (ITU-R P.526-15, eq. 31):
    ``6.9 + 20 log10(sqrt((nu - 0.1)^2 + 1) + nu - 0.1)`` for ``nu > -0.78``, else 0. Shape kept."""
    nu = np.asarray(nu, np.float32)
    nu = np.where(np.isfinite(nu), nu, np.float32(NU_MIN - 1))  # -inf: no edge at all
    v = nu - np.float32(0.1)
    loss = np.float32(6.9) + np.float32(20.0) * np.log10(np.sqrt(v * v + 1) + v)
    return np.where(nu > NU_MIN, loss, np.float32(0.0)).astype(np.float32)


def fresnel_nu(h_m: np.ndarray, d1_m: np.ndarray, d2_m: np.ndarray, wavelength_m: float) -> np.ndarray:
    """Fresnel-Kirchhoff parameter of an edge ``h_m`` above the line between two ends at distances ``d1_m`` and
    ``d2_m`` from it (ITU-R P.526-15, eq. 26: ``h sqrt(2 / lambda (1 / d1 + 1 / d2))``). Broadcast shapes."""
    d1 = np.maximum(d1_m, 1e-3)
    d2 = np.maximum(d2_m, 1e-3)
    return (h_m * np.sqrt(np.float32(2.0 / wavelength_m) * (1.0 / d1 + 1.0 / d2))).astype(np.float32)


def path_features(scene: Scene, user: tuple[int, int], user_height_m: float, cells: np.ndarray | None = None) -> dict:
    """The profile features of the straight paths from a user at cell ``user`` ``(iy, ix)``, ``user_height_m`` above
    the ground, to the UAV at every cell (or at ``cells`` [M, 2] ``(iy, ix)``): ``log_d``, ``walls`` and
    ``diffraction_db``, each ``[num_y, num_x]`` (or ``[M]``) float32 (see the module's docstring). Each path is
    sampled once per cell length of its own (``ceil`` of its horizontal length in cells, at least one sample)."""
    h = scene.ground_height_m
    ny, nx = h.shape
    whole = cells is None
    if whole:
        yy, xx = np.mgrid[:ny, :nx]
        cells = np.stack([yy.ravel(), xx.ravel()], axis=1)
    cells = np.asarray(cells, np.int64).reshape(-1, 2)
    uy, ux = float(user[0]), float(user[1])
    horiz = np.hypot(cells[:, 0] - uy, cells[:, 1] - ux).astype(np.float32)
    rise = np.float32(scene.altitude_m - user_height_m)
    length = np.sqrt((horiz * np.float32(scene.spacing_m)) ** 2 + rise**2).astype(np.float32)  # [M]
    zero = np.zeros(len(cells), np.float32)
    out = {"log_d": np.log10(np.maximum(length, 1.0)), "walls": zero.copy(), "diffraction_db": zero.copy()}
    if (h > 0).any():  # open ground: no wall, no edge above any path
        samples = np.maximum(np.ceil(horiz - 1e-4), 1).astype(np.int64)
        order = np.argsort(samples, kind="stable")
        # Paths in chunks of similar length, each chunk padded to its longest: about the work of the paths themselves.
        for chunk in np.array_split(order, max(1, min(16, len(order) // 256))):
            if len(chunk):
                walls, diffraction = _profile(scene, user, user_height_m, cells[chunk], samples[chunk], length[chunk])
                out["walls"][chunk], out["diffraction_db"][chunk] = walls, diffraction
    return {k: v.reshape(ny, nx) for k, v in out.items()} if whole else out


def _profile(
    scene: Scene, user: tuple[int, int], user_height_m: float, cells: np.ndarray, samples: np.ndarray, length: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(walls, Deygout's loss) [M] of the paths to ``cells`` [M, 2], path ``m`` sampled at ``samples[m]`` points."""
    h = scene.ground_height_m
    ny, nx = h.shape
    uy, ux = int(user[0]), int(user[1])
    k = int(samples.max())
    idx = np.arange(k, dtype=np.float32)[None, :]
    valid = idx < samples[:, None]  # [M, K]
    s = ((idx + 0.5) / samples[:, None]).astype(np.float32)  # fractions along each path
    s = np.where(valid, s, np.float32(1.0))
    dy, dx = (cells[:, 0] - uy).astype(np.float32), (cells[:, 1] - ux).astype(np.float32)
    sy = np.clip(np.rint(uy + s * dy[:, None]), 0, ny - 1).astype(np.int32)
    sx = np.clip(np.rint(ux + s * dx[:, None]), 0, nx - 1).astype(np.int32)
    flat = sy * np.int32(nx) + sx  # [M, K] the samples' cells
    # Samples at the user's or the UAV's own cell stand for the ends, not obstacles; padding samples are nothing.
    own = (flat == uy * nx + ux) | (flat == (cells[:, 0] * nx + cells[:, 1]).astype(np.int32)[:, None]) | ~valid
    roof = np.where(own, np.float32(0.0), h.ravel().take(flat))
    rise = np.float32(scene.altitude_m - user_height_m)
    line = np.float32(user_height_m) + s * rise  # [M, K] the straight path's height
    above = roof - line
    inside = above > 0
    walls = (inside[:, 0].astype(np.int32) + (inside[:, 1:] & ~inside[:, :-1]).sum(axis=1)).astype(np.float32)
    diffraction = np.zeros(len(cells), np.float32)
    d1 = s * length[:, None]
    d2 = (1 - s) * length[:, None]
    lam = scene.wavelength_m
    nu = np.where(valid, fresnel_nu(above, d1, d2, lam), -np.inf)
    main = np.argmax(nu, axis=1)  # [M] Deygout's principal edge
    rows = np.arange(len(cells))
    nu_main = nu[rows, main]
    edged = np.flatnonzero(nu_main > NU_MIN)  # only these paths lose anything to an edge
    if not len(edged):
        return walls, diffraction
    s, roof, flat, d1, d2, valid = (a[edged] for a in (s, roof, flat, d1, d2, valid))
    main, nu_main, length = main[edged], nu_main[edged], length[edged]
    rows = np.arange(len(edged))
    s_main = s[rows, main][:, None]
    top = (line[edged][rows, main] + above[edged][rows, main])[:, None]  # the edge's height [m]
    # The secondary edges: above the lines from each end to the principal edge's top, in other cells than its own
    # (two samples of one cell are one edge).
    same = flat == flat[rows, main][:, None]
    before = (s < s_main) & ~same & valid
    line_a = np.float32(user_height_m) + (s / np.maximum(s_main, 1e-6)) * (top - user_height_m)
    nu_a = np.where(before, fresnel_nu(roof - line_a, d1, (s_main - s) * length[:, None], lam), -np.inf).max(axis=1)
    after = (s > s_main) & ~same & valid
    line_b = top + (s - s_main) / np.maximum(1 - s_main, 1e-6) * (np.float32(scene.altitude_m) - top)
    nu_b = np.where(after, fresnel_nu(roof - line_b, (s - s_main) * length[:, None], d2, lam), -np.inf).max(axis=1)
    diffraction[edged] = knife_edge_db(nu_main) + knife_edge_db(nu_a) + knife_edge_db(nu_b)
    return walls, diffraction


class PhysicsConstants(Contract):
    """The physics tier's fitted constants (data/agents/searcher/predictor.json) and how they were fitted."""

    intercept_db: float = Field(description="Path gain at 1 m with no wall and no edge [dB]")
    log_d_db: float = Field(description="Gain per decade of 3D distance [dB] (free space: -20)")
    wall_db: float = Field(description="Gain per wall crossed below a roof [dB] (negative)")
    diffraction_weight: float = Field(description="Weight of Deygout's knife-edge loss (1: as ITU-R P.526 gives it)")
    max_walls: float = Field(default=6.0, gt=0, description="Walls counted at most (beyond, a path is lost either way)")
    user_height_m: float = Field(default=1.5, ge=0, description="The user's antenna above the ground [m]")
    dead_level_db: float = Field(description="Predicted SINR at which a cell is dead with probability one half [dB]")
    dead_scale_db: float = Field(gt=0, description="Width of the dead-cell logistic [dB]")
    error_db: float = Field(gt=0, description="Std of (measured - predicted) SINR on the fitting cities' live cells [dB]")
    fitted_on: list[str] = Field(default_factory=list, description="city@version of the fitting bundles")

    def version(self) -> str:
        """12 hex digits of the constants and ``FEATURES_VERSION``: what a cache of predicted maps is keyed by."""
        doc = {"features": FEATURES_VERSION, "constants": self.model_dump(mode="json")}
        return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]


def predict_sinr(scene: Scene, constants: PhysicsConstants, user: tuple[int, int], cells: np.ndarray | None = None) -> np.ndarray:
    """Predicted SINR [dB] of a user at cell ``user`` ``(iy, ix)`` at every UAV cell ``[num_y, num_x]`` (or ``cells``
    [M, 2]): the mean of the live value, not floored (``dead_probability`` says how likely the cell is dead)."""
    f = path_features(scene, user, constants.user_height_m, cells)
    return sinr_from_features(f, scene, constants)


def sinr_from_features(features: dict, scene: Scene, constants: PhysicsConstants) -> np.ndarray:
    gain = (
        constants.intercept_db
        + constants.log_d_db * features["log_d"]
        + constants.wall_db * np.minimum(features["walls"], constants.max_walls)
        - constants.diffraction_weight * features["diffraction_db"]
    )
    return (scene.tx_power_dbm + gain - scene.noise_dbm).astype(np.float32)


def dead_probability(predicted_db: np.ndarray, constants: PhysicsConstants) -> np.ndarray:
    """The probability that a cell of predicted SINR ``predicted_db`` is dead: ``1 / (1 + exp((pred - level) /
    scale))``. Shape kept."""
    z = np.clip((np.asarray(predicted_db, np.float32) - constants.dead_level_db) / constants.dead_scale_db, -60, 60)
    return (1.0 / (1.0 + np.exp(z))).astype(np.float32)


class PhysicsPredictor:
    """The physics tier as a predictor of many users' maps (the interface the map searchers and ``prediction_scores``
    use; ``rl.predictor.TIERS`` names the others)."""

    tier = "physics"

    def __init__(self, constants: PhysicsConstants) -> None:
        self.constants = constants
        self.error_db = constants.error_db

    def version(self) -> str:
        """12 hex digits of the constants and the predictors' code (``code_digest``): a cache of its maps' key."""
        return version_of({"tier": self.tier, "constants": self.constants.version(), "code": code_digest()})

    def predict(self, scene: Scene, users: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``mu``, ``p_dead``), each ``[U, M]`` float32: the predicted SINR [dB] of a user at each of ``users`` [U, 2]
        at the UAV cells ``cells`` [M, 2] (not floored), and the probability that the cell is dead or at the floor."""
        mu = np.empty((len(users), len(cells)), np.float32)
        for i, (iy, ix) in enumerate(np.asarray(users, np.int64)):
            mu[i] = predict_sinr(scene, self.constants, (int(iy), int(ix)), cells)
        return mu, dead_probability(mu, self.constants)


def _fit_rows(bundle: Bundle, users: np.ndarray, user_height_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, Scene]:
    """(features [R, 3], measured SINR [R], dead [R], scene) at the legal cells of ``users`` of ``bundle``."""
    scene = Scene.of(bundle)
    cells = np.argwhere(~bundle.blocked)
    table = bundle.users.set_index("user")
    feats, sinr, dead = [], [], []
    for u in users:
        f = path_features(scene, (int(table.at[u, "iy"]), int(table.at[u, "ix"])), user_height_m, cells)
        feats.append(np.stack([f["log_d"], f["walls"], f["diffraction_db"]], axis=1))
        sinr.append(bundle.sinr_db[u, cells[:, 0], cells[:, 1]])
        dead.append(bundle.dead[u, cells[:, 0], cells[:, 1]])
    return np.concatenate(feats), np.concatenate(sinr), np.concatenate(dead), scene


def fit_constants(
    bundles: list[Bundle], users: list[np.ndarray], user_height_m: float = 1.5, max_walls: float = 3.0
) -> PhysicsConstants:
    """The physics tier's constants fitted on ``users`` (bundle user indices, one array per bundle) of ``bundles``.

    The gain's four constants by least squares on the live cells above the floor (gain = measured SINR - power +
    noise); ``error_db`` the residuals' std; the dead-cell logistic by Newton's method on every legal cell, with the
    cells at the floor counted as dead (what a measurement there says is the same)."""
    rows = [_fit_rows(b, u, user_height_m) for b, u in zip(bundles, users, strict=True) if len(u)]
    if not rows:
        raise ValueError("fit_constants: no user to fit on")
    x = np.concatenate([r[0] for r in rows])
    offset = np.concatenate([np.full(len(r[1]), r[3].tx_power_dbm - r[3].noise_dbm, np.float32) for r in rows])
    floor = np.concatenate([np.full(len(r[1]), r[3].floor_db, np.float32) for r in rows])
    sinr = np.concatenate([r[1] for r in rows])
    dead = np.concatenate([r[2] for r in rows])
    live = ~dead & (sinr > floor + 1e-3)
    a = np.stack([np.ones(len(x)), x[:, 0], np.minimum(x[:, 1], max_walls), -x[:, 2]], axis=1)
    coef, *_ = np.linalg.lstsq(a[live], (sinr - offset)[live], rcond=None)
    pred = a @ coef + offset
    error = float(np.std(sinr[live] - pred[live]))
    level, scale = _fit_logistic(pred, ~live)
    return PhysicsConstants(
        intercept_db=float(coef[0]),
        log_d_db=float(coef[1]),
        wall_db=float(coef[2]),
        diffraction_weight=float(coef[3]),
        max_walls=max_walls,
        user_height_m=user_height_m,
        dead_level_db=level,
        dead_scale_db=scale,
        error_db=error,
        fitted_on=[f"{b.city}@{b.version}" for b, u in zip(bundles, users, strict=True) if len(u)],
    )


def _fit_logistic(pred: np.ndarray, low: np.ndarray) -> tuple[float, float]:
    """(level, scale) of ``P(low) = 1 / (1 + exp((pred - level) / scale))`` by maximum likelihood (Newton's method
    on ``P = sigmoid(w0 + w1 pred)``)."""
    x = np.stack([np.ones(len(pred)), np.asarray(pred, np.float64)], axis=1)
    y = np.asarray(low, np.float64)
    w = np.array([0.0, -0.1])
    for _ in range(50):
        p = 1.0 / (1.0 + np.exp(-np.clip(x @ w, -60, 60)))
        grad = x.T @ (y - p)
        hess = (x * (p * (1 - p))[:, None]).T @ x + 1e-9 * np.eye(2)
        step = np.linalg.solve(hess, grad)
        w = w + step
        if np.abs(step).max() < 1e-8:
            break
    scale = -1.0 / w[1] if w[1] < 0 else 1e3
    return float(w[0] * scale), float(max(scale, 1e-3))

"""The belief arithmetic (``BeliefModel``): a canvas's candidates and their predicted maps (``CandidateMaps``), the
likelihood of a measurement, the posterior probability that a cell reaches P_T (``posterior_cover``); the package's
docstring says the model."""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch
from scipy.special import ndtr, ndtri

from uavplace.infra.device import torch_device
from uavplace.infra.limits import check_limit
from uavplace.rl.belief.cache import PredictionCache
from uavplace.rl.config import SearchConfig
from uavplace.rl.predictor import PhysicsConstants, PhysicsPredictor, Predictor, Scene
from uavplace.rl.world.view import PublicMaps

#: Candidates predicted at once between two progress reports (a multiple of the learned tier's batch of 16).
PREDICT_CHUNK = 128
#: The span of SINR [dB] over which the likelihood's flat share is spread.
OUTLIER_SPAN_DB = 100.0


@dataclass(frozen=True)
class CandidateMaps:
    """One canvas's predictions: ``cells`` [C, 2] candidate cells ``(iy, ix)`` of the (transformed) map, ``legal``
    [M, 2] the map cells the UAV may enter, ``index`` [num_y, num_x] a legal cell's column (-1 elsewhere), ``mu``
    [C, M] float32 predicted SINR [dB], ``p_dead`` [C, M] float32, ``cover`` [C, M] float32 the probability of
    reaching P_T (``canvas_maps`` holds ``mu`` and ``p_dead`` column-major, ``cover`` row-major: the order each is
    read in); ``probit`` [C, M] float32 ``Phi^-1(cover)`` where the planner krigs (``SearchConfig.error_share`` > 0),
    else None."""

    cells: np.ndarray
    legal: np.ndarray
    index: np.ndarray
    mu: np.ndarray
    p_dead: np.ndarray
    cover: np.ndarray
    probit: np.ndarray | None = None

    @cached_property
    def cover64(self) -> np.ndarray:
        """``cover`` as float64, made once: the operand of a float64 belief's product (``posterior_cover``), which
        numpy would otherwise cast at every product. The same sums to the bit (float32 -> float64 is exact and the
        product is the same BLAS call), without the cast: 1.1-6 x faster on these cores, most with few rows."""
        return self.cover.astype(np.float64)


def candidate_cells(ground_height_m: np.ndarray, stride: int, buildings: bool) -> np.ndarray:
    """``[C, 2]`` candidate user cells: the lattice of ``stride`` cells (offset to the middle of the first block),
    open ground only when ``buildings``."""
    ny, nx = ground_height_m.shape
    o = stride // 2
    yy, xx = np.mgrid[o:ny:stride, o:nx:stride]
    cells = np.stack([yy.ravel(), xx.ravel()], axis=1)
    if buildings:
        cells = cells[ground_height_m[cells[:, 0], cells[:, 1]] <= 0]
    return cells


def rows_of(maps: CandidateMaps, keep: np.ndarray) -> CandidateMaps:
    """``maps`` with the candidates of ``keep`` [C] only."""
    probit = None if maps.probit is None else maps.probit[keep]
    return CandidateMaps(maps.cells[keep], maps.legal, maps.index, maps.mu[keep], maps.p_dead[keep], maps.cover[keep], probit)


def probit_of(cover: np.ndarray) -> np.ndarray:
    """``Phi^-1(cover)`` as float32, ``cover`` clipped to 1e-6 from 0 and 1: where a cell's chance of reaching P_T lies
    on a standard normal (the kriging planner's scale, ``BeliefModel.kriged_cover``)."""
    return ndtri(np.clip(cover, 1e-6, 1 - 1e-6)).astype(np.float32)


class DeviceCopies:
    """Arrays copied once to a torch ``device`` in a dtype: a copy is kept while the array it copies lives (held by a
    weak reference, so an array made later at the same address is copied anew)."""

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self._held: dict[tuple[int, str], tuple[weakref.ref, torch.Tensor]] = {}

    def __call__(self, array: np.ndarray, dtype: np.dtype | torch.dtype) -> torch.Tensor:
        key = (id(array), str(dtype) if isinstance(dtype, torch.dtype) else np.dtype(dtype).str)
        held = self._held.get(key)
        if held is not None and held[0]() is array:
            return held[1]
        self._held = {k: v for k, v in self._held.items() if v[0]() is not None}
        if isinstance(dtype, torch.dtype):  # a dtype numpy has not (bfloat16): cast by torch
            copy = torch.from_numpy(np.ascontiguousarray(array)).to(self.device, dtype)
        else:
            copy = torch.from_numpy(np.ascontiguousarray(array, dtype)).to(self.device)
        self._held[key] = (weakref.ref(array), copy)
        return copy


def posterior_cover(
    log_b: np.ndarray, maps: CandidateMaps, on_device: DeviceCopies | None = None, precision: str = "belief"
) -> np.ndarray:
    """``[R, M]`` the posterior probability that each cell reaches P_T, ``b @ cover``, for log-beliefs ``log_b`` [R, C]
    (any offset) over the candidates of ``maps`` [C, M]: the rows in one matrix product, which reads the cover once
    for them all (the planner's main cost). In the precision of ``log_b`` with the float32 cover, as numpy gives it: a
    float32 belief's product in float32, a float64 one's over ``CandidateMaps.cover64`` (made once; numpy would cast
    the cover at every product, to the same sums). ``on_device``: the product in torch on its device (the cover
    copied there once), in the same precision; None: numpy on the CPU.

    ``precision`` "bfloat16" (``SearchConfig.precision``, the hybrid's ``EnvConfig.belief_precision``): the belief (in
    float32) and the cover rounded to bfloat16, multiplied by torch (on ``on_device``'s device, else the CPU) and the
    sums rounded to bfloat16 too, returned as float32: within 3 x 2^-8 (bfloat16 keeps 8 bits) of the float32
    product's value, each row's the same in any batch (``tests/test_device.py``)."""
    if precision == "bfloat16":
        copies = on_device or _CPU_COPIES
        b = np.exp(log_b - log_b.max(axis=1, keepdims=True), dtype=np.float32)
        b /= b.sum(axis=1, keepdims=True)
        low = torch.from_numpy(b).to(copies.device, torch.bfloat16)
        return (low @ copies(maps.cover, torch.bfloat16)).float().cpu().numpy()
    if precision != "belief":
        raise ValueError(f"a belief product in the belief's precision ('belief') or 'bfloat16', not {precision!r}")
    dtype = np.result_type(log_b.dtype, maps.cover.dtype)
    if on_device is not None:
        b = torch.softmax(torch.from_numpy(np.asarray(log_b, dtype)).to(on_device.device), dim=1)
        return (b @ on_device(maps.cover, dtype)).cpu().numpy()
    b = np.exp(log_b - log_b.max(axis=1, keepdims=True))
    b /= b.sum(axis=1, keepdims=True)
    return b @ (maps.cover64 if dtype == np.float64 else maps.cover)


#: The CPU's copies of the covers a bfloat16 product reads (``posterior_cover``), each made once while its cover lives.
_CPU_COPIES = DeviceCopies(torch.device("cpu"))


def device_copies(device: str) -> DeviceCopies | None:
    """Where the belief products of the setting ``device`` (``infra.device``) run: None on the CPU (numpy)."""
    chosen = torch_device(device)
    return None if chosen.type == "cpu" else DeviceCopies(chosen)


class BeliefModel:
    """The searcher's belief arithmetic over the candidate cells of a canvas: the predicted maps of every candidate
    (``canvas_maps``, cached on disk by ``PredictionCache``), the likelihood of a measurement (``update``), the
    probability that a cell reaches P_T (``cover``) and the information a measurement gives (``information``). No
    planning: ``rl.tasks.placement.searcher.MapSearchPolicy`` plans on it, ``BeliefTracker`` paints it for the hybrid's
    observation."""

    def __init__(
        self,
        predictor: Predictor | PhysicsConstants,
        config: SearchConfig | None = None,
        cache: PredictionCache | None = None,
        device: str = "cpu",
    ) -> None:
        self.predictor = PhysicsPredictor(predictor) if isinstance(predictor, PhysicsConstants) else predictor
        self.config = config or SearchConfig()
        self.cache = cache or PredictionCache(None)
        #: Where the belief products run (``infra.device``'s setting), and their copies of the maps there (None: numpy).
        self.device = device
        self.on_device = device_copies(device)
        self._canvases: dict[tuple, CandidateMaps] = {}
        #: Told ``(candidates done, candidates)`` as a canvas's maps are predicted (a report's progress), or None.
        self.on_predict: Callable[[int, int], None] | None = None

    def __getstate__(self) -> dict:
        """What a copy in another process (a Ray task) takes: the predictor, the settings and the cache's folder,
        not the maps held in memory (read again from the cache there) nor the progress callback."""
        state = self.__dict__.copy()
        state.update(_canvases={}, on_predict=None, on_device=None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.on_device = device_copies(self.device)  # the device of the process it lands in

    # -- predictions -----------------------------------------------------------------------------
    def canvas_maps(self, public: PublicMaps, canvas: int) -> CandidateMaps:
        settings = public.settings[public.bundle_of(canvas)]
        key = (settings["version"], public.symmetry_of(canvas), public.config.p_t_db)
        if key in self._canvases:
            return self._canvases[key]
        cfg, k = self.config, public.symmetry_of(canvas)
        heights = public.map_heights(canvas)
        if not cfg.buildings:
            heights = np.full_like(heights, -settings["altitude_m"])
        scene = Scene.from_settings(settings, heights)
        cells = candidate_cells(scene.ground_height_m, cfg.stride, cfg.buildings)
        legal_map = public.legal(canvas)
        legal = np.argwhere(legal_map)
        check_limit(
            "prediction_bytes",
            (16 if cfg.kriged_planner else 12) * len(cells) * len(legal),  # mu, p_dead, cover [, probit]; not cover64
            settings["city"],
            f"predicted maps of {len(cells)} candidates x {len(legal)} cells (a larger stride has fewer)",
        )
        index = np.full(legal_map.shape, -1, np.int64)
        index[legal[:, 0], legal[:, 1]] = np.arange(len(legal))
        cache_key = "-".join(
            [settings["version"], f"k{k}", f"s{cfg.stride}", "b" if cfg.buildings else "open", self.predictor.version()]
        )
        hit = self.cache.load(cache_key, (len(cells), len(legal)))
        if hit is None:
            mu, p_dead = self.predict_all(scene, cells, legal)
            self.cache.save(cache_key, mu, p_dead)
            hit = tuple(a.astype(np.float16).astype(np.float32) for a in (mu, p_dead))  # as stored: cold = warm
        mu, p_dead = hit
        cover = self.cover(mu, p_dead, public.config.p_t_db)
        # a measurement reads one cell of every candidate: held cell by cell (the same values, column-major), that read
        # is one contiguous row instead of a stride through every candidate's map
        mu, p_dead = np.asfortranarray(mu), np.asfortranarray(p_dead)
        probit = np.asfortranarray(probit_of(cover)) if cfg.kriged_planner else None  # read a column at a time
        out = self._canvases[key] = CandidateMaps(cells, legal, index, mu, p_dead, cover, probit)
        return out

    def predict_all(self, scene: Scene, cells: np.ndarray, legal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The predictor's maps of every candidate, in chunks of ``PREDICT_CHUNK`` (a multiple of the learned tier's
        batch, so the same batches and the same numbers as in one call), telling ``on_predict(done, total)`` after each:
        the minutes of a city's first predictions are shown as they pass, never a silent wait."""
        mu = np.empty((len(cells), len(legal)), np.float32)
        p_dead = np.empty_like(mu)
        for i in range(0, len(cells), PREDICT_CHUNK):
            mu[i : i + PREDICT_CHUNK], p_dead[i : i + PREDICT_CHUNK] = self.predictor.predict(
                scene, cells[i : i + PREDICT_CHUNK], legal
            )
            if self.on_predict is not None:
                self.on_predict(min(i + PREDICT_CHUNK, len(cells)), len(cells))
        return mu, p_dead

    @property
    def sigma(self) -> float:
        """The predicted map's spread [dB]: the predictor's measured error, at least ``min_sigma_db``."""
        return max(self.predictor.error_db, self.config.min_sigma_db)

    @property
    def read_sigma(self) -> float:
        """The spread of a measurement about the predicted map [dB]: ``sigma`` and the declared measurement error
        (``SearchConfig.measurement_sigma_db``) in quadrature; ``sigma`` itself when that is 0."""
        noise = self.config.measurement_sigma_db
        return self.sigma if noise == 0 else math.hypot(self.sigma, noise)

    def cover(self, mu: np.ndarray, p_dead: np.ndarray, p_t_db: float) -> np.ndarray:
        """The probability that a predicted map ``mu`` [dB] with dead-cell probability ``p_dead`` reaches ``p_t_db``."""
        return ((1 - p_dead) * ndtr((mu - p_t_db) / self.sigma)).astype(np.float32)

    def bin_edges(self, floor_db: float, p_t_db: float) -> np.ndarray:
        """The upper edges of the SINR bins a measurement falls in (``outcome_probabilities``), ``info_bin_db`` apart,
        one of them at P_T, over ``OUTLIER_SPAN_DB`` above the floor."""
        w = self.config.info_bin_db
        k = np.arange(math.floor((floor_db - p_t_db) / w) + 1, math.ceil((floor_db + OUTLIER_SPAN_DB - p_t_db) / w))
        return p_t_db + w * k

    def outcome_probabilities(self, maps: CandidateMaps, columns: np.ndarray, floor_db: float, p_t_db: float) -> np.ndarray:
        """``[C, K, J]`` the probability that a measurement at legal cells ``columns`` [K] falls in each of ``J`` SINR
        bins for a user at each candidate, by the likelihood ``update`` uses: bin 0 at or below the floor (censored),
        then the bins between ``bin_edges``, the last open above; the flat share ``outlier`` spread evenly."""
        cfg = self.config
        mu = maps.mu[:, columns].astype(np.float64)[:, :, None]
        p_dead = maps.p_dead[:, columns].astype(np.float64)[:, :, None]
        edges = self.bin_edges(floor_db, p_t_db)
        cdf = ndtr((np.concatenate([[floor_db], edges]) - mu) / self.read_sigma)  # [C, K, J]
        live = np.diff(np.concatenate([cdf, np.ones_like(cdf[..., :1])], axis=-1), axis=-1)
        probs = np.concatenate([p_dead + (1 - p_dead) * cdf[..., :1], (1 - p_dead) * live], axis=-1)
        return (1 - cfg.outlier) * probs + cfg.outlier / probs.shape[-1]

    def information(
        self, maps: CandidateMaps, log_b: np.ndarray, columns: np.ndarray, floor_db: float, p_t_db: float
    ) -> np.ndarray:
        """``[K]`` the mutual information [bits] between the user's candidate cell, under belief ``log_b`` [C], and a
        measurement at each of legal cells ``columns`` [K]: H(mixture of the outcomes) - E_b[H(outcomes)]
        (``outcome_probabilities``; candidates of belief under 1e-6 of the largest are left out)."""
        b = np.exp(log_b - log_b.max())
        keep = b > 1e-6
        b = b[keep] / b[keep].sum()
        probs = self.outcome_probabilities(rows_of(maps, keep), columns, floor_db, p_t_db)  # [C', K, J]

        def entropy(p: np.ndarray) -> np.ndarray:
            return -(p * np.log2(np.maximum(p, 1e-300))).sum(axis=-1)

        mixture = np.einsum("c,ckj->kj", b, probs)
        return np.maximum(entropy(mixture) - b @ entropy(probs), 0.0)

    def error_latent(self, maps: CandidateMaps, columns: np.ndarray, measured: np.ndarray, floor_db: float) -> np.ndarray:
        """``[C, V]`` where measurements ``measured`` [V] [dB] at legal cells ``columns`` [V] fall in each candidate's
        predicted distribution, as a standard normal: ``Phi^-1(F(m))``, ``F(m) = p_dead + (1 - p_dead) Phi((m - mu) /
        sigma)`` the predicted probability of a value at or below ``m`` (dead the lowest); at the floor (censored: dead,
        or live and at or below it) the normal's mean below ``Phi^-1(F(floor))``."""
        m = np.asarray(measured, np.float64)
        low = m <= floor_db + 1e-3
        z = self.latent_at(maps.mu[:, columns], maps.p_dead[:, columns], np.where(low, floor_db, m))
        below = -np.exp(-0.5 * z * z) / math.sqrt(2 * math.pi) / ndtr(z)  # E[Z | Z <= z] of a standard normal Z
        return np.where(low, below, z)

    def latent_at(self, mu: np.ndarray, p_dead: np.ndarray, level: np.ndarray | float) -> np.ndarray:
        """``Phi^-1(p_dead + (1 - p_dead) Phi((level - mu) / sigma))``: the standard normal value at the predicted
        probability of a value at or below ``level`` [dB], dead the lowest (clipped to 1e-6 from 0 and 1)."""
        mu, p_dead = mu.astype(np.float64), p_dead.astype(np.float64)
        return ndtri(np.clip(p_dead + (1 - p_dead) * ndtr((level - mu) / self.read_sigma), 1e-6, 1 - 1e-6))

    def kriging(self, legal: np.ndarray, columns: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The simple-kriging weights ``[V, K]`` of the error latents at legal cells ``columns`` [V] (distinct) for the
        latents at cells ``targets`` [K], and the latents' spread ``[K]`` given them, under a correlation
        ``error_share * exp(-d / error_range_cells)`` between two cells ``d`` cells apart (1 at the same cell)."""
        cfg = self.config
        at, to = legal[columns].astype(np.float64), legal[targets].astype(np.float64)
        k_vv = cfg.error_share * np.exp(-np.hypot(*(at[:, None, :] - at[None, :, :]).transpose(2, 0, 1)) / cfg.error_range_cells)
        np.fill_diagonal(k_vv, 1.0)
        k_vt = cfg.error_share * np.exp(-np.hypot(*(at[:, None, :] - to[None, :, :]).transpose(2, 0, 1)) / cfg.error_range_cells)
        k_vt[(at[:, None, :] == to[None, :, :]).all(axis=2)] = 1.0
        weights = np.linalg.solve(k_vv, k_vt)
        return weights, np.sqrt(np.clip(1.0 - (k_vt * weights).sum(axis=0), 1e-4, 1.0))

    def kriged_cover(
        self,
        maps: CandidateMaps,
        log_b: np.ndarray,
        columns: np.ndarray,
        measured: np.ndarray,
        floor_db: float,
        targets: np.ndarray,
        latents: np.ndarray | None = None,
    ) -> np.ndarray:
        """``[K]`` the posterior probability that each of legal cells ``targets`` reaches P_T under belief ``log_b`` [C],
        each candidate's chance there moved by what measurements ``measured`` [V] at legal cells ``columns`` [V]
        (distinct) say of its map's errors: the error latents (``error_latent``) kriged to the targets (``kriging``),
        a cell reaching P_T when its latent is above ``Phi^-1(1 - cover)``. Candidates of belief under 1e-6 of the
        largest are left out. ``latents`` [C, V]: the measurements' ``error_latent``, where the caller holds them."""
        b = np.exp(log_b - log_b.max())
        keep = b > 1e-6
        b = b[keep] / b[keep].sum()
        weights, spread = self.kriging(maps.legal, columns, targets)
        latents = self.error_latent(maps, columns, measured, floor_db) if latents is None else latents
        latent = latents[keep].astype(np.float32)  # [C', V]
        q = (probit_of(maps.cover[:, targets]) if maps.probit is None else maps.probit[:, targets])[keep]  # [C', K]
        # torch's normal CDF: the step's main cost, a tenth of scipy's on these cores
        device = torch.device("cpu") if self.on_device is None else self.on_device.device

        def put(a: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(a, np.float32)).to(device)

        z = (put(latent) @ put(weights) + put(q)) / put(spread)
        return (put(b) @ torch.special.ndtr(z)).cpu().numpy().astype(np.float64)

    def update(
        self,
        maps: CandidateMaps,
        log_b: np.ndarray,
        column: int,
        measured: float,
        floor_db: float,
        before: dict[int, float] | None = None,
        latents: np.ndarray | None = None,
    ) -> np.ndarray:
        """``log_b`` [C] after measuring ``measured`` [dB] at legal cell ``column`` (the module's likelihood; given the
        measurements ``before``, legal cell to value, where ``SearchConfig.kriged_belief``: ``correlated_update``,
        ``latents`` theirs where the caller holds them)."""
        if before and self.config.kriged_belief:
            return self.correlated_update(maps, log_b, column, measured, floor_db, before, latents)
        return self.update_rows(maps, log_b[None], np.array([column]), np.array([measured], np.float64), floor_db)[0]

    def correlated_update(
        self,
        maps: CandidateMaps,
        log_b: np.ndarray,
        column: int,
        measured: float,
        floor_db: float,
        before: dict[int, float],
        latents: np.ndarray | None = None,
    ) -> np.ndarray:
        """``log_b`` [C] after measuring ``measured`` [dB] at legal cell ``column``, each candidate's likelihood taken
        given the ``error_memory`` measurements last made ``before`` (legal cell to value, ``column`` not among them):
        its error latent there (``error_latent``) is normal with the mean and spread kriged from theirs (``kriging``),
        so a value its map predicted no better than its neighbours' adds little against it. Above the floor the
        density ``(1 - p_dead) N(m; mu, sigma) N(eps; mean, spread) / N(eps; 0, 1)`` (the Gaussian copula); at the
        floor ``Phi((Phi^-1(F(floor)) - mean) / spread)``; a share ``outlier`` flat, the power ``temper``, as
        ``update_rows``. ``latents`` [C, V]: the ``error_latent`` of the last ``error_memory`` of ``before``, where the
        caller holds them."""
        cfg, sigma, eps = self.config, self.read_sigma, self.config.outlier
        columns = np.fromiter(before, np.int64)[-cfg.error_memory :]
        values = np.fromiter(before.values(), np.float64)[-cfg.error_memory :]
        weights, spread = self.kriging(maps.legal, columns, np.array([column]))
        latents = self.error_latent(maps, columns, values, floor_db) if latents is None else latents
        mean = (latents @ weights)[:, 0]  # [C]
        mu, p_dead = maps.mu[:, column].astype(np.float64), maps.p_dead[:, column].astype(np.float64)
        low = measured <= floor_db + 1e-3
        latent = self.latent_at(mu, p_dead, floor_db if low else measured)
        if low:
            like = (1 - eps) * ndtr((latent - mean) / spread[0]) + eps
        else:
            z = (measured - mu) / sigma
            copula = np.exp(-0.5 * ((latent - mean) / spread[0]) ** 2 + 0.5 * latent**2) / spread[0]
            density = (1 - p_dead) * np.exp(-0.5 * z * z) / (sigma * math.sqrt(2 * math.pi))
            like = (1 - eps) * density * copula + eps / OUTLIER_SPAN_DB
        out = log_b + cfg.temper * np.log(like + 1e-30)
        return (out - out.max()).astype(np.float32)

    def update_rows(
        self, maps: CandidateMaps, log_b: np.ndarray, columns: np.ndarray, measured: np.ndarray, floor_db: float
    ) -> np.ndarray:
        """``log_b`` [R, C] after row ``i`` measured ``measured[i]`` [dB] at legal cell ``columns[i]``: ``update`` of
        each row, the same numbers, the rows at once."""
        sigma = self.read_sigma
        eps = self.config.outlier
        mu, p_dead = maps.mu[:, columns].T, maps.p_dead[:, columns].T  # [R, C]
        like = np.empty(mu.shape, np.float32)
        floor = np.asarray(measured, np.float64) <= floor_db + 1e-3  # censored: the probability of a value at or below the floor
        if floor.any():
            d = p_dead[floor]
            like[floor] = (1 - eps) * (d + (1 - d) * ndtr((floor_db - mu[floor]) / sigma)) + eps
        if not floor.all():  # a density over dB; the flat part spreads its share over OUTLIER_SPAN_DB
            z = (np.asarray(measured, np.float32)[~floor, None] - mu[~floor]) / sigma
            live = (1 - eps) * (1 - p_dead[~floor]) * np.exp(-0.5 * z * z) / (sigma * math.sqrt(2 * math.pi))
            like[~floor] = live + eps / OUTLIER_SPAN_DB
        out = log_b + self.config.temper * np.log(like + 1e-30)
        return out - out.max(axis=1, keepdims=True)

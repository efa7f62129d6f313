"""The searcher's belief of every row of a ``BatchedEnv`` as an observation channel (``BeliefTracker``: the hybrid
learner's, ``EnvConfig.belief_channel``)."""

from __future__ import annotations

import numpy as np

from uavplace.rl.belief.cache import PredictionCache
from uavplace.rl.belief.model import BeliefModel, CandidateMaps, posterior_cover
from uavplace.rl.config import SearchConfig
from uavplace.rl.predictor import Predictor
from uavplace.rl.world.maps import MapSet, transform
from uavplace.rl.world.view import PublicMaps


class BeliefTracker:
    """The searcher's belief for every row of a ``BatchedEnv``, as an observation channel (``EnvConfig.belief_channel``):
    the hybrid of docs/searcher.md, a learner that reads where the belief says P_T is likely.

    Per row, ``log_b`` [N, C_max] the log-belief over the candidate cells of its city (the searcher's ``update`` after
    every measurement, the start's included; -inf past the city's candidates) and ``cover`` [N, L, L] the posterior
    probability [%] that each legal canvas cell reaches P_T (0 on blocked cells and beyond the map; with ``window``,
    current only in the window centred on the row's last measurement, what its observation reads). A canvas under
    symmetry ``k`` reads its city's predictions at ``k = 0`` through the turned column map (``candidates``): the
    predicted maps of the unturned city, turned, never predicted again. It is told only what the UAV measures
    (``start``, ``measure``): the users' maps stay in the env. With ``MapSet.buildings_shown`` False (after
    ``show_buildings(None)``) the predictor is shown open ground, as in the searcher's ablation. ``precision``: the
    cover's product in float32 or in bfloat16 (``EnvConfig.belief_precision``, ``posterior_cover``).
    """

    def __init__(
        self,
        maps: MapSet,
        num_envs: int,
        predictor: Predictor,
        config: SearchConfig,
        cache: PredictionCache,
        window: int | None = None,
        precision: str = "float32",
    ) -> None:
        self.maps = maps
        self.window = window
        self.precision = "belief" if precision == "float32" else precision  # posterior_cover's name: its beliefs are float32
        self.public = PublicMaps.of(maps)
        self.models = {b: BeliefModel(predictor, config.model_copy(update={"buildings": b}), cache) for b in (True, False)}
        self._columns: dict[tuple[int, bool], np.ndarray] = {}
        self._around: dict[tuple[int, bool], np.ndarray] = {}  # [.., w, w] windows of each canvas's column map
        if window is not None and window // 2 > self.public.pad:
            raise ValueError(f"a window of {window} cells reaches past the canvas's pad of {self.public.pad}")
        S = self.public.symmetries
        width = max(len(self.candidates(S * i)[0].cells) for i in range(len(maps.bundles)))
        self.log_b = np.full((num_envs, width), -np.inf, np.float32)
        self.canvas = np.zeros(num_envs, np.int64)
        self.cover = np.zeros((num_envs, maps.side, maps.side), np.float32)
        if window is not None:  # window (y0, x0) of row r is [r, y0, x0], written through
            self._cover_windows = np.lib.stride_tricks.sliding_window_view(
                self.cover, (window, window), axis=(1, 2), writeable=True
            )

    def candidates(self, canvas: int) -> tuple[CandidateMaps, np.ndarray]:
        """The predictions of ``canvas``'s city (at symmetry 0, with or without its buildings as the maps show them)
        and ``[num_y, num_x]`` the column of each cell of the canvas's (turned) map in them (-1 where the UAV may not
        go)."""
        public, shown = self.public, self.maps.buildings_shown
        if not isinstance(shown, bool):
            raise ValueError(f"the belief channel predicts with the city's buildings or none, not with {shown}'s")
        k = public.symmetry_of(canvas)
        cm = self.models[shown].canvas_maps(public, canvas - k)
        if (canvas, shown) not in self._columns:
            self._columns[canvas, shown] = np.ascontiguousarray(transform(cm.index, k))
        return cm, self._columns[canvas, shown]

    def start(
        self,
        rows: np.ndarray,
        canvases: np.ndarray,
        y: np.ndarray,
        x: np.ndarray,
        first: np.ndarray,
        unread: np.ndarray | None = None,
    ) -> None:
        """Rows ``rows`` begin over ``canvases``, measuring ``first`` at map cells ``(y, x)``: a uniform belief
        updated by that measurement (``unread``: as ``measure``'s)."""
        self.canvas[rows] = canvases
        self.log_b[rows] = -np.inf
        for r, c in zip(rows, canvases, strict=True):
            self.log_b[r, : len(self.candidates(int(c))[0].cells)] = 0.0
        self.measure(rows, y, x, first, unread)

    def measure(
        self, rows: np.ndarray, y: np.ndarray, x: np.ndarray, values: np.ndarray, unread: np.ndarray | None = None
    ) -> None:
        """Rows ``rows`` measured ``values`` [dB] at map cells ``(y, x)``: their beliefs, then their cover canvases
        (with ``window``, only the window centred on ``(y, x)``: all an observation reads before the next measurement).
        ``unread`` [len(rows)]: rows whose canvas no one reads (a played-out queue's placeholders), left as they are."""
        public, model = self.public, self.models[self.maps.buildings_shown]
        read = np.ones(len(rows), bool) if unread is None else ~np.asarray(unread, bool)
        for c, members in self._groups(rows, read).items():  # a canvas's rows updated at once
            cm, columns = self.candidates(c)
            floor_db = float(public.settings[public.bundle_of(c)]["floor_db"])
            r, n, at = rows[members], len(cm.cells), columns[y[members], x[members]]
            self.log_b[r, :n] = model.update_rows(cm, self.log_b[r, :n], at, values[members], floor_db)
        self.paint(rows, read, (np.asarray(y), np.asarray(x)))

    def paint(self, rows: np.ndarray, read: np.ndarray | None = None, at: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """The cover canvases of rows ``rows`` (those of ``read`` only) from their beliefs, a canvas's rows in one
        matrix product; with ``window`` and ``at``, only the window centred on each row's map cell ``(y, x)``, else
        the whole canvas.

        The product takes every row of ``rows`` on the canvas, read or not, and the unread ones are dropped after it:
        a row's sums then never depend on which of its neighbours someone reads (a BLAS orders a product's sums by
        its shape, so a row computed among fewer rows may differ in the last bit)."""
        read = np.ones(len(rows), bool) if read is None else read
        p = self.public.pad
        for c, members in self._groups(rows).items():
            kept = [i for i in members if read[i]]
            if not kept:
                continue
            cm, columns = self.candidates(c)
            log_b = self.log_b[rows[members], : len(cm.cells)]
            scores = np.zeros((len(kept), cm.cover.shape[1] + 1), np.float32)  # the last column: -1's zero
            scores[:, :-1] = posterior_cover(log_b, cm, precision=self.precision)[[members.index(i) for i in kept]]
            scores *= np.float32(100.0)
            targets = rows[kept]
            if at is None or self.window is None:
                ny, nx = columns.shape
                self.cover[targets] = 0.0  # a turned map of another shape may have painted beyond this one
                self.cover[targets, p : p + ny, p : p + nx] = scores[:, columns]
            else:
                self._paint_windows(c, targets, scores, at[0][kept], at[1][kept])

    def _groups(self, rows: np.ndarray, read: np.ndarray | None = None) -> dict[int, list[int]]:
        """``{canvas: [i, ...]}``: the positions in ``rows`` (of ``read`` only) of each canvas's rows, in order."""
        groups: dict[int, list[int]] = {}
        for i, r in enumerate(rows):
            if read is None or read[i]:
                groups.setdefault(int(self.canvas[r]), []).append(i)
        return groups

    def _paint_windows(self, canvas: int, targets: np.ndarray, scores: np.ndarray, y: np.ndarray, x: np.ndarray) -> None:
        """Write ``scores`` [R, M + 1] into the ``window`` of rows ``targets`` (over ``canvas``) centred on map cells
        ``(y, x)``: the canvas there as ``paint`` would make it whole (0 off the map and where the UAV may not go)."""
        w, h, p = self.window, self.window // 2, self.public.pad
        key = (canvas, self.maps.buildings_shown)
        if key not in self._around:  # a column per cell a window centred on the map covers, -1 off the map
            columns = self.candidates(canvas)[1]
            ny, nx = columns.shape
            around = np.full((ny + 2 * h, nx + 2 * h), -1, np.int64)
            around[h : h + ny, h : h + nx] = columns
            self._around[key] = np.lib.stride_tricks.sliding_window_view(around, (w, w))
        cells = self._around[key][y, x]  # [R, w, w]
        self._cover_windows[targets, y + p - h, x + p - h] = scores[np.arange(len(targets))[:, None, None], cells]

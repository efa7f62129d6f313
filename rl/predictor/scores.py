"""How well a tier's maps match the measured ones (``scores_of``, ``reliability``, ``platt_scaling``), and every tier
scored on validation cities' users: what `uavrl train-predictor` writes into the model card."""

from __future__ import annotations

import time

import numpy as np

from uavplace.dataset.bundle import Bundle
from uavplace.rl.predictor.base import Predictor
from uavplace.rl.predictor.scene import Scene


def reliability(p: np.ndarray, outcome: np.ndarray, bins: int = 10) -> tuple[float, list[list[float]]]:
    """(expected calibration error, the reliability diagram's rows) of probabilities ``p`` of events ``outcome``
    (bool), in ``bins`` equal-width bins of ``p``: per non-empty bin ``[mean p, observed frequency, count]``; the
    error is the count-weighted mean of ``|frequency - mean p|`` (Guo et al. 2017)."""
    p = np.asarray(p, np.float64).ravel()
    outcome = np.asarray(outcome, bool).ravel()
    which = np.minimum((p * bins).astype(np.int64), bins - 1)
    count = np.bincount(which, minlength=bins)
    mean_p = np.bincount(which, weights=p, minlength=bins)
    hits = np.bincount(which, weights=outcome.astype(np.float64), minlength=bins)
    rows = [[mean_p[b] / count[b], hits[b] / count[b], float(count[b])] for b in range(bins) if count[b]]
    ece = sum(n * abs(f - m) for m, f, n in rows) / max(len(p), 1)
    return float(ece), rows


def platt_scaling(logit: np.ndarray, outcome: np.ndarray) -> tuple[float, float]:
    """(scale, bias) of least binary cross-entropy of ``sigmoid(scale * logit + bias)`` against events ``outcome``
    (Platt 1999): Newton's method on the two parameters from (1, 0), steps halved until the loss falls, a ridge of 1e-6 keeping it defined when the
    events are separable."""
    z = np.asarray(logit, np.float64).ravel()
    y = np.asarray(outcome, np.float64).ravel()
    x = np.stack([z, np.ones_like(z)], axis=1)

    def loss(t: np.ndarray) -> float:  # the mean cross-entropy, from the logits (no log of 0)
        a = x @ t
        return float(np.mean(np.logaddexp(0, a) - y * a))

    theta = np.array([1.0, 0.0])
    current = loss(theta)
    for _ in range(100):
        p = 1 / (1 + np.exp(-np.clip(x @ theta, -50, 50)))
        hess = (x * (p * (1 - p))[:, None]).T @ x + 1e-6 * np.eye(2)
        step = np.linalg.solve(hess, x.T @ (p - y))
        shrink = 1.0  # halve the Newton step until the loss falls (Newton alone overshoots far from the optimum)
        while shrink > 1e-6 and loss(theta - shrink * step) > current:
            shrink /= 2
        theta = theta - shrink * step
        new = loss(theta)
        if current - new < 1e-12:
            break
        current = new
    return float(theta[0]), float(theta[1])


def predicted_and_measured(bundle: Bundle, users: np.ndarray, predictor: Predictor) -> dict:
    """``predictor``'s maps (any tier) of ``users`` of ``bundle``
    beside the measured ones, at the legal cells, flattened: ``mu``, ``p_dead``, ``sinr``, ``dead``, ``low`` (dead or
    at the SINR floor: the event ``p_dead`` predicts), ``floor_db`` and ``ms_per_map`` (the milliseconds per
    predicted map of the legal cells)."""
    scene = Scene.of(bundle)
    cells = np.argwhere(~bundle.blocked)
    where = bundle.user_cells(users)
    t0 = time.perf_counter()
    mu, p_dead = predictor.predict(scene, where, cells)
    ms = 1000 * (time.perf_counter() - t0) / max(len(users), 1)
    sinr = bundle.sinr_db[np.asarray(users)[:, None], cells[None, :, 0], cells[None, :, 1]].ravel()
    dead = bundle.dead[np.asarray(users)[:, None], cells[None, :, 0], cells[None, :, 1]].ravel()
    low = dead | (sinr <= scene.floor_db + 1e-3)
    return {
        "mu": mu.ravel(),
        "p_dead": p_dead.ravel(),
        "sinr": sinr,
        "dead": dead,
        "low": low,
        "floor_db": scene.floor_db,
        "ms_per_map": ms,
    }


def prediction_scores(bundle: Bundle, users: np.ndarray, predictor: Predictor) -> dict[str, float]:
    """How well ``predictor``'s maps match ``users``' maps of ``bundle`` (``predicted_and_measured``): ``scores_of``."""
    return scores_of(predicted_and_measured(bundle, users, predictor))


def scores_of(pm: dict) -> dict[str, float]:
    """The scores of predicted beside measured maps ``pm`` (``predicted_and_measured``): ``median_error_db`` and
    ``p90_error_db`` of |predicted - measured| SINR on the live cells (the prediction floored, and the floor's value
    where it says dead), ``dead_live_agreement``, the share of cells whose dead-or-live call (dead where the dead
    probability > 1/2) is right, ``calibration_error``, the expected calibration error (``reliability``) of the dead
    probability against what it predicts (a cell dead or at the floor), ``ms_per_map`` and ``cells``."""
    called_dead = pm["p_dead"] > 0.5
    shown = np.where(called_dead, pm["floor_db"], np.maximum(pm["mu"], pm["floor_db"]))
    err = np.abs(shown - pm["sinr"])[~pm["dead"]]
    return {
        "median_error_db": float(np.median(err)),
        "p90_error_db": float(np.percentile(err, 90)),
        "dead_live_agreement": float((called_dead == pm["dead"]).mean()),
        "calibration_error": reliability(pm["p_dead"], pm["low"])[0],
        "ms_per_map": float(pm["ms_per_map"]),
        "cells": int(len(pm["sinr"])),
    }


#: The columns of a tier's scores on a validation city, as the model card and the command print them.
SCORE_COLUMNS = ("median |error| [dB]", "p90 |error| [dB]", "dead/live agreement", "calibration error", "ms per map")


def score_cells(scores: dict[str, float], prefix: str = "") -> list[str]:
    """A tier's scores (``scores_of``, each name after ``prefix``) as the cells of ``SCORE_COLUMNS``."""
    s = {k.removeprefix(prefix): v for k, v in scores.items() if k.startswith(prefix)}
    return [
        f"{s['median_error_db']:.1f}",
        f"{s['p90_error_db']:.1f}",
        f"{100 * s['dead_live_agreement']:.1f} %",
        f"{s['calibration_error']:.3f}",
        f"{s['ms_per_map']:.0f}",
    ]


def score_tiers(
    bundles: list[Bundle], tiers: dict[str, Predictor]
) -> tuple[dict[str, dict[str, float]], dict[str, list[list[float]]]]:
    """Every tier of ``tiers`` (name -> predictor) on all users of each validation bundle: per city, the scores of
    each tier as ``{tier}_{score}`` (``scores_of``), and the reliability diagram of the first tier's
    dead-cell probability (``reliability``)."""
    scores: dict[str, dict[str, float]] = {}
    diagrams: dict[str, list[list[float]]] = {}
    for b in bundles:
        row: dict[str, float] = {}
        for i, (tier, predictor) in enumerate(tiers.items()):
            pm = predicted_and_measured(b, b.user_indices(), predictor)
            row.update({f"{tier}_{k}": v for k, v in scores_of(pm).items()})
            if i == 0:
                diagrams[b.city] = reliability(pm["p_dead"], pm["low"])[1]
        scores[b.city] = row
    return scores, diagrams

"""What the UAV reads at a cell: the true SINR plus an error (``rl.config.MeasurementSettings``, a setting of every task).

- **i.i.d. error**: Gaussian in dB, spread ``sigma_db``, drawn anew at every step.
- **shadowing**: a Gaussian field in space, spread ``shadow_sigma_db``, its correlation between two cells ``d`` metres
  apart ``exp(-d / shadow_distance_m)`` (Gudmundson's model); one field per episode and user, fixed through the
  episode. It is a sum of ``SHADOW_WAVES`` cosines whose wave vectors are drawn from that correlation's 2-D spectrum
  (the radius's CDF ``1 - 1 / sqrt(1 + k^2 d^2)``, the direction and phase uniform), so it is evaluated only at the
  cells measured, never on a whole canvas.

A dead cell reads as dead, at the floor (no link: the receiver decodes nothing, whatever the error). Every draw is
keyed by the episode's world key (its episode and its user, ``rl.randomness``) and the step: an episode reads the same
errors in any list, batch or subset of a run. The env adds the error to what it writes into the UAV's memory; it
judges success, rewards and its metrics on the true SINR.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtri

from uavplace.rl.config import MeasurementSettings
from uavplace.rl.randomness import stream_key, uniforms

#: The draws' streams (``rl.randomness``): the i.i.d. error's, step by step, and the shadowing field's, once.
ERROR_STREAM = stream_key("measurement error")
SHADOW_STREAM = stream_key("shadowing field")
#: Cosines of one shadowing field: its values are near Gaussian (a sum of 64 independent terms).
SHADOW_WAVES = 64


def _normal(u: np.ndarray) -> np.ndarray:
    """Standard normal values of uniforms ``u`` in [0, 1) (0 moved half an ulp of 2**-53 in, never -inf)."""
    return ndtri(u + 2.0**-54)


def shadow_waves(keys: np.ndarray, distance_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each episode's shadowing field (world ``keys`` [N]): wave vectors ``kx``, ``ky`` [N, W] [rad/m] and phases
    [N, W], drawn from the exponential correlation's spectrum (module docstring)."""
    u = uniforms(SHADOW_STREAM, keys, np.zeros(len(keys), np.int64), 3 * SHADOW_WAVES)
    radius, angle, phase = np.split(u, 3, axis=1)
    k = np.sqrt(1.0 / np.square(1.0 - radius) - 1.0) / distance_m
    return k * np.cos(2 * np.pi * angle), k * np.sin(2 * np.pi * angle), 2 * np.pi * phase


def shadowing(keys: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, sigma_db: float, distance_m: float) -> np.ndarray:
    """[N] the shadowing [dB] of each episode's field (world ``keys`` [N]) at the points ``(x_m, y_m)`` [N]."""
    kx, ky, phase = shadow_waves(keys, distance_m)
    waves = np.cos(kx * np.asarray(x_m, np.float64)[:, None] + ky * np.asarray(y_m, np.float64)[:, None] + phase)
    return sigma_db * np.sqrt(2.0 / SHADOW_WAVES) * waves.sum(axis=1)


def measurement_error(
    settings: MeasurementSettings, keys: np.ndarray, step: np.ndarray, x_m: np.ndarray, y_m: np.ndarray
) -> np.ndarray:
    """[N] the error [dB] of each row's reading at step ``step`` [N], at the points ``(x_m, y_m)`` [N] [m] of its
    episode (world ``keys`` [N]); zeros for the exact measurement."""
    error = np.zeros(len(keys))
    if settings.sigma_db > 0:
        error += settings.sigma_db * _normal(uniforms(ERROR_STREAM, keys, step, 1)[:, 0])
    if settings.shadow_sigma_db > 0:
        error += shadowing(keys, x_m, y_m, settings.shadow_sigma_db, settings.shadow_distance_m)
    return error


def read(
    settings: MeasurementSettings,
    true_db: np.ndarray,
    dead: np.ndarray,
    keys: np.ndarray,
    step: np.ndarray,
    x_m: np.ndarray,
    y_m: np.ndarray,
) -> np.ndarray:
    """What the UAVs read [dB] (the dtype of ``true_db``): ``true_db`` plus ``measurement_error`` where the cell is
    live; ``true_db`` itself (the floor) where it is ``dead``, and everywhere for the exact measurement."""
    if settings.exact:
        return true_db
    error = measurement_error(settings, keys, step, x_m, y_m)
    return np.where(dead, true_db, true_db + error).astype(true_db.dtype)

"""The UAV's 3D map when it is not the traced city (``rl.config.MapErrorSettings``, a setting of every task).

``seen_heights`` makes, from a bundle's building heights, the heights the UAV's map holds:

1. each building (``Bundle.building_id``) off by its own Gaussian error of spread ``height_sigma_m``, never below
   the ground;
2. a share ``missing_share`` of the buildings whose footprint is under ``missing_area_m2`` missing (ground there);
3. the whole map shifted by ``shift_m`` in a random direction (bilinear, the edge's values carried on).

The errors are drawn, every one of them whatever the settings (so one seed gives the same error of a kind whichever
others are on), from the settings' ``seed`` and the city's public map (``Bundle.public_digest``): the same city
errs alike in every run. Only heights change: which cells the UAV may enter is its own obstacle sensing, the traced
city's (``MapSet.blocked``); the users' maps, the genie and the oracles never see the error.
"""

from __future__ import annotations

import hashlib

import numpy as np
from scipy import ndimage

from uavplace.dataset.bundle import Bundle
from uavplace.rl.config import MapErrorSettings


def seen_heights(bundle: Bundle, settings: MapErrorSettings) -> np.ndarray:
    """``[ny, nx]`` float32: the building heights minus the altitude (``Bundle.height_rel_m``'s form) of the UAV's
    map of ``bundle`` under ``settings`` (the module's docstring); the bundle's own when the map is exact."""
    if settings.exact:
        return bundle.height_rel_m
    rng = np.random.default_rng([settings.seed, int(bundle.public_digest[:15], 16)])
    ground = -float(bundle.altitude_m)
    heights = bundle.height_rel_m.astype(np.float64)
    ids = bundle.building_id
    on = ids >= 0
    names, index, cells = np.unique(ids[on], return_inverse=True, return_counts=True)
    errors = rng.normal(0.0, 1.0, len(names)) * settings.height_sigma_m
    missing = (cells * bundle.spacing_m**2 < settings.missing_area_m2) & (rng.random(len(names)) < settings.missing_share)
    angle = rng.uniform(0.0, 2 * np.pi)
    heights[on] = np.maximum(heights[on] + errors[index], ground)
    heights[on] = np.where(missing[index], ground, heights[on])
    if settings.shift_m > 0:
        shift = settings.shift_m / bundle.spacing_m * np.array([np.sin(angle), np.cos(angle)])  # (rows: y, columns: x)
        heights = ndimage.shift(heights, shift, order=1, mode="nearest")
    return heights.astype(np.float32)


def error_tag(settings: MapErrorSettings) -> str:
    """What names an erring map beside its city's version (the searcher's cache keys its predicted maps by it): empty
    for the exact map."""
    if settings.exact:
        return ""
    return "~map-" + hashlib.sha256(settings.model_dump_json().encode()).hexdigest()[:12]

"""The radio-map predictor family: what a searcher can know of a user's map before measuring it.

Every tier reads only what the UAV knows (``Scene``: the city's building heights on its grid, the altitude, the
carrier, the user's power, the noise and the SINR floor) and a candidate user cell, and gives what the belief needs
(the ``Predictor`` protocol): the predicted SINR at every UAV cell, the probability that a cell is dead, the spread of
its errors, and a version that keys the cache of its maps (its weights, constants, settings and ``code_digest``, the
hash of this folder's code). The tiers, one module each:

- ``physics``: free space, walls crossed and Deygout's knife edges, four constants fitted on training cities;
- ``learned``: a U-Net that corrects the physics tier, trained on training cities' ray-traced maps;
- ``raytraced``: Sionna RT over the city's public 3D map (the heights as buildings, one generic material).

``load_predictor`` reads a tier from its model card: a folder's ``model.json`` names its tier (none: learned), a file
is the physics tier's constants. ``scores`` holds the scores every tier is judged by, ``cli`` the commands that fit,
train and calibrate them, ``weights`` the learned tier's bounded weights-only reader.
"""

from __future__ import annotations

import json
from pathlib import Path

from uavplace.infra.files import read_model_json, read_small_file
from uavplace.rl.config import DEFAULT_CONSTANTS, DEFAULT_PREDICTOR
from uavplace.rl.predictor.base import Predictor, code_digest, version_of
from uavplace.rl.predictor.physics import (
    FEATURES_VERSION,
    PhysicsConstants,
    PhysicsPredictor,
    dead_probability,
    fit_constants,
    fresnel_nu,
    knife_edge_db,
    path_features,
    predict_sinr,
    sinr_from_features,
)
from uavplace.rl.predictor.scene import C_M_S, Scene
from uavplace.rl.predictor.scores import platt_scaling, predicted_and_measured, prediction_scores, reliability, scores_of
from uavplace.schemas import InputError

__all__ = [
    "C_M_S",
    "FEATURES_VERSION",
    "TIERS",
    "PhysicsConstants",
    "PhysicsPredictor",
    "Predictor",
    "Scene",
    "code_digest",
    "dead_probability",
    "fit_constants",
    "fresnel_nu",
    "knife_edge_db",
    "load_constants",
    "load_predictor",
    "path_features",
    "platt_scaling",
    "predict_sinr",
    "predicted_and_measured",
    "prediction_scores",
    "reliability",
    "scores_of",
    "sinr_from_features",
    "tier_of",
    "version_of",
]

#: Each tier a folder's ``model.json`` may name, with its loader ("module:function", imported when named).
TIERS = {
    "learned": "uavplace.rl.predictor.learned:load_learned",
    "raytraced": "uavplace.rl.predictor.raytraced:load_raytraced",
}
#: The model card of a tier's folder.
MODEL_JSON = "model.json"


def tier_of(folder: str | Path) -> str:
    """The tier a predictor folder's ``model.json`` names (``tier``; a card without it is the learned tier's, the form
    before there were others); ``InputError`` naming the file when it is unreadable or names no known tier."""
    path = Path(folder) / MODEL_JSON
    data = read_small_file(path, "a predictor's model card (`uavrl train-predictor` writes it)")
    try:
        doc = json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise InputError(path, f"not JSON ({str(exc)[:120]})") from None
    tier = doc.get("tier", "learned") if isinstance(doc, dict) else None
    if tier not in TIERS:
        raise InputError(path, f"names tier {tier!r}; the tiers of a folder are {', '.join(TIERS)}", field="tier")
    return tier


def load_predictor(path: str | Path = DEFAULT_PREDICTOR) -> Predictor:
    """The predictor at ``path``: a folder is the tier its model card names (``tier_of``, ``TIERS``), a file the
    physics tier's constants (``load_constants``); ``InputError`` saying where the shipped ones live when there is
    none."""
    if Path(path).is_dir():
        import importlib

        module, function = TIERS[tier_of(path)].split(":")
        return getattr(importlib.import_module(module), function)(path)
    if not Path(path).exists() and not Path(path).is_symlink():
        raise InputError(
            path,
            f"no predictor here: give a tier's folder or a physics tier's constants (the shipped ones are "
            f"{DEFAULT_PREDICTOR} and {DEFAULT_CONSTANTS})",
        )
    return PhysicsPredictor(load_constants(path))


def load_constants(path: str | Path = DEFAULT_CONSTANTS) -> PhysicsConstants:
    """The physics tier's constants from their JSON file (``InputError`` naming it when unreadable or invalid)."""
    return read_model_json(path, PhysicsConstants, "a predictor's constants (`uavrl fit-predictor` writes them)")

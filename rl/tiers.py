"""The learned predictor's training maps gathered from cities and packs, and the predictors' tiers scored on
validation cities' users: what `uavrl train-predictor` reads and writes into the model card (``rl.learned``)."""

from __future__ import annotations

from pathlib import Path

from uavplace.dataset.bundle import Bundle
from uavplace.dataset.export import read_radiomapseer
from uavplace.dataset.trainmaps import TrainingMaps, read_pack, select_packs
from uavplace.rl.predictor import PhysicsPredictor, predicted_and_measured, reliability, scores_of

#: The columns of a tier's scores on a validation city, as the model card and the command print them.
SCORE_COLUMNS = ("median |error| [dB]", "p90 |error| [dB]", "dead/live agreement", "calibration error", "ms per map")


def training_maps(
    bundles: list[Bundle], users: list, folders: tuple[Path, ...] = (), patterns: tuple[str, ...] = ()
) -> list[TrainingMaps]:
    """The maps a predictor trains on: ``users`` of each of ``bundles``, then the packs of each folder of packs whose
    city matches one of ``patterns`` (``select_packs``; every pack without one), or one RadioMapSeer-style city folder
    (`uavdata export`: it has a ``scale.json``)."""
    maps = [TrainingMaps.of_bundle(b, u) for b, u in zip(bundles, users, strict=True)]
    for folder in folders:
        is_radiomapseer = (folder / "scale.json").is_file()
        maps += [read_radiomapseer(folder)] if is_radiomapseer else [read_pack(p) for p in select_packs([folder], patterns)]
    return maps


def score_cells(scores: dict[str, float], prefix: str = "") -> list[str]:
    """A tier's scores (``rl.predictor.scores_of``, each name after ``prefix``) as the cells of ``SCORE_COLUMNS``."""
    s = {k.removeprefix(prefix): v for k, v in scores.items() if k.startswith(prefix)}
    return [
        f"{s['median_error_db']:.1f}",
        f"{s['p90_error_db']:.1f}",
        f"{100 * s['dead_live_agreement']:.1f} %",
        f"{s['calibration_error']:.3f}",
        f"{s['ms_per_map']:.0f}",
    ]


def score_tiers(
    bundles: list[Bundle], tiers: dict[str, PhysicsPredictor]
) -> tuple[dict[str, dict[str, float]], dict[str, list[list[float]]]]:
    """Every tier of ``tiers`` (name -> predictor) on all users of each validation bundle: per city, the scores of
    each tier as ``{tier}_{score}`` (``rl.predictor.scores_of``), and the reliability diagram of the first tier's
    dead-cell probability (``rl.predictor.reliability``)."""
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

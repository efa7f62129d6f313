"""What the predictor's commands share (``rl.predictor.cli``): the options that name training cities, training-map
packs, validation cities and calibration maps, and the lines they print (the scores of every tier, a model card's
commands)."""

from __future__ import annotations

from pathlib import Path

import click

from uavplace.infra.console import path_option, plain_table, stdout
from uavplace.rl.config import DEFAULT_CONSTANTS

#: The predictors' training cities (``uavrl fit-predictor``, ``uavrl train-predictor``).
training_cities_option = click.option(
    "--dataset",
    "datasets",
    multiple=True,
    required=True,
    help="Training city (repeatable); a city with a declared role gives its train users only.",
)


#: Which packs of the --maps folders a learned tier reads (``uavrl train-predictor``, ``uavrl calibrate-predictor``).
packs_option = click.option(
    "--packs",
    multiple=True,
    help="Only the packs of --maps whose city's name matches this shell-style pattern, whole (repeatable; 'tt-*': the "
    "tiered cities, the real crops' kind of geometry, docs/predictor.md; 'tt-00[0-4]': five of them, for good). Default: "
    "every pack.",
)


def calibration_maps_option(purpose: str):  # noqa: ANN201 - a click decorator
    """The required ``--maps`` of a command that calibrates a tier on training-maps packs; ``purpose`` ends its help."""
    return click.option(
        "--maps",
        "map_folders",
        multiple=True,
        required=True,
        type=click.Path(file_okay=False, path_type=Path),
        help="A folder of training-maps packs (repeatable; `uavdata pack` writes them, data/trainmaps holds the shipped "
        f"ones) {purpose}",
    )


def no_pack_matched(folders: tuple[Path, ...], patterns: tuple[str, ...]) -> click.BadParameter:
    return click.BadParameter(
        f"no pack of {', '.join(map(str, folders))} is of a city named {' or '.join(patterns)}", param_hint="--packs"
    )


#: The learned tier's validation cities (``uavrl train-predictor``, ``uavrl calibrate-predictor``).
learned_validation_option = click.option(
    "--val-dataset",
    "val_datasets",
    multiple=True,
    help="Validation city whose users' maps score the tier the command writes and the physics tier (repeatable): median and p90 "
    "|error| [dB], dead/live agreement, calibration error, ms per map; in model.json and the card.",
)


def training_users(datasets: tuple[str, ...], root: Path) -> tuple[list, list]:
    """(bundles, their training users): a city with a declared role gives its train users only, any other all."""
    from uavplace.dataset.bundle import load_bundle

    bundles = [load_bundle(name, root=root) for name in datasets]
    return bundles, [b.user_indices("train") if b.manifest.config.role else b.user_indices() for b in bundles]


def card_commands(card: Path) -> list[str]:
    """The commands of a model card's "Made by" block (a card written before ``made_by`` was recorded), or none."""
    try:
        text = card.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return []
    _, found, rest = text.partition("## Made by")
    if not found or "```bash" not in rest:
        return []
    block = rest.split("```bash", 1)[1].split("```", 1)[0]
    return [line for line in block.strip().splitlines() if line.strip()]


def print_scores(scores: dict[str, dict[str, float]], tiers: list[str]) -> None:
    """Every tier's scores on every validation city (``rl.predictor.scores.score_tiers``), one row each; nothing without any."""
    from uavplace.rl.predictor.scores import SCORE_COLUMNS, score_cells

    table = plain_table("city", "tier", *SCORE_COLUMNS)
    for name, row in scores.items():
        for tier in tiers:
            table.add_row(name, tier, *score_cells(row, f"{tier}_"))
    if scores:
        stdout().print(table)


def constants_option(purpose: str):  # noqa: ANN201 - a click decorator
    """``--constants``: the physics tier's constants that the command's tier stands on (``purpose``)."""
    return path_option(
        "--constants",
        folder=False,
        default=DEFAULT_CONSTANTS,
        help=f"The physics tier {purpose} (`uavrl fit-predictor` writes it; default: the shipped one, found in the "
        "project wherever the command runs).",
    )

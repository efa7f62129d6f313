"""``uavrl fit-predictor`` and ``uavrl train-predictor``: the map searcher's radio-map predictor fitted and trained
on training cities and scored on validation cities (registered in ``uavplace.cli``)."""

from __future__ import annotations

import time
from pathlib import Path

import click

from uavplace.infra.console import LogLines, path_option, plain_table, root_option, stdout
from uavplace.infra.files import shipped
from uavplace.infra.options import model_options, settings
from uavplace.rl.config import UNetConfig

#: The predictors' training cities (``uavrl fit-predictor``, ``uavrl train-predictor``).
training_cities_option = click.option(
    "--dataset",
    "datasets",
    multiple=True,
    required=True,
    help="Training city (repeatable); a city with a declared role gives its train users only.",
)


def _training_users(datasets: tuple[str, ...], root: Path) -> tuple[list, list]:
    """(bundles, their training users): a city with a declared role gives its train users only, any other all."""
    from uavplace.dataset.bundle import load_bundle

    bundles = [load_bundle(name, root=root) for name in datasets]
    return bundles, [b.user_indices("train") if b.manifest.config.role else b.user_indices() for b in bundles]


@click.command("fit-predictor")
@training_cities_option
@click.option(
    "--val-dataset",
    "val_datasets",
    multiple=True,
    help="Validation city whose users' maps score the fit (repeatable): median and p90 |error| [dB], dead/live agreement.",
)
@path_option(
    "--out",
    folder=False,
    default=Path("data/agents/searcher/predictor.json"),
    help="The constants' JSON file (written atomically; a regular file or absent).",
)
@root_option
def fit_predictor(datasets: tuple[str, ...], val_datasets: tuple[str, ...], out: Path, root: Path) -> None:
    """Fit the map searcher's radio-map predictor (rl/predictor.py: free space, walls crossed and Deygout's knife
    edges on the straight path) on the users of training cities, and score it on validation cities' users."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.infra.files import atomic_write_text, check_replaceable_file
    from uavplace.rl.predictor import PhysicsPredictor, fit_constants, prediction_scores

    check_replaceable_file(out)
    bundles, users = _training_users(datasets, root)
    t0 = time.perf_counter()
    constants = fit_constants(bundles, users)
    table = plain_table("city", "users", "median |error| [dB]", "p90 |error| [dB]", "dead/live agreement")
    for name in val_datasets:
        b = load_bundle(name, root=root)
        s = prediction_scores(b, b.user_indices(), PhysicsPredictor(constants))
        table.add_row(
            name,
            str(b.num_users),
            f"{s['median_error_db']:.1f}",
            f"{s['p90_error_db']:.1f}",
            f"{100 * s['dead_live_agreement']:.1f} %",
        )
    atomic_write_text(out, constants.model_dump_json(indent=2) + "\n")
    if val_datasets:
        stdout().print(table)
    stdout().print(
        f"wrote {out}: fitted on {sum(map(len, users))} users of {len(bundles)} cities in "
        f"{time.perf_counter() - t0:.0f} s; error std {constants.error_db:.1f} dB",
        highlight=False,
        soft_wrap=True,
    )


@click.command("train-predictor")
@click.option(
    "--dataset",
    "datasets",
    multiple=True,
    help="Training city (repeatable); a city with a declared role gives its train users only.",
)
@click.option(
    "--maps",
    "map_folders",
    multiple=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="A folder of training-maps packs (repeatable; `uavdata pack` writes them, data/trainmaps holds the shipped "
    "ones), or a RadioMapSeer-style city folder (`uavdata export`, dataset/export.py): every user is a training user.",
)
@model_options(UNetConfig, "widths")
@click.option(
    "--val-dataset",
    "val_datasets",
    multiple=True,
    help="Validation city whose users' maps score both tiers "
    "(repeatable): median and p90 |error| [dB], dead/live agreement, ms per map; in model.json and the card.",
)
@path_option(
    "--constants",
    folder=False,
    default=shipped("data/agents/searcher/predictor.json"),
    help="The physics tier the network corrects (`uavrl fit-predictor` writes it; default: the shipped one, found in "
    "the project wherever the command runs).",
)
@path_option(
    "--out",
    folder=True,
    default=Path("data/agents/searcher/unet"),
    help="Folder of model.json, weights.pt and MODEL_CARD.md (replaced whole, or left as it was).",
)
@model_options(UNetConfig, "steps", "batch", "seed", "threads")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@root_option
def train_predictor(
    datasets: tuple[str, ...],
    map_folders: tuple[Path, ...],
    widths: str,
    val_datasets: tuple[str, ...],
    constants: Path,
    out: Path,
    steps: int,
    batch: int,
    seed: int,
    threads: int,
    quiet: bool,
    root: Path,
) -> None:
    """Train the map searcher's learned radio-map predictor (rl/learned.py: a U-Net correcting the physics tier)
    on the users of training cities (--dataset) and of training-maps packs (--maps), score it and the physics tier on
    validation cities' users, and write it with its model card. A validation city may not be a training city."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from uavplace.dataset.bundle import load_bundle
    from uavplace.infra.console import command_line
    from uavplace.infra.files import atomic_directory
    from uavplace.rl.belief import load_constants
    from uavplace.rl.learned import MODEL_CARD, MODEL_JSON, LearnedPredictor, model_card, save_learned, train_learned
    from uavplace.rl.predictor import PhysicsPredictor
    from uavplace.rl.tiers import SCORE_COLUMNS, score_cells, score_tiers, training_maps

    if not datasets and not map_folders:
        raise click.UsageError("give training maps: --dataset CITY or --maps FOLDER (or both)")
    config = settings(UNetConfig, {"widths": widths, "steps": steps, "batch": batch, "seed": seed, "threads": threads})
    physics = load_constants(constants)
    maps = training_maps(*_training_users(datasets, root), map_folders)
    overlap = sorted({m.city for m in maps} & set(val_datasets))
    if overlap:
        raise click.BadParameter(
            f"{', '.join(overlap)}: a validation city is also a training city (it would score the "
            "predictor on its own training maps)",
            param_hint="--val-dataset",
        )
    columns = (TextColumn("[bold]train-predictor[/] loss {task.fields[loss]:.4f}"), BarColumn(), MofNCompleteColumn())
    log = LogLines(quiet)  # a log: a plain line every LINE_SECONDS instead of a bar
    with Progress(*columns, TextColumn("steps"), TimeElapsedColumn(), console=stdout(), disable=quiet or log.enabled) as bar:
        task = bar.add_task("train", total=steps, loss=float("nan"))

        def on_progress(done: int, loss: float) -> None:
            bar.update(task, completed=done, loss=loss)
            log(f"train-predictor: step {done:,}/{steps:,} loss {loss:.4f}", last=done >= steps)

        net, facts = train_learned(maps, physics, config, progress=on_progress)
    fields = {"config": config, "constants": physics, "fitted_on": [f"{m.city}@{m.version}" for m in maps], **facts}
    with atomic_directory(out, marker=MODEL_JSON, what="learned predictor") as tmp:
        model = save_learned(tmp, net, fields)
        tiers = {"learned": LearnedPredictor(model, net), "physics": PhysicsPredictor(physics)}
        scores, diagrams = score_tiers([load_bundle(name, root=root) for name in val_datasets], tiers)
        model = model.model_copy(update={"scores": scores, "reliability": diagrams})
        (tmp / MODEL_JSON).write_text(model.model_dump_json(indent=2) + "\n")
        (tmp / MODEL_CARD).write_text(model_card(model, command_line()))
    table = plain_table("city", "tier", *SCORE_COLUMNS)
    for name, row in scores.items():
        for tier in tiers:
            table.add_row(name, tier, *score_cells(row, f"{tier}_"))
    if val_datasets:
        stdout().print(table)
    scale, bias = facts["calibration"]
    stdout().print(
        f"wrote {out}: trained on {facts['users']} users of {len(maps)} cities in "
        f"{facts['train_seconds']:.0f} s; residual std {facts['error_db']:.1f} dB; dead logit calibrated "
        f"x {scale:.3f} {bias:+.3f} on {facts['calibration_users']} held-out users",
        highlight=False,
        soft_wrap=True,
    )

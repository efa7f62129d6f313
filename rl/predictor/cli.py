"""``uavrl fit-predictor`` and ``uavrl train-predictor``: the map searcher's radio-map predictor fitted and trained
on training cities and scored on validation cities (registered in ``uavplace.cli``)."""

from __future__ import annotations

import time
from pathlib import Path

import click
import numpy as np

from uavplace.infra.console import LogLines, path_option, plain_table, root_option, say, stdout
from uavplace.infra.options import model_options, settings
from uavplace.rl.config import DEFAULT_PREDICTOR, UNetConfig
from uavplace.rl.predictor.options import (
    calibration_maps_option,
    card_commands,
    constants_option,
    learned_validation_option,
    no_pack_matched,
    packs_option,
    print_scores,
    training_cities_option,
    training_users,
)
from uavplace.rl.predictor.raytraced import RayTracedModel


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
    default=Path("runs/predictor/predictor.json"),
    help="The constants' JSON file (written atomically; a regular file or absent). The shipped constants are "
    "data/agents/searcher/predictor.json: name it to replace them.",
)
@root_option
def fit_predictor(datasets: tuple[str, ...], val_datasets: tuple[str, ...], out: Path, root: Path) -> None:
    """Fit the map searcher's radio-map predictor (rl/predictor/physics.py: free space, walls crossed and Deygout's knife
    edges on the straight path) on the users of training cities, and score it on validation cities' users."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.infra.files import atomic_write_text, check_replaceable_file
    from uavplace.rl.predictor import PhysicsPredictor, fit_constants, prediction_scores

    check_replaceable_file(out)
    bundles, users = training_users(datasets, root)
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
    say(
        f"wrote {out}: fitted on {sum(map(len, users))} users of {len(bundles)} cities in "
        f"{time.perf_counter() - t0:.0f} s; error std {constants.error_db:.1f} dB",
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
@packs_option
@model_options(UNetConfig, "widths")
@learned_validation_option
@constants_option("the network corrects")
@path_option(
    "--out",
    folder=True,
    default=Path("runs/predictor/unet"),
    help="Folder of model.json, weights.pt and MODEL_CARD.md (replaced whole, or left as it was). The shipped tier is "
    "data/agents/searcher/unet: name it to replace it.",
)
@model_options(UNetConfig, "steps", "batch", "seed", "threads")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@root_option
def train_predictor(
    datasets: tuple[str, ...],
    map_folders: tuple[Path, ...],
    packs: tuple[str, ...],
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
    """Train the map searcher's learned radio-map predictor (rl/predictor/learned.py: a U-Net correcting the physics tier)
    on the users of training cities (--dataset) and of training-maps packs (--maps), score it and the physics tier on
    validation cities' users, and write it with its model card. A validation city may not be a training city."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from uavplace.dataset.bundle import load_bundle
    from uavplace.dataset.trainmaps import select_packs
    from uavplace.infra.console import command_line
    from uavplace.infra.files import atomic_directory, check_output_folder
    from uavplace.rl.predictor import PhysicsPredictor, load_constants
    from uavplace.rl.predictor.learned import (
        MODEL_CARD,
        MODEL_JSON,
        WEIGHTS,
        LearnedPredictor,
        model_card,
        save_learned,
        train_learned,
        training_maps,
    )
    from uavplace.rl.predictor.scores import score_tiers

    if not datasets and not map_folders:
        raise click.UsageError("give training maps: --dataset CITY or --maps FOLDER (or both)")
    check_output_folder(out, MODEL_JSON, "learned predictor", (MODEL_JSON, WEIGHTS, MODEL_CARD))  # before the training
    config = settings(UNetConfig, {"widths": widths, "steps": steps, "batch": batch, "seed": seed, "threads": threads})
    physics = load_constants(constants)
    if packs and not map_folders:
        raise click.UsageError("--packs selects among the packs of --maps: give --maps FOLDER")
    if packs and not select_packs(map_folders, packs):  # before any map is read
        raise no_pack_matched(map_folders, packs)
    maps = training_maps(*training_users(datasets, root), map_folders, packs)
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
    fields = {
        "config": config,
        "constants": physics,
        "fitted_on": [f"{m.city}@{m.version}" for m in maps],
        **facts,
        "made_by": [command_line()],
    }
    with atomic_directory(out, marker=MODEL_JSON, what="learned predictor") as tmp:
        model = save_learned(tmp, net, fields)
        tiers = {"learned": LearnedPredictor(model, net), "physics": PhysicsPredictor(physics)}
        scores, diagrams = score_tiers([load_bundle(name, root=root) for name in val_datasets], tiers)
        model = model.model_copy(update={"scores": scores, "reliability": diagrams})
        (tmp / MODEL_JSON).write_text(model.model_dump_json(indent=2) + "\n")
        (tmp / MODEL_CARD).write_text(model_card(model, command_line()))
    print_scores(scores, list(tiers))
    scale, bias = facts["calibration"]
    say(
        f"wrote {out}: trained on {facts['users']} users of {len(maps)} cities in "
        f"{facts['train_seconds']:.0f} s; residual std {facts['error_db']:.1f} dB; dead logit calibrated "
        f"x {scale:.3f} {bias:+.3f} on {facts['calibration_users']} held-out users",
    )


@click.command("calibrate-predictor")
@path_option(
    "--predictor",
    folder=True,
    default=DEFAULT_PREDICTOR,
    help="The learned predictor's folder (`uavrl train-predictor` writes it): its weights are kept, its calibration refitted.",
)
@calibration_maps_option("of cities the network was not trained on: the calibration is fitted on every user of each.")
@packs_option
@learned_validation_option
@path_option(
    "--out",
    folder=True,
    default=Path("runs/predictor/calibrated"),
    help="Folder to write the calibrated predictor to (replaced whole, or left as it was). --predictor's own folder "
    "refits it in place (the shipped tier's calibration: --out data/agents/searcher/unet).",
)
@root_option
def calibrate_predictor(
    predictor: Path,
    map_folders: tuple[Path, ...],
    packs: tuple[str, ...],
    val_datasets: tuple[str, ...],
    out: Path,
    root: Path,
) -> None:
    """Refit the dead-cell probability's calibration of a learned predictor (Platt scaling of its uncalibrated dead
    logit) on training-maps packs its network was not trained on, score it on validation cities' users, and write it
    with its model card: the same weights, a new calibration, scores and reliability diagrams."""
    import shutil

    from uavplace.dataset.bundle import load_bundle
    from uavplace.dataset.trainmaps import read_pack, select_packs
    from uavplace.infra.console import command_line
    from uavplace.infra.files import atomic_directory, check_output_folder
    from uavplace.rl.predictor import PhysicsPredictor
    from uavplace.rl.predictor.learned import (
        MODEL_CARD,
        MODEL_JSON,
        WEIGHTS,
        LearnedPredictor,
        load_learned,
        model_card,
        pack_calibration,
    )
    from uavplace.rl.predictor.scores import score_tiers

    check_output_folder(out, MODEL_JSON, "learned predictor", (MODEL_JSON, WEIGHTS, MODEL_CARD))
    learned = load_learned(predictor)
    model = learned.model
    paths = select_packs(map_folders, packs)
    if not paths:
        raise no_pack_matched(map_folders, packs)
    maps = [read_pack(p) for p in paths]
    trained = {entry.rsplit("@", 1)[0] for entry in model.fitted_on}
    overlap = sorted({m.city for m in maps} & (trained | set(val_datasets)))
    if overlap:
        raise click.BadParameter(
            f"{', '.join(overlap)}: the network was trained on it, or it is a validation city (the calibration "
            "would be fitted on maps it is scored or trained on)",
            param_hint="--maps",
        )
    t0 = time.perf_counter()
    scale, bias = pack_calibration(learned, maps)
    made_by = model.made_by or card_commands(predictor / MODEL_CARD)
    model = model.model_copy(
        update={
            "calibration": (scale, bias),
            "calibration_users": 0,
            "calibrated_on": [f"{m.city}@{m.version}" for m in maps],
            "made_by": [*made_by, command_line()],
        }
    )
    calibrated = LearnedPredictor(model, learned.net)
    tiers = {"learned": calibrated, "physics": PhysicsPredictor(model.constants)}
    scores, diagrams = score_tiers([load_bundle(name, root=root) for name in val_datasets], tiers)
    model = model.model_copy(update={"scores": scores, "reliability": diagrams})  # the old ones scored another calibration
    with atomic_directory(out, marker=MODEL_JSON, what="learned predictor") as tmp:
        shutil.copyfile(predictor / WEIGHTS, tmp / WEIGHTS)
        (tmp / MODEL_JSON).write_text(model.model_dump_json(indent=2) + "\n")
        (tmp / MODEL_CARD).write_text(model_card(model, command_line()))
    load_learned(out)  # the weights still the ones model.json names
    print_scores(scores, list(tiers))
    users = sum(len(m.users) for m in maps)
    say(
        f"wrote {out}: dead logit calibrated x {scale:.3f} {bias:+.3f} on {users} users of {len(maps)} packs in "
        f"{time.perf_counter() - t0:.0f} s",
    )


@click.command("trace-predictor")
@calibration_maps_option(
    "of training cities: the ray-traced tier's spread and dead probabilities are calibrated on the first --users "
    "users of each selected pack."
)
@packs_option
@click.option(
    "--users",
    "users_per_pack",
    type=click.IntRange(1, 64),
    default=4,
    show_default=True,
    help="Users of each pack the calibration traces.",
)
@model_options(
    RayTracedModel,
    "samples",
    "device",
    "seed",
    "walk_reach_m",
    "fallback",
    "spread_cells",
    "spread_estimator",
    names={"walk_reach_m": "--walk-reach"},
    samples={"type": click.FloatRange(1e3, 1e8), "default": 1e5, "show_default": True},
)
@learned_validation_option
@click.option(
    "--workers",
    type=click.IntRange(1, 64),
    default=1,
    show_default=True,
    help="Ray tasks the users are traced in, on a local Ray of that many CPUs (the maps are the same whatever the number).",
)
@constants_option("that predicts the cells no ray reached")
@path_option(
    "--out",
    folder=True,
    default=Path("runs/predictor/raytraced"),
    help="Folder of the tier's model.json (replaced whole, or left as it was); `uavrl report --predictor` takes it.",
)
@root_option
def trace_predictor(
    map_folders: tuple[Path, ...],
    packs: tuple[str, ...],
    users_per_pack: int,
    samples: float,
    device: str,
    seed: int,
    walk_reach_m: float,
    fallback: str,
    spread_cells: str,
    spread_estimator: str,
    val_datasets: tuple[str, ...],
    workers: int,
    constants: Path,
    out: Path,
    root: Path,
) -> None:
    """Make the ray-traced tier of the map searcher's predictor (rl/predictor/raytraced.py: Sionna RT over the
    city's public 3D map, one generic material): calibrate its spread and dead-cell probability on training-maps
    packs, score it and the physics tier on validation cities' users, and write its model card. Needs the raytrace
    extra (pip install -e '.[raytrace]'; on a CPU also libllvm19)."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.dataset.trainmaps import read_pack, select_packs
    from uavplace.infra.console import command_line
    from uavplace.infra.files import atomic_directory, check_output_folder
    from uavplace.rl.predictor import MODEL_JSON, PhysicsPredictor, Scene, load_constants
    from uavplace.rl.predictor.raytraced import RayTracedPredictor, calibrate
    from uavplace.rl.predictor.scores import score_tiers
    from uavplace.simulate.raytrace import mitsuba_variant, require_raytrace

    try:
        require_raytrace()
        mitsuba_variant(device)
    except (RuntimeError, ValueError) as err:
        raise click.UsageError(str(err)) from None
    check_output_folder(out, MODEL_JSON, "ray-traced predictor", (MODEL_JSON,))
    paths = select_packs(map_folders, packs)
    if not paths:
        raise no_pack_matched(map_folders, packs)
    maps = [read_pack(p) for p in paths]
    overlap = sorted({m.city for m in maps} & set(val_datasets))
    if overlap:
        raise click.BadParameter(f"{', '.join(overlap)}: a validation city is also a calibration city", param_hint="--maps")
    model = RayTracedModel(
        constants=load_constants(constants),
        samples=int(samples),
        device=device,
        seed=seed,
        walk_reach_m=walk_reach_m,
        fallback=fallback,
        spread_cells=spread_cells,
        spread_estimator=spread_estimator,
    )
    if workers > 1:
        from uavplace.infra.cluster import start_ray

        start_ray(None, 1.0, "--workers", num_cpus=workers)
    t0 = time.perf_counter()
    rows: dict[str, list] = {"traced": [], "fallback": [], "measured": [], "low": []}
    for i, m in enumerate(maps):
        scene = Scene.from_settings(m.settings, m.height_rel_m)
        cells = np.argwhere(~m.blocked)
        users = m.users[:users_per_pack]
        predictor = RayTracedPredictor(model, workers)
        traced = predictor.traced_sinr(scene, users)[:, cells[:, 0], cells[:, 1]]
        rows["fallback"].append(predictor.fallback.predict(scene, users, cells)[0].ravel())
        sinr = m.sinr_db[: len(users), cells[:, 0], cells[:, 1]]
        dead = m.dead[: len(users), cells[:, 0], cells[:, 1]]
        rows["traced"].append(traced.ravel())
        rows["measured"].append(sinr.ravel())
        rows["low"].append((dead | (sinr <= scene.floor_db + 1e-3)).ravel())
        done = f"trace-predictor: {m.city} traced ({i + 1}/{len(maps)}, {time.perf_counter() - t0:.0f} s)"
        stdout().print(done, highlight=False, markup=False, soft_wrap=True)  # a line a pack, terminal or log
    try:
        model = calibrate(model, *(np.concatenate(rows[k]) for k in ("traced", "fallback", "measured", "low")))
    except ValueError as err:
        raise click.BadParameter(f"{err}: give packs of cities with dead cells, or more --users", param_hint="--maps") from None
    model = model.model_copy(
        update={
            "calibrated_on": [f"{m.city}@{m.version}" for m in maps],
            "calibration_users": sum(min(users_per_pack, len(m.users)) for m in maps),
            "made_by": [command_line()],
        }
    )
    tiers = {"raytraced": RayTracedPredictor(model, workers), "physics": PhysicsPredictor(model.constants)}
    scores, _ = score_tiers([load_bundle(name, root=root) for name in val_datasets], tiers)
    model = model.model_copy(update={"scores": scores})
    with atomic_directory(out, marker=MODEL_JSON, what="ray-traced predictor") as tmp:
        (tmp / MODEL_JSON).write_text(model.model_dump_json(indent=2) + "\n")
    print_scores(scores, list(tiers))
    say(
        f"wrote {out}: calibrated on {model.calibration_users} users of {len(maps)} packs in "
        f"{time.perf_counter() - t0:.0f} s at {model.samples:g} rays; spread {model.error_db:.1f} dB, dead at "
        f"{model.dead_level_db:.1f} dB (width {model.dead_scale_db:.1f} dB)",
    )

"""``uavrl datasets``, ``baselines`` and ``train``: agents on map bundles built by ``uavdata`` (registered in ``uavplace.cli``)."""

from __future__ import annotations

from pathlib import Path

import click

from uavplace.dataset.bundle import list_versions, read_latest
from uavplace.dataset.catalog import list_cities
from uavplace.infra.console import LogLines, fail, plain_table, root_option, say, stdout, warn_or_refuse
from uavplace.infra.options import model_options
from uavplace.rl.agent.config import PRESETS, DQNConfig
from uavplace.rl.config import EpisodeSettings
from uavplace.rl.tasks.registry import TASKS
from uavplace.rl.world.stats import STATS, format_stat, summarise


def task_option(help_text: str):  # noqa: ANN201 - a click decorator
    """``--task``: one of the registered tasks (``rl.tasks.registry.TASKS``), placement by default."""
    return click.option("--task", type=click.Choice(list(TASKS)), default="placement", show_default=True, help=help_text)


@click.command()
@root_option
def datasets(root: Path) -> None:
    """List the built cities under ROOT that agents can be given (`--dataset NAME`), from their latest bundle."""
    out = stdout()
    cities = list_cities(root)
    table = plain_table("dataset", "version", "grid [m]", "alt [m]", "cells", "users", "role", "train / val / test users")
    unbuilt = []
    for c in cities:
        latest = read_latest(c.name, root)
        m = next((m for m in list_versions(c.name, root) if m.version == latest), None)
        if m is None:
            unbuilt.append(c.name)
            continue
        s = m.split
        table.add_row(
            c.name,
            m.version,
            f"{m.grid.spacing_m:g}",
            f"{m.config.altitude_m:g}",
            f"{m.grid.num_x} x {m.grid.num_y}",
            str(m.num_users),
            m.config.role or "-",
            f"{s['train']} / {s['val']} / {s['test']}" if m.config.role else "-",
        )
    if table.row_count:
        out.print(table)
    else:
        out.print(f"no built city under {root}: run `uavdata ingest data/raw/<city>/` then `uavdata build`")
    if unbuilt:
        out.print(f"ingested but not built (run `uavdata build`): {', '.join(unbuilt)}")


#: The evaluation protocol's options, shared by ``baselines`` and ``report``: ``EpisodeSettings``'s fields.
episode_options = model_options(EpisodeSettings, "episodes", "t_max", "p_t_db", "split", "seed")


@click.command()
@click.option("--dataset", "datasets", multiple=True, required=True, help="Built city to play in (repeatable).")
@episode_options
@root_option
def baselines(
    datasets: tuple[str, ...], episodes: int, t_max: int, p_t_db: float, split: str | None, seed: int, root: Path
) -> None:
    """Play the genie, the steered random walk and greedy hill-climbing on the same episodes; print a table per city."""
    from rich.progress import Progress

    from uavplace.infra.limits import check_limit
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.policies import GeniePolicy, GreedyPolicy, RandomWalkPolicy
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.world.maps import MapSet

    check_limit("episode_steps", episodes * t_max, None, "--episodes x --t-max", field="episodes")
    config = EnvConfig(t_max=t_max, p_t_db=p_t_db, split=split, rotate=False)
    for dataset in datasets:  # one table per city: cities are never pooled
        maps = MapSet.load(dataset, config, root=str(root))
        eps = maps.episode_list(episodes, seed)
        title = f"{dataset}: {episodes} episodes, t_max {t_max}, P_T {p_t_db:g} dB" + (f", {split} users" if split else "")
        table = plain_table("method", *STATS.values(), title=title)
        table.columns[0].no_wrap = True  # the method's name whole; the statistics' headers wrap in a narrow terminal
        with Progress(console=stdout(), transient=True) as progress:
            for policy in (GeniePolicy(), RandomWalkPolicy(seed=seed), GreedyPolicy(config.p_h_db, seed=seed)):
                task = progress.add_task(f"{dataset} {policy.name}", total=episodes)
                df = run_episodes(maps, policy, eps, on_step=lambda d, t, task=task: progress.update(task, completed=d))
                s = summarise(df)
                table.add_row(policy.name, *(format_stat(k, s[k], t_max=t_max) for k in STATS))
        stdout().print(table)


#: The option names of ``uavrl train``'s settings that are not ``--field-name``.
_TRAIN_OPTIONS = {"total_steps": "--steps"}


@click.command()
@click.option(
    "--dataset",
    "datasets",
    multiple=True,
    help="Built city to train in, or a corpus name (NAME for the cities NAME-000, NAME-001...); repeatable. "
    "Cities built as val (`uavdata build --split CITY=val`) select the checkpoint instead; test cities are refused. "
    "Required unless --resume.",
)
@click.option(
    "--val-dataset",
    "val_datasets",
    multiple=True,
    help="Built city (or corpus) on which best.pt is selected, besides the val cities of --dataset (repeatable). "
    "Without any, the held-out val users of the training cities.",
)
@model_options(DQNConfig, "agent")
@click.option(
    "--preset",
    type=click.Choice(list(PRESETS)),
    default="best",
    show_default=True,
    help="Hyperparameters: best (ours: a recurrent Q-network learnt by PQN, 300 k steps), hybrid (best reading the map "
    "searcher's belief as a channel, env.belief_channel; docs/searcher.md), best-pqn (best without the recurrent core), "
    "best-dqn (that one learnt by replay DQN), paper (docs/method.md, about 7 M steps: days on a CPU), fast (40 k "
    "steps, for checks). Their settings: rl/agent/config.py, PRESETS; what each costs: the README, Training and reporting.",
)
@task_option(DQNConfig.model_fields["task"].description)
@model_options(DQNConfig, "total_steps", names=_TRAIN_OPTIONS, unset={"total_steps": "the preset's"})
@click.option(
    "--set",
    "settings",
    multiple=True,
    metavar="FIELD=VALUE",
    help="Override one field of the preset's DQNConfig (rl/agent/config.py), env fields as env.FIELD "
    "(rl/tasks/placement/config.py, EnvConfig), "
    + ", ".join(
        f"the {t.name} task's as {t.settings.prefix}.FIELD ({t.settings.__module__}.{t.settings.__name__})"
        for t in TASKS.values()
        if t.settings.prefix
    )
    + ", e.g. --set env.shaping=1 --set eval_episodes=1000; repeatable.",
)
@model_options(DQNConfig, "seed", "eval_every", unset={"eval_every": "the preset's"})
@click.option(
    "--out",
    "runs",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("runs"),
    show_default=True,
    help="Folder of runs; this one goes to OUT/<run-id>/.",
)
@click.option(
    "--name", default=None, help="Run folder name under OUT (default: <time>-<preset>[-<task>]-<agent>-s<seed>); must be new."
)
@click.option(
    "--until",
    type=click.IntRange(min=1),
    default=None,
    help="Stop at this step (after its checkpoint) instead of the end; `--resume` continues the same schedule later.",
)
@click.option(
    "--resume",
    type=click.Path(file_okay=False, exists=True, path_type=Path),
    default=None,
    help="Continue the run in this folder exactly where its last checkpoint left it.",
)
@click.option(
    "--strict",
    is_flag=True,
    help="With --resume: refuse when a training city's bundle is now built with other settings (grid, altitude, "
    "noise) than the run was trained on (run.json's bundle_settings). Without it: one warning line per city.",
)
@root_option
@click.option("--quiet", is_flag=True, help="No progress bar.")
def train(
    datasets,
    val_datasets,
    preset: str,
    task: str,
    settings,
    runs: Path,
    name: str | None,
    until: int | None,
    resume: Path | None,
    strict: bool,
    root: Path,
    quiet: bool,
    **options: object,
) -> None:
    """Train the DQN agent (or its blind twin) on built cities, for any task (--task); write config, metrics and
    checkpoints to a run folder.

    \b
    Its progress line (a bar on a terminal, a line every 30 s in a log):
      ep N          training episodes ended so far
      gain100       mean SINR gain (last SINR - first) of the last 100 training episodes [dB]
      success100    share of the last 100 training episodes that reached P_T
      eps           the exploration rate now (a random legal move's probability)
      loss          mean training loss of the last updates ('-': no update yet)
      best eval     success of the best evaluation so far on the validation users ('-': none yet)
    """
    from uavplace.dataset.catalog import expand_datasets
    from uavplace.infra.files import check_name, exclusive_folder
    from uavplace.rl.agent.config import parse_settings, preset_config
    from uavplace.rl.agent.runs import new_run_dir, read_run_json
    from uavplace.schemas import InputError

    if resume is not None:
        doc = read_run_json(resume)
        config, datasets, val_datasets, run_dir = doc.config, list(doc.datasets), list(doc.val_datasets), resume
        _check_resumed_bundles(doc, datasets, root, strict)
    elif not datasets:
        raise click.UsageError("give --dataset CITY (or --resume RUN_FOLDER)")
    else:
        named = runs / check_name(name, "run name") if name else None
        datasets, val_datasets = expand_datasets(datasets, root), expand_datasets(val_datasets, root)
        given = parse_settings(settings)
        # settings with their own option: the option would win over the --set without a word (--agent, --task and
        # --seed always, with their defaults; --steps and --eval-every when given)
        chosen = {k: v for k, v in options.items() if v is not None} | {"task": task}
        clash = [f"--set {k} and {_TRAIN_OPTIONS.get(k, '--' + k.replace('_', '-'))}" for k in given if k in chosen]
        if clash:
            raise click.UsageError(f"{', '.join(clash)} set the same field: give it once, with the option")
        config = preset_config(preset, **given, **chosen)
        run_dir = named or new_run_dir(runs, config)
    # The run folder is held for the whole training: a second command on it (the same --name a second later, or a
    # second --resume) is refused at once, and a new run's folder is claimed before any work.
    try:
        with exclusive_folder(run_dir, "training run"):
            _train_in(run_dir, resume, config, datasets, val_datasets, root, until, quiet)
    except InputError as err:
        fail(err)


def _check_resumed_bundles(doc, datasets: list[str], root: Path, strict: bool) -> None:  # noqa: ANN001 - a RunRecord
    """The training cities' bundles a resumed run reads now, against the settings it was trained on: one warning
    line per city that differs, or a refusal with ``--strict``."""
    from uavplace.dataset.bundle import read_manifest, resolve
    from uavplace.rl.agent.runs import settings_unlike

    lines = []
    for city in datasets:
        manifest = read_manifest(resolve(city, root=root))
        unlike = settings_unlike(doc, manifest)
        if unlike:
            lines.append(f"{city}@{manifest.version}: {'; '.join(unlike)}: the run continues on other maps")
    warn_or_refuse(lines, strict)


def _train_in(run_dir: Path, resume, config, datasets, val_datasets, root: Path, until: int | None, quiet: bool) -> None:  # noqa: ANN001
    """``uavrl train``'s work, with ``run_dir``'s lock held."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from uavplace.infra.console import command_line
    from uavplace.rl.agent.resume import Interrupted
    from uavplace.rl.agent.train import start_run

    try:
        trainer = start_run(run_dir, config, datasets, val_datasets, root, resume=resume is not None, command=command_line())
    except FileExistsError as err:
        fail(err)
    columns = (
        TextColumn("[bold]train[/] {task.description}"),
        BarColumn(),
        TextColumn("{task.completed:,}/{task.total:,}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    log = LogLines(quiet)  # a log: a plain line every LINE_SECONDS instead of a bar
    with Progress(*columns, console=stdout(), disable=quiet or log.enabled) as bar:
        task = bar.add_task(run_dir.name, total=config.total_steps)

        def on_progress(p) -> None:
            best = "-" if p.best is None else f"{100 * p.best:.0f} %"
            text = (
                f"ep {p.episodes} gain100 {p.gain_mean100:.1f} dB success100 {100 * p.success100:.0f} % "
                f"eps {p.epsilon:.2f} loss {'-' if p.loss != p.loss else f'{p.loss:.3f}'} best eval {best}"
            )
            bar.update(task, completed=p.step, description=text)
            log(f"train {run_dir.name}: step {p.step:,}/{config.total_steps:,} {text}", last=p.step >= config.total_steps)

        try:
            trainer.run(resume=resume is not None, on_progress=on_progress, stop_at=until)
        except Interrupted as stop:
            bar.stop()
            say(str(stop))
            raise SystemExit(130) from None  # the shell's status for Ctrl-C
    last = trainer.state.evals[-1] if trainer.state.evals else None
    summary = f"; last evaluation: {trainer.learning.describe(last)}" if last else ""
    say(f"trained {run_dir}{summary}")


@click.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="The ensemble's folder (new): run.json, checkpoints/best.pt, eval.parquet, metrics.parquet, as a run's; "
    "`uavrl report --run OUT` plays it.",
)
@root_option
@click.option("--quiet", is_flag=True, help="No progress bar.")
def ensemble(runs: tuple[Path, ...], out: Path, root: Path, quiet: bool) -> None:
    """Finished training RUNS (two or more folders of `uavrl train`, one config, different seeds) as one agent: the
    mean of their Q values, each network with its own recurrent state (rl/agent/ensemble.py). It is evaluated as a run
    is, on the members' validation cities (their config's eval_episodes, seeded as a run's), never on a test city."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from uavplace.infra.console import command_line
    from uavplace.rl.agent.ensemble import build_ensemble

    columns = (
        TextColumn("[bold]ensemble[/] validation"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("episodes"),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=stdout(), disable=quiet) as bar:
        task = bar.add_task("validation", total=None)
        row = build_ensemble(
            list(runs),
            out,
            root,
            command=command_line(),
            on_progress=lambda done, total: bar.update(task, completed=done, total=total),
        )
    say(
        f"wrote {out}: {len(runs)} runs; validation {100 * row['success']:.1f} % success, median {row['median_steps']:g} steps",
    )

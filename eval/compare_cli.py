"""The commands that compare runs on the validation cities: ``uavrl sweep`` (Ray Tune trials, then their table),
``uavrl levers`` (the lever table of any runs) and ``uavrl peer`` (Stable-Baselines3's agents beside a ``best`` run);
registered in ``uavplace.cli``."""

from __future__ import annotations

from pathlib import Path

import click

from uavplace.eval.config import PeerConfig
from uavplace.infra.console import (
    Finite,
    command_line,
    fail,
    markdown_table,
    path_option,
    ray_address_option,
    root_option,
    stdout,
)
from uavplace.infra.files import shipped
from uavplace.infra.options import model_options
from uavplace.rl.config import EpisodeSettings


@click.command()
@click.argument("spec_file", metavar="SPEC", type=click.Path(dir_okay=False, exists=True, path_type=Path))
@path_option(
    "--out",
    folder=True,
    help="Folder of the sweep's runs and table  [default: runs/<SPEC's name without .toml>]",
)
@ray_address_option("the trials")
@click.option(
    "--cpus-per-trial",
    type=Finite(min=1),
    default=1.0,
    show_default=True,
    help="CPUs each trial reserves, and its torch threads: trials run side by side on what the machine has.",
)
@click.option("--table-only", is_flag=True, help="Train nothing: only play the finished runs and write the table.")
@root_option
@click.option("--quiet", is_flag=True, help="No progress bar for the table's evaluation.")
def sweep(
    spec_file: Path, out: Path | None, ray_address: str | None, cpus_per_trial: float, table_only: bool, root: Path, quiet: bool
) -> None:
    """Train the runs of a sweep file SPEC on Ray Tune, then compare them on the validation cities.

    \b
    SPEC is a TOML file (eval/sweep.py, SweepSpec), e.g. experiments/sweeps/best.toml:
      datasets = ["corpus", "oldtown", "train"]
      [[trials]]                       # runs OUT/best-s0, OUT/best-s1, ...
      name = "best"
      preset = "best"
      seeds = [0, 1, 2]
      settings = {"env.shaping" = 1}   # as uavrl train --set
      [[ensembles]]
      name = "best-e012"
      members = ["best-s0", "best-s1", "best-s2"]
    Each trial is a run folder of `uavrl train`; running the same command again continues the
    unfinished ones and skips the finished. The table (OUT/sweep.md, OUT/sweep.csv) plays every
    run and ensemble on 1000 episodes of each validation city, with the genie, as `uavrl report`
    plays them; test cities are never used.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from uavplace.eval.sweep import check_held_out, read_spec, run_sweep, validation_table, write_table
    from uavplace.schemas import InputError

    out = out or Path("runs") / spec_file.stem
    say = stdout()
    try:
        spec = read_spec(spec_file)
        check_held_out(spec, spec_file, root)
        if not table_only:
            failed = run_sweep(
                spec,
                out,
                root=root,
                address=ray_address,
                cpus_per_trial=cpus_per_trial,
                command=command_line(),
                on_line=lambda line: say.print(line, highlight=False, markup=False),
            )
            if failed:
                fail(f"{len(failed)} trial(s) failed: {', '.join(failed)}; run the command again to continue them")
        folders = [out / name for name in (*spec.run_names(), *(e.name for e in spec.ensembles))]
        missing = [f.name for f in folders if not (f / "checkpoints" / "best.pt").is_file()]
        if missing:
            fail(f"not trained yet: {', '.join(missing)} (run the sweep without --table-only)")
        columns = (TextColumn("[bold]sweep[/] {task.description:<24}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
        with Progress(*columns, console=say, disable=quiet, transient=True) as bar:
            tasks: dict[str, int] = {}

            def on_progress(method: str, done: int, total: int) -> None:
                if method not in tasks:
                    tasks[method] = bar.add_task(method, total=total)
                bar.update(tasks[method], completed=done)

            table = validation_table(
                folders, list(spec.cities), root=root, episodes=spec.episodes, seed=spec.seed, on_progress=on_progress
            )
    except InputError as err:
        fail(err)
    except RuntimeError as err:  # Ray Tune missing
        fail(err)
    path = write_table(table, out, spec_file)
    say.print(path.read_text(encoding="utf-8"), highlight=False, markup=False, soft_wrap=True)
    say.print(f"table: {path} (and sweep.csv); the spec: {out / 'sweep.toml'}", highlight=False, soft_wrap=True)


def validation_options(command):  # noqa: ANN001, ANN201 - a click command
    """``--city`` (default: every built validation city), ``--episodes`` and ``--seed``: the options of the commands
    that compare runs on the validation cities (``levers``, ``peer table``)."""
    options = (
        click.option("--city", "cities", multiple=True, help="City to play (repeatable; default: every built validation city)."),
        model_options(EpisodeSettings, "episodes", "seed"),
    )
    for option in reversed(options):
        command = option(command)
    return command


@click.command()
@click.argument("runs", nargs=-1, required=True, type=click.Path(file_okay=False, exists=True, path_type=Path))
@validation_options
@path_option(
    "--against",
    folder=True,
    help="One of RUNS: every other run's success and median steps minus its, paired on the same episodes, per city and "
    "for the cities pooled, with 95 % intervals over users then episodes (whether a change is more than the noise).",
)
@click.option("--release", is_flag=True, help="Allow test cities (release numbers only, never to choose).")
@root_option
def levers(
    runs: tuple[Path, ...], cities: tuple[str, ...], episodes: int, seed: int, against: Path | None, release: bool, root: Path
) -> None:
    """The lever table of run or ensemble folders RUNS: each one's settings that differ from its preset, the evaluation
    that chose its best.pt, then best.pt on the episodes `uavrl report` draws in each validation city, with the genie
    (success and median steps with 95 % intervals over users then episodes, the ratio to the genie's median, the run's
    wall time): the table `uavrl sweep` ends with, for any runs (eval/sweep.py, validation_table)."""
    from uavplace.eval.render import difference_rows
    from uavplace.eval.reports.base import check_runs_once
    from uavplace.eval.sweep import markdown, paired_differences, validation_table
    from uavplace.schemas import InputError

    check_runs_once(list(runs), "RUNS")  # each a method of the table: a run twice would be two methods of one name
    if against is not None and against.name not in {r.name for r in runs}:
        raise click.UsageError(f"--against {against}: not one of RUNS")
    played: dict = {}
    try:
        table = validation_table(
            list(runs), list(cities) or None, root=root, episodes=episodes, seed=seed, release=release, played=played
        )
    except InputError as err:
        fail(err)
    click.echo(markdown(table), nl=False)
    if against is not None:
        for city, diffs in paired_differences(played, against.name, seed).items():
            click.echo(f"\n{city}: paired differences (95 % intervals over users, then episodes)\n")
            click.echo(markdown_table(difference_rows(diffs, 500)))


@click.group()
def peer() -> None:
    """A peer on the same env: Stable-Baselines3's DQN or PPO (CnnPolicy) trained on the shipped agents' cities and
    played beside a `best` run (eval/peer.py, docs/peer.md; needs the extra `peer`: pip install -e '.[peer]')."""


@peer.command(name="train")
@click.argument("algo", type=click.Choice(["dqn", "ppo"]))
@click.option(
    "--out", type=click.Path(file_okay=False, path_type=Path), required=True, help="The peer's folder (policy.pt, peer.json)."
)
@click.option(
    "--match",
    type=click.Path(file_okay=False, exists=True, path_type=Path),
    default=None,
    help="A finished `best` run whose wall time is the peer's budget of CPU seconds (of this process, on the threads "
    "OMP_NUM_THREADS allows).",
)
@model_options(PeerConfig, "cpu_seconds", "max_steps")
@click.option(
    "--dataset",
    "datasets",
    multiple=True,
    help="Training city or corpus (repeatable): their training users, as a `best` run's. Default: the shipped best "
    "agent's training cities (data/agents/best/run.json).",
)
@model_options(PeerConfig, "n_envs", "seed")
@root_option
def peer_train(
    algo: str,
    out: Path,
    match: Path | None,
    cpu_seconds: float | None,
    max_steps: int,
    datasets: tuple[str, ...],
    n_envs: int,
    seed: int,
    root: Path,
) -> None:
    """Train one SB3 algorithm ALGO (dqn or ppo) until its CPU budget or --max-steps is spent, on one torch thread
    (OMP_NUM_THREADS=N for more); the weights are saved weights-only (never SB3's pickled zip)."""
    from uavplace.dataset.catalog import expand_datasets
    from uavplace.eval.peer import run_wall_seconds, train_sb3, training_maps
    from uavplace.rl.agent.runs import read_run_json
    from uavplace.schemas import InputError

    if (match is None) == (cpu_seconds is None):
        raise click.UsageError("give --match RUN or --cpu-seconds S")
    import os

    import torch

    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))  # one thread unless told otherwise
    try:
        budget = cpu_seconds if cpu_seconds is not None else run_wall_seconds(match)
        if not datasets:  # the shipped best's cities, as its record names them
            datasets = tuple(read_run_json(shipped("data/agents/best")).datasets)
        maps = training_maps(expand_datasets(list(datasets), root), root)
        record = train_sb3(
            algo,
            maps,
            out,
            cpu_seconds=budget,
            max_steps=max_steps,
            n_envs=n_envs,
            seed=seed,
            on_progress=lambda step, cpu: click.echo(f"{algo}: step {step:,}, {cpu:.0f} CPU s"),
        )
    except (InputError, RuntimeError) as err:
        fail(err)
    click.echo(
        f"{algo}: {record['steps']:,} steps in {record['cpu_seconds']:.0f} CPU s ({record['wall_seconds']:.0f} s wall) -> {out}"
    )


@peer.command(name="table")
@click.option(
    "--best",
    type=click.Path(file_okay=False, exists=True, path_type=Path),
    required=True,
    help="The `best` run (or ensemble) to compare with.",
)
@click.option(
    "--peer",
    "peers",
    multiple=True,
    required=True,
    type=click.Path(file_okay=False, exists=True, path_type=Path),
    help="A peer folder of `uavrl peer train` (repeatable).",
)
@validation_options
@path_option(
    "--markdown",
    "markdown_path",
    folder=False,
    help="Also write the table there (Markdown).",
)
@root_option
def peer_table(
    best: Path, peers: tuple[Path, ...], cities: tuple[str, ...], episodes: int, seed: int, markdown_path: Path | None, root: Path
) -> None:
    """The `best` run, the peers and the genie on the same episodes of each validation city: success and median steps
    with 95 % intervals over users then episodes, and the ratios best / peer (success) and peer / best (median steps).
    Test cities are refused."""
    from uavplace.eval.cities import development_cities
    from uavplace.eval.peer import peer_table as table
    from uavplace.infra.files import atomic_write_text
    from uavplace.schemas import InputError

    try:
        text = markdown_table(table(best, list(peers), development_cities(list(cities) or None, root), root, episodes, seed))
        if markdown_path is not None:
            atomic_write_text(markdown_path, text + "\n")
    except (InputError, RuntimeError) as err:
        fail(err)
    click.echo(text)

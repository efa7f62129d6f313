"""``uavrl report``: added here to the ``uavrl`` command group of ``rl.cli`` (eval imports rl, never the reverse)."""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Table

from dataset.cli import command_line, plain_table, root_option, stdout
from rl.cli import episode_options, main

__all__ = ["main"]


@main.command()
@click.option(
    "--run",
    "runs",
    multiple=True,
    type=click.Path(file_okay=False, exists=True, path_type=Path),
    help="Agent to evaluate: a run folder of `uavrl train` or a shipped agent (repeatable). "
    "Default: every agent under data/agents/.",
)
@click.option(
    "--dataset",
    "datasets",
    multiple=True,
    default=("test",),
    show_default=True,
    help="Test city: a built dataset never used in training or checkpoint selection (repeatable: one report per city).",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Report folder (with several --dataset: the folder that holds one per city); an existing report folder "
    "is replaced only if it is a report (holds report.json), anything else is refused.  [default: reports/<dataset>]",
)
@episode_options
@click.option(
    "--test-epsilon",
    type=click.FloatRange(0, 1),
    default=0.096,
    show_default=True,
    help="Probability of a random legal move of the agents (paper: 0.096).",
)
@click.option(
    "--bootstrap",
    "n_boot",
    type=click.IntRange(min=100),
    default=2000,
    show_default=True,
    help="Bootstrap resamples of the 95 % intervals.",
)
@click.option(
    "--trajectories", type=click.IntRange(min=0), default=3, show_default=True, help="Successful episodes drawn (first agent)."
)
@click.option("--agents-dir", type=click.Path(file_okay=False, path_type=Path), default=Path("data/agents"), show_default=True,
              help="Where the default agents are looked for.")  # fmt: skip
@root_option
@click.option("--quiet", is_flag=True, help="No progress bar.")
def report(
    runs: tuple[Path, ...], datasets: tuple[str, ...], out: Path | None, episodes: int, t_max: int, p_t_db: float, test_epsilon: float,
    n_boot: int, trajectories: int, split: str | None, seed: int, agents_dir: Path, root: Path, quiet: bool,
) -> None:  # fmt: skip
    """Evaluate agents and baselines on the same episodes of a test city; write an HTML report, PNGs, CSV and Parquet.

    Methods: every agent, the genie (shortest path, full knowledge), the steered random walk and greedy
    hill-climbing. Prints the results table (95 % bootstrap intervals in brackets) and the report's path;
    with several cities, one report each, then a summary of success and median steps per method and city.
    """
    from eval.metrics import format_stat
    from eval.report import ReportConfig, default_agents, table_rows

    chosen = list(runs) or default_agents(agents_dir)
    summary: dict[str, dict[str, str]] = {}
    for dataset in datasets:
        config = ReportConfig(
            dataset=dataset, runs=[str(r) for r in chosen], episodes=episodes, t_max=t_max, p_t_db=p_t_db,
            test_epsilon=test_epsilon, seed=seed, n_boot=n_boot, trajectories=trajectories, split=split,
        )  # fmt: skip
        city = dataset.split("@")[0]
        folder = out if out and len(datasets) == 1 else (out or Path("reports")) / city
        result = _one_report(config, folder, root, quiet)
        rows = table_rows(result.table, t_max)
        table = Table(*rows[0], title=f"{episodes} episodes in {dataset} (t_max {t_max}, P_T {p_t_db:g} dB)")
        for r in rows[1:]:
            table.add_row(*r)
        for r in result.table.to_dict("records"):
            cell = " / ".join(format_stat(s, r[s]) for s in ("success", "median_steps"))
            summary.setdefault(r["method"], {})[city] = cell.replace("> t_max", f"> {t_max}")
        stdout().print(table)
        stdout().print(f"report: {result.out / 'report.html'}", highlight=False, soft_wrap=True)
    if len(datasets) > 1:
        cities = [d.split("@")[0] for d in datasets]
        table = plain_table("method", *(f"{c}: success / median steps" for c in cities))
        for method, cells in summary.items():
            table.add_row(method, *(cells.get(c, "-") for c in cities))
        stdout().print(table)


def _one_report(config, out: Path, root: Path, quiet: bool):
    """``make_report`` with a progress bar per method."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from eval.report import make_report

    tasks: dict[str, int] = {}
    columns = (TextColumn("[bold]report[/] {task.description:<20}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=stdout(), disable=quiet) as bar:

        def on_progress(method: str, done: int, total: int) -> None:
            if method not in tasks:
                tasks[method] = bar.add_task(f"{config.dataset} {method}", total=total)
            bar.update(tasks[method], completed=done)

        return make_report(config, out, root=root, command=command_line(), on_progress=on_progress)

"""``uavrl report`` of the placement task: one report folder per city (``eval.report.make_report``), then the page of
every city and the summary."""

from __future__ import annotations

import contextlib
from pathlib import Path

import click

from uavplace.eval.config import ReportConfig
from uavplace.eval.reports.base import ReportRequest, TaskReport, check_runs_once, check_training_settings, print_table
from uavplace.infra.console import LogLines, command_line, console, plain_table, say, stdout

#: The columns of a report's table that a terminal shows (they fit 120 columns).
TERMINAL_COLUMNS = ("method", "success", "median steps", "median of per-episode steps / genie")


def play(request: ReportRequest, after: contextlib.ExitStack) -> None:
    """One report folder per city, then the page of every city (several cities) and the Markdown tables."""
    from uavplace.eval.evaluate import check_unseen_runs, default_agents
    from uavplace.eval.render import check_summary_page, summary_rows, write_summary_page

    datasets, out, t_max = request.datasets, request.out, request.t_max
    chosen = list(request.runs) or default_agents(request.agents_dir, "placement")
    check_runs_once(chosen, "--run")
    grouped = groups(request.groups, chosen)
    check_runs_once(chosen, "--run and --group")
    checking = f"checking {len(chosen)} agents against {len(datasets)} cities"
    with contextlib.nullcontext() if request.quiet else console.status(checking):
        check_unseen_runs(chosen, list(datasets), request.root)  # every city before the first city's report
        check_training_settings(chosen, request)
    if len(datasets) > 1:
        check_summary_page(out or Path("reports"))
    folders = {d: out if out and len(datasets) == 1 else (out or Path("reports")) / d.split("@")[0] for d in datasets}
    if not request.overwrite:
        for folder in folders.values():
            check_same_agents(folder, chosen)
    parallel = request.joined_ray(after)
    settings = ReportConfig(
        dataset=datasets[0],
        t_max=t_max,
        p_t_db=request.p_t_db,
        split=request.split,
        groups=grouped,
        trajectories=request.trajectories,
        **request.shared_settings(chosen),
    )
    reports = []
    for number, dataset in enumerate(datasets, 1):
        config = settings.model_copy(update={"dataset": dataset})
        result = one_report(config, folders[dataset], request, (number, len(datasets)), parallel)
        reports.append(result)
        print_city(result, f"{request.episodes} episodes in {dataset} (t_max {t_max}, P_T {request.p_t_db:g} dB)", dataset)
    top = None  # several cities: the page's findings, which the Markdown leads with too
    if len(datasets) > 1:
        print_table(summary_rows(reports, t_max), "success / median steps per method and city")
        page, top = write_summary_page(reports, out or Path("reports"), t_max)
        say(f"report (every city): {page}")
    if request.markdown is not None:
        from uavplace.eval.render import markdown_tables
        from uavplace.infra.files import atomic_write_text

        atomic_write_text(request.markdown, markdown_tables(reports, t_max, top))
        say(f"tables (Markdown): {request.markdown}")


def groups(texts: tuple[str, ...], chosen: list[Path]) -> dict[str, list[str]]:
    """``--group NAME=RUN,RUN,...`` values as ``{name: [run, ...]}``; each group's runs not yet among ``chosen`` are
    added to it (they are played alone too)."""
    grouped: dict[str, list[str]] = {}
    for text in texts:
        name, _, members = text.partition("=")
        folders = [m for m in members.split(",") if m]
        if not name or not folders:
            raise click.UsageError(f"--group {text!r}: expected NAME=RUN,RUN,...")
        if name in grouped:
            raise click.UsageError(f"--group {name} is given twice: one group of each name")
        if name in method_names():
            raise click.UsageError(f"--group {name}: the name of a method of the report; call the group otherwise")
        check_runs_once([Path(f) for f in folders], f"--group {name}")
        grouped[name] = [str(Path(f)) for f in folders]
        chosen += [Path(f) for f in folders if Path(f).resolve() not in {c.resolve() for c in chosen}]
    return grouped


def method_names() -> set[str]:
    """The names of the report's methods other than agents (a group may not take one)."""
    from uavplace.rl.tasks.placement.policies import GeniePolicy, GreedyPolicy, RandomWalkPolicy
    from uavplace.rl.tasks.placement.searcher import SEARCHER

    return {GeniePolicy.name, RandomWalkPolicy.name, GreedyPolicy.name, SEARCHER, "oracle"}


def check_same_agents(folder: Path, runs: list[Path]) -> None:
    """Refuse to replace a report folder that holds a report of other agents (``--overwrite`` replaces it)."""
    import json

    from uavplace.infra.files import read_small_file
    from uavplace.schemas import InputError

    record = folder / "report.json"
    if not record.is_file():
        return
    try:
        held = json.loads(read_small_file(record, "a report's record"))["report_config"]["runs"]
    except (InputError, ValueError, KeyError, TypeError):
        return  # not a report this uavplace reads: check_replaceable decides
    if sorted(str(Path(r).resolve()) for r in held) != sorted(str(r.resolve()) for r in runs):
        names = ", ".join(Path(r).name for r in held) or "no agent"
        raise click.UsageError(
            f"{folder} holds a report of other agents ({names}): give another --out, or --overwrite to replace it"
        )


def terminal_columns(rows: list[list[str]]) -> list[list[str]]:
    """``rows`` (header first) with only ``TERMINAL_COLUMNS``."""
    keep = [i for i, name in enumerate(rows[0]) if name in TERMINAL_COLUMNS]
    return [[r[i] for i in keep] for r in rows]


def print_city(result, title: str, dataset: str) -> None:  # noqa: ANN001 - a ReportResult
    """A city's tables as the report printed them: the results (a terminal gets the columns that fit; the full table
    is in the report and --markdown), the paired differences and the groups of runs."""
    rows = result.rows
    if stdout().is_terminal:
        rows = terminal_columns(rows)
        title += f"; every column: {result.out / 'report.html'}"
    stdout().print(plain_table(*rows[0], rows=rows[1:], title=title))
    titles = (
        (result.diff_rows, f"paired differences in {dataset}, method minus reference, 95 % intervals"),
        (result.group_rows, f"groups of runs in {dataset}: mean over runs [interval over runs, users, episodes] (runs' range)"),
    )
    for table, caption in titles:
        if table is not None and len(table) > 1:
            stdout().print(plain_table(*table[0], rows=table[1:], title=caption))
    say(f"report: {result.out / 'report.html'}")


def one_report(config: ReportConfig, out: Path, request: ReportRequest, city: tuple[int, int], parallel: bool):  # noqa: ANN201
    """``make_report`` with a progress bar per method (and stage: a searcher's predicted maps), named by the city's
    place among the report's (``city``: its number and the count) and the method's number."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from uavplace.eval.report import make_report

    tasks: dict[str, int] = {}
    plan: list[str] = []  # every stage of the city's evaluation, in order (make_report's on_plan)
    # no time-remaining column: the last episodes of a batch are its longest, so a rate-based ETA sat at 1 s for minutes
    columns = (TextColumn("[bold]report[/] {task.description:<20}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    log = LogLines(request.quiet)  # a log: a plain line every LINE_SECONDS (and at each method's start and end), not a bar
    with Progress(*columns, console=stdout(), disable=request.quiet or log.enabled) as bar:
        where = f"city {city[0]} of {city[1]}: {config.dataset}"
        loading = bar.add_task(f"{where}: loading", total=None)

        def on_status(text: str) -> None:  # what is loaded before the first stage, from the first second
            bar.update(loading, description=f"{where}: {text}")
            log(f"report {where}: {text}", last=True)

        def on_plan(stages: list[str]) -> None:  # everything is loaded: the stages begin
            plan.extend(stages)
            bar.remove_task(loading)

        def on_progress(stage: str, done: int, total: int) -> None:
            new = stage not in tasks
            name = f"{where}, stage {plan.index(stage) + 1} of {len(plan)}: {stage}"
            if new:
                tasks[stage] = bar.add_task(name, total=total)
            bar.update(tasks[stage], completed=done)
            unit = "candidates" if stage.endswith("predicted maps") else "episodes"
            log(f"report {name} {done}/{total} {unit}", last=new or done >= total)

        return make_report(
            config,
            out,
            root=request.root,
            command=command_line(),
            on_progress=on_progress,
            on_plan=on_plan,
            on_status=on_status,
            parallel=parallel,
        )


REPORT = TaskReport(
    play=play,
    summary="the paper's task (a user who stays): every agent, the genie, the steered random walk, greedy hill-climbing and "
    "the map searcher with its ablation shown no building, a report folder per city (OUT defaults to reports/)",
    selects_users=True,
    config=ReportConfig,
    searcher="uavplace.rl.tasks.placement.searcher:MapSearchPolicy",
    sets=frozenset({"buildings"}),
)

"""``uavrl report``: the evaluation protocol and its HTML report (registered in ``uavplace.cli``)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
from pydantic import BaseModel

from uavplace.eval.config import FleetReportConfig, PeerConfig, ReportConfig, TrackingReportConfig
from uavplace.infra.cluster import start_ray
from uavplace.infra.console import (
    Finite,
    LogLines,
    command_line,
    console,
    fail,
    markdown_table,
    path_option,
    plain_table,
    ray_address_option,
    root_option,
    stdout,
    warn_or_refuse,
)
from uavplace.infra.files import exclusive_folder, shipped
from uavplace.infra.options import model_options, with_pairs
from uavplace.rl.cli import episode_options
from uavplace.rl.config import EpisodeSettings, SearchConfig
from uavplace.rl.tasks.fleet.config import FleetConfig
from uavplace.rl.tasks.registry import TASKS
from uavplace.rl.tasks.tracking.config import TrackingConfig
from uavplace.schemas.base import repeated


@click.command()
@click.option(
    "--run",
    "runs",
    multiple=True,
    type=click.Path(file_okay=False, exists=True, path_type=Path),
    help="Agent to evaluate: a run folder of `uavrl train` or a shipped agent (repeatable). "
    "Default: every agent under the project's data/agents/ (--agents-dir).",
)
@click.option(
    "--dataset",
    "datasets",
    multiple=True,
    help="Test city: a built dataset never used in training or checkpoint selection (repeatable: a report folder per "
    "city, and OUT/report.html with a summary table and a section per city)  [default: every built city of the test "
    "role (data/raw/cities.toml, or --split CITY=test): those without routes, or with routes for --task tracking].",
)
@path_option(
    "--out",
    folder=True,
    help="Report folder (with several --dataset: the folder that holds one per city); an existing report folder "
    "is replaced only if it is a report (holds report.json), anything else is refused.  [default: reports/<dataset>]",
)
@episode_options
@model_options(ReportConfig, "test_epsilon", "n_boot", "trajectories", names={"n_boot": "--bootstrap"})
@click.option(
    "--group",
    "groups",
    multiple=True,
    metavar="NAME=RUN,RUN,...",
    help="Report these runs (a preset's seeds, each also played alone) as one method NAME: the mean over its runs, "
    "the runs' range, and an interval that resamples runs, then users, then episodes; with paired differences against "
    "the blind paper agent and the genie (repeatable; groups.csv and a table in the report).",
)
@path_option(
    "--agents-dir",
    folder=True,
    default=shipped("data/agents"),
    help="Where the default agents are looked for (without --run: those of the report's task; a tracking "
    "report plays the placement agents too; a fleet report its 'best' on every UAV and the fleet-trained agents).",
)
@path_option(
    "--markdown",
    folder=False,
    help="Also write every table (each city's results and paired differences, then the summary) as Markdown to this "
    "file, for a README that cannot drift from what the command printed.",
)
@click.option(
    "--task",
    type=click.Choice(list(TASKS)),
    default="placement",
    show_default=True,
    help="placement: the paper's task (a user who stays); tracking: a user who moves along the routes of the cities "
    "(bundles simulated with --routes; rl/tasks/tracking/): the oracle, the agents (placement agents run unchanged), the "
    "re-planning genie and the baselines (eval/tracking.py; OUT defaults to reports/tracking); fleet: --uavs UAVs "
    "serve --users users at once (rl/tasks/fleet/): the oracle, the map searcher run for the fleet, the agents (--run; "
    "default: the shipped best and the fleet-trained agents under --agents-dir) run on every UAV on the users dealt "
    "to it, greedy hill-climbing and the random walk (eval/fleet.py; OUT defaults to reports/fleet).",
)
@model_options(FleetConfig, "uavs", "users")
@model_options(TrackingConfig, "horizon")
@model_options(TrackingReportConfig, "hold")
@click.option(
    "--predictor",
    default=str(shipped("data/agents/searcher/unet")),
    show_default=True,
    help="The map searcher's radio-map predictor (rl/tasks/placement/searcher.py): a learned tier's folder "
    "(`uavrl train-predictor`), the physics tier's constants (data/agents/searcher/predictor.json, `uavrl fit-predictor`), or 'none' "
    "to leave the searcher and its ablation out (with --task tracking, the tracking searcher, rl/tasks/tracking/searcher.py). Its "
    "predicted maps are cached under ROOT/.predictions/.",
)
@click.option(
    "--search",
    multiple=True,
    metavar="NAME=VALUE",
    help="A setting of the searcher the task plays (a field of SearchConfig, rl/config.py, where each is explained; "
    "repeatable), e.g. --search planner=info --search error_share=0.8: every other setting is the task's default "
    "(docs/searcher.md); one the task's searcher does not read is refused. Saved in the report's record.",
)
@click.option(
    "--overwrite",
    is_flag=True,
    help="Replace a report folder that holds a report of other agents (refused by default: `--run X` would otherwise "
    "write over the main job's reports/<city>/).",
)
@click.option(
    "--strict",
    is_flag=True,
    help="Refuse to play an agent on a bundle built with other settings (grid, altitude, noise) than its training "
    "cities' (run.json's bundle_settings), or at another P_T than it was trained at. Without it: one warning line "
    "for each such agent and city.",
)
@click.option(
    "--workers",
    type=click.IntRange(1),
    default=1,
    show_default=True,
    help="Placement: play each city's methods, in pieces of their episodes, as Ray tasks on this many CPUs of this "
    "machine (1: one after the other in this process, torch on every core: on 2 cores the faster, docs/benchmarks.md). "
    "The numbers are the same whatever it is (eval/parallel.py).",
)
@ray_address_option("the methods (with it, --workers is the cluster's CPUs)")
@root_option
@click.option("--quiet", is_flag=True, help="No progress bar.")
def report(**v: Any) -> None:
    """Evaluate agents and baselines on the same episodes of a test city; write an HTML report, PNGs, CSV and Parquet.

    Methods: every agent, the genie (shortest path, full knowledge), the steered random walk, greedy
    hill-climbing, and the map searcher with its ablation shown no building (--predictor). Prints the results table (95 % bootstrap intervals in brackets) and the report's path;
    with several cities, one report folder each, then a summary of success and median steps per method and city, and
    one page with every city (OUT/report.html, OUT/summary.csv; OUT defaults to reports/).

    With --task tracking, the user moves: the oracle (the upper bound), the agents (placement agents run unchanged),
    the re-planning genie, the tracking searcher (--predictor), the random walk and greedy hill-climbing on the same
    episodes of each city's routes, those
    without a stay action also holding their cell while covered (--hold); one
    page OUT/tracking.html with a table per city, the coverage over time and three episodes on the maps
    (eval/tracking.py).
    """
    from uavplace.dataset.bundle import resolve
    from uavplace.infra.files import check_replaceable_file
    from uavplace.infra.limits import check_limit

    task = TASK_REPORTS[v["task"]]
    cities = [d.split("@")[0] for d in v["datasets"]]
    twice = repeated(cities)
    if twice:  # one folder, table and summary row per city: two versions of one city would overwrite each other
        given = ", ".join(d for d in v["datasets"] if d.split("@")[0] in twice)
        raise click.UsageError(
            f"--dataset names {', '.join(twice)} more than once ({given}): one report per city; "
            "report each version with its own --out"
        )
    for dataset in v["datasets"]:  # a mistyped city is named, with the nearest ones, before anything heavy is loaded
        resolve(dataset, root=v["root"])
    v["search"] = task.search(v["search"])  # a setting refused before any city is loaded (its searcher imports torch)
    if v["markdown"] is not None:  # refused before any work: only a regular file or nothing is replaced
        check_replaceable_file(v["markdown"])
    if not v["datasets"]:  # the release's cities: those built with the test role
        from uavplace.eval.cities import release_cities

        v["datasets"] = tuple(release_cities(v["root"], routes=task.routes))
    budget, option = task.budget
    check_limit("episode_steps", v["episodes"] * v[budget], None, f"--episodes x {option}", field="episodes")
    if not task.selects_users and (v["groups"] or v["split"]):
        raise click.UsageError(f"--task {v['task']} plays every user and route of the cities: it takes no --group or --split")
    # One report into a folder at a time: a second one of the same folder, even of other agents, is refused at once
    # (both would publish, the last one winning, and both would say they wrote it).
    target = v["out"] or Path("reports") / TASKS[v["task"]].tag  # placement's: reports/ itself
    with exclusive_folder(target, "report", kind="job"), contextlib.ExitStack() as after:
        task.play(v, after)


def _placement_report(v: dict[str, Any], after: contextlib.ExitStack) -> None:
    """``uavrl report`` of the placement task: one report folder per city, then the page of every city."""
    from uavplace.eval.evaluate import check_unseen_runs, default_agents
    from uavplace.eval.render import check_summary_page, summary_rows, write_summary_page

    datasets, out, t_max = v["datasets"], v["out"], v["t_max"]
    chosen = list(v["runs"]) or default_agents(v["agents_dir"], "placement")
    _check_runs_once(chosen, "--run")
    grouped = _groups(v["groups"], chosen)
    _check_runs_once(chosen, "--run and --group")
    check_unseen_runs(chosen, list(datasets), v["root"])  # every city before the first city's report
    _check_training_settings(chosen, datasets, v["p_t_db"], v["root"], v["strict"])
    if len(datasets) > 1:
        check_summary_page(out or Path("reports"))
    folders = {d: out if out and len(datasets) == 1 else (out or Path("reports")) / d.split("@")[0] for d in datasets}
    if not v["overwrite"]:
        for folder in folders.values():
            _check_same_agents(folder, chosen)
    reports = []
    parallel = v["ray_address"] is not None or v["workers"] > 1
    if parallel and start_ray(v["ray_address"], 1, "--workers", v["workers"] if v["ray_address"] is None else None):
        import ray

        after.callback(ray.shutdown)
    shared = report_settings(chosen, v)
    for dataset in datasets:
        config = ReportConfig(dataset=dataset, t_max=t_max, p_t_db=v["p_t_db"], split=v["split"], groups=grouped, **shared)
        where = (datasets.index(dataset) + 1, len(datasets))
        result = _one_report(config, folders[dataset], v["root"], v["quiet"], where, parallel)
        reports.append(result)
        _print_city(result, f"{v['episodes']} episodes in {dataset} (t_max {t_max}, P_T {v['p_t_db']:g} dB)", dataset)
    top = None  # several cities: the page's findings, which the Markdown leads with too
    if len(datasets) > 1:
        rows = summary_rows(reports, t_max)
        stdout().print(plain_table(*rows[0], rows=rows[1:], title="success / median steps per method and city"))
        page, top = write_summary_page(reports, out or Path("reports"), t_max)
        stdout().print(f"report (every city): {page}", highlight=False, soft_wrap=True)
    if v["markdown"] is not None:
        from uavplace.eval.render import markdown_tables
        from uavplace.infra.files import atomic_write_text

        atomic_write_text(v["markdown"], markdown_tables(reports, t_max, top))
        stdout().print(f"tables (Markdown): {v['markdown']}", highlight=False, soft_wrap=True)


def _groups(groups: tuple[str, ...], chosen: list[Path]) -> dict[str, list[str]]:
    """``--group NAME=RUN,RUN,...`` values as ``{name: [run, ...]}``; each group's runs not yet among ``chosen`` are
    added to it (they are played alone too)."""
    grouped: dict[str, list[str]] = {}
    for text in groups:
        name, _, members = text.partition("=")
        folders = [m for m in members.split(",") if m]
        if not name or not folders:
            raise click.UsageError(f"--group {text!r}: expected NAME=RUN,RUN,...")
        if name in grouped:
            raise click.UsageError(f"--group {name} is given twice: one group of each name")
        if name in _method_names():
            raise click.UsageError(f"--group {name}: the name of a method of the report; call the group otherwise")
        _check_runs_once([Path(f) for f in folders], f"--group {name}")
        grouped[name] = [str(Path(f)) for f in folders]
        chosen += [Path(f) for f in folders if Path(f).resolve() not in {c.resolve() for c in chosen}]
    return grouped


def _print_city(result, title: str, dataset: str) -> None:  # noqa: ANN001 - a ReportResult
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
    stdout().print(f"report: {result.out / 'report.html'}", highlight=False, soft_wrap=True)


def predictor_or_none(text: str) -> str | None:
    """``--predictor``'s value: a predictor's path, or None for 'none' (the searchers left out)."""
    return None if text.lower() == "none" else text


#: The settings every task's report takes from the command line as they are (its config's fields of the same names).
SHARED_SETTINGS = ("episodes", "seed", "test_epsilon", "n_boot")


def report_settings(runs: list[Path], v: dict[str, Any]) -> dict:
    """The settings the placement and tracking reports' configs share, from the command line's values ``v``."""
    shared = {k: v[k] for k in (*SHARED_SETTINGS, "trajectories", "search")}
    return {"runs": [str(r) for r in runs], **shared, "predictor": predictor_or_none(v["predictor"])}


#: The columns of a report's table that a terminal shows (they fit 120 columns).
TERMINAL_COLUMNS = ("method", "success", "median steps", "median of per-episode steps / genie")


def terminal_columns(rows: list[list[str]]) -> list[list[str]]:
    """``rows`` (header first) with only ``TERMINAL_COLUMNS``."""
    keep = [i for i, name in enumerate(rows[0]) if name in TERMINAL_COLUMNS]
    return [[r[i] for i in keep] for r in rows]


def _check_same_agents(folder: Path, runs: list[Path]) -> None:
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


def _check_runs_once(runs: list[Path], option: str) -> None:
    """Refuse a run given twice (by two spellings or a link to it), and two runs of one folder name (their methods
    would share a name in every table)."""
    seen: dict[Path, Path] = {}
    names: dict[str, Path] = {}
    for run in runs:
        real = run.resolve()
        if real in seen:
            twice = f"{run} is given twice" if run == seen[real] else f"{run} and {seen[real]} are one run"
            raise click.UsageError(f"{option}: {twice}: give each run once")
        if run.name in names:
            raise click.UsageError(
                f"{option}: {names[run.name]} and {run} are both named {run.name}: their methods would "
                "share a name; rename one folder"
            )
        seen[real], names[run.name] = run, run


def _method_names() -> set[str]:
    """The names of the report's methods other than agents (a group may not take one)."""
    from uavplace.rl.tasks.placement.policies import GeniePolicy, GreedyPolicy, RandomWalkPolicy
    from uavplace.rl.tasks.placement.searcher import SEARCHER

    return {GeniePolicy.name, RandomWalkPolicy.name, GreedyPolicy.name, SEARCHER, "oracle"}


def _check_training_settings(runs: list[Path], datasets: tuple[str, ...], p_t_db: float, root: Path, strict: bool) -> None:
    """Name every agent and city where the agent would play outside its training settings (``unlike_training``): one
    warning line each, or a refusal with ``--strict``."""
    from uavplace.eval.evaluate import unlike_training

    warn_or_refuse(unlike_training(runs, list(datasets), root, p_t_db), strict)


def _tracking_report(v: dict[str, Any], after: contextlib.ExitStack) -> None:
    """``uavrl report --task tracking``: every method on the same episodes of each city's routes, one page."""
    from uavplace.eval.evaluate import default_agents
    from uavplace.eval.tracking import SUMMARY_TITLE, make_tracking_report, summary_rows, table_rows
    from uavplace.rl.tasks.tracking import TrackingConfig

    runs = list(v["runs"]) or default_agents(v["agents_dir"], ("placement", "tracking"))
    _check_runs_once(runs, "--run")
    _check_training_settings(runs, v["datasets"], v["p_t_db"], v["root"], v["strict"])
    horizon = v["horizon"]
    task = TrackingConfig(horizon=horizon, p_t_db=v["p_t_db"])
    config = TrackingReportConfig(datasets=list(v["datasets"]), hold=v["hold"], task=task, **report_settings(runs, v))
    with _reporting("tracking report", v["quiet"]) as on_progress:
        out = v["out"] or Path("reports") / "tracking"
        table, page = make_tracking_report(config, out, root=v["root"], command=command_line(), on_progress=on_progress)
    for city, rows in table.groupby("city", sort=False):
        cells = table_rows(rows, horizon)
        title = f"{v['episodes']} tracking episodes in {city} (horizon {horizon}, P_T {v['p_t_db']:g} dB)"
        stdout().print(plain_table(*cells[0], rows=cells[1:], title=title))
    if table["city"].nunique() > 1:
        cells = summary_rows(table)
        stdout().print(plain_table(*cells[0], rows=cells[1:], title=SUMMARY_TITLE))
    _say_written(v["markdown"], page, page.parent / "tracking.md")


def _fleet_report(v: dict[str, Any], after: contextlib.ExitStack) -> None:
    """``uavrl report --task fleet``: every method on the same fleet episodes of each city, one page."""
    from uavplace.eval.evaluate import check_unseen_runs, default_agents
    from uavplace.eval.fleet import DEFAULT_AGENT, SUMMARY_TITLE, make_fleet_report, summary_rows, table_rows
    from uavplace.eval.render import difference_rows
    from uavplace.rl.tasks.fleet import FleetConfig

    shipped = [p for p in default_agents(v["agents_dir"]) if p.name == DEFAULT_AGENT]
    runs = list(v["runs"]) or shipped + default_agents(v["agents_dir"], "fleet")
    _check_runs_once(runs, "--run")
    check_unseen_runs(runs, list(v["datasets"]), v["root"])
    _check_training_settings(runs, v["datasets"], v["p_t_db"], v["root"], v["strict"])
    t_max, uavs, users = v["t_max"], v["uavs"], v["users"]
    task = FleetConfig(uavs=uavs, users=users, t_max=t_max, p_t_db=v["p_t_db"])
    shared = {k: v[k] for k in SHARED_SETTINGS}
    config = FleetReportConfig(
        datasets=list(v["datasets"]),
        runs=[str(r) for r in runs],
        task=task,
        predictor=predictor_or_none(v["predictor"]),
        search=v["search"],
        **shared,
    )
    with _reporting("fleet report", v["quiet"]) as on_progress:
        out = v["out"] or Path("reports") / "fleet"
        table, diff, page = make_fleet_report(config, out, root=v["root"], command=command_line(), on_progress=on_progress)
    for city in config.datasets:
        cells = table_rows(table[table["city"] == city], t_max)
        title = f"{v['episodes']} fleet episodes in {city} ({uavs} UAVs, {users} users, t_max {t_max}, P_T {v['p_t_db']:g} dB)"
        stdout().print(plain_table(*cells[0], rows=cells[1:], title=title))
        cells = difference_rows(diff[diff["city"] == city], t_max)
        stdout().print(plain_table(*cells[0], rows=cells[1:], title=f"paired differences in {city}, 95 % intervals"))
    if len(config.datasets) > 1:
        cells = summary_rows(table, diff, t_max)
        stdout().print(plain_table(*cells[0], rows=cells[1:], title=SUMMARY_TITLE))
    _say_written(v["markdown"], page, page)


@contextlib.contextmanager
def _reporting(what: str, quiet: bool) -> Iterator[Callable[[str], None]]:
    """A spinner saying what a tracking or fleet report is on (a log line instead when not a terminal), and the
    ``on_progress`` that updates it."""
    log = LogLines(quiet)
    with console.status(f"[bold]{what}[/]", spinner="dots") if not quiet else contextlib.nullcontext() as status:

        def on_progress(step: str) -> None:
            if status is not None:
                status.update(f"[bold]{what}[/] {step}")
            log(f"{what} {step}", last=True)

        yield on_progress


def _say_written(markdown: Path | None, page: Path, tables: Path) -> None:
    """Copy a report's Markdown ``tables`` to ``markdown`` (when given) and say where the report and the copy are."""
    if markdown is not None:
        from uavplace.infra.files import atomic_write_text

        atomic_write_text(markdown, tables.read_text(encoding="utf-8"))
        stdout().print(f"tables (Markdown): {markdown}", highlight=False, soft_wrap=True)
    stdout().print(f"report: {page}", highlight=False, soft_wrap=True)


@dataclass(frozen=True)
class TaskReport:
    """How ``uavrl report --task NAME`` plays one task (``TASK_REPORTS``)."""

    #: The report: its settings (the command's values by name) and the stack its cleanups go on.
    play: Callable[[dict[str, Any], contextlib.ExitStack], None]
    #: Whether its cities need routes (the default cities: the test cities with routes).
    routes: bool
    #: The setting that bounds an episode's steps, and its option.
    budget: tuple[str, str]
    #: Whether it takes --group and --split (the others play every user and route of the cities).
    selects_users: bool
    #: Its report's settings, whose ``search`` field ``--search`` changes.
    config: type[BaseModel]
    #: Its searcher's class, ``module:Class`` (imported when asked): the ``SearchConfig`` fields it does not read
    #: (``unread_settings``), and the planners it has where not every one (``planners``).
    searcher: str
    #: The ``SearchConfig`` fields the report sets itself (placement plays the searcher with the buildings and without).
    sets: frozenset[str] = frozenset()

    def search(self, pairs: tuple[str, ...]) -> SearchConfig:
        """The task's searcher settings (its report config's default) with ``--search``'s ``NAME=VALUE`` set; a
        setting its searcher does not read (or a planner it has not) is refused, not recorded as if it were played."""
        import importlib

        module, _, name = self.searcher.partition(":")
        searcher = getattr(importlib.import_module(module), name)
        default = self.config.model_fields["search"].get_default(call_default_factory=True)
        search = with_pairs(default, pairs, "--search")
        unread = sorted(f for f in searcher.unread_settings | self.sets if getattr(search, f) != getattr(default, f))
        planners = getattr(searcher, "planners", None)
        if planners is not None and search.planner not in planners:
            unread.append(f"planner={search.planner} (it plans with {' or '.join(planners)})")
        if unread:
            why = " (the report plays it with the buildings and without)" if self.sets & set(unread) else ""
            raise click.BadParameter(
                f"the {searcher.name} ({name}) of this report does not read {', '.join(unread)}{why}: it would be "
                "recorded, not played",
                param_hint="'--search'",
            )
        return search


_RL = "uavplace.rl.tasks"
#: Each task's report (``rl.tasks.registry.TASKS`` names the same tasks).
TASK_REPORTS = {
    "placement": TaskReport(
        _placement_report,
        False,
        ("t_max", "--t-max"),
        True,
        ReportConfig,
        f"{_RL}.placement.searcher:MapSearchPolicy",
        frozenset({"buildings"}),
    ),
    "tracking": TaskReport(
        _tracking_report,
        True,
        ("horizon", "--horizon"),
        False,
        TrackingReportConfig,
        f"{_RL}.tracking.searcher:TrackingSearchPolicy",
    ),
    "fleet": TaskReport(
        _fleet_report, False, ("t_max", "--t-max"), False, FleetReportConfig, f"{_RL}.fleet.searcher:FleetSearcher"
    ),
}


def _one_report(config, out: Path, root: Path, quiet: bool, city: tuple[int, int] = (1, 1), parallel: bool = False):
    """``make_report`` with a progress bar per method (and stage: a searcher's predicted maps), named by the city's
    place among the report's (``city``: its number and the count) and the method's number."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from uavplace.eval.report import make_report

    tasks: dict[str, int] = {}
    plan: list[str] = []  # every stage of the city's evaluation, in order (make_report's on_plan)
    # no time-remaining column: the last episodes of a batch are its longest, so a rate-based ETA sat at 1 s for minutes
    columns = (TextColumn("[bold]report[/] {task.description:<20}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    log = LogLines(quiet)  # a log: a plain line every LINE_SECONDS (and at each method's start and end), not a bar
    with Progress(*columns, console=stdout(), disable=quiet or log.enabled) as bar:

        def on_progress(stage: str, done: int, total: int) -> None:
            new = stage not in tasks
            name = f"city {city[0]} of {city[1]}: {config.dataset}, stage {plan.index(stage) + 1} of {len(plan)}: {stage}"
            if new:
                tasks[stage] = bar.add_task(name, total=total)
            bar.update(tasks[stage], completed=done)
            unit = "candidates" if stage.endswith("predicted maps") else "episodes"
            log(f"report {name} {done}/{total} {unit}", last=new or done >= total)

        return make_report(
            config, out, root=root, command=command_line(), on_progress=on_progress, on_plan=plan.extend, parallel=parallel
        )


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
    from uavplace.eval.sweep import markdown, paired_differences, validation_table
    from uavplace.schemas import InputError

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
    default=("corpus", "oldtown", "train"),
    show_default=True,
    help="Training city or corpus (repeatable): their training users, as a `best` run's.",
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
    from uavplace.schemas import InputError

    if (match is None) == (cpu_seconds is None):
        raise click.UsageError("give --match RUN or --cpu-seconds S")
    import os

    import torch

    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))  # one thread unless told otherwise
    try:
        budget = cpu_seconds if cpu_seconds is not None else run_wall_seconds(match)
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

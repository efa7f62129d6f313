"""What every task's report shares: how ``uavrl report`` hands a task its request (``ReportRequest``: the command's
values, read once), how a task declares its report (``TaskReport``), and the checks and console lines every report
makes (agents given once, a report folder of other agents kept, training settings warned, progress, what was
written)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import click
from pydantic import BaseModel, ConfigDict

from uavplace.infra.console import LogLines, console, plain_table, say, stdout, warn_or_refuse
from uavplace.infra.device import Device
from uavplace.infra.options import with_pairs
from uavplace.rl.config import MapErrorSettings, MeasurementSettings, SearchConfig


class ReportRequest(BaseModel):
    """What ``uavrl report`` was asked, by the names of its options, read once from the command line and handed to
    the task's report (``TaskReport.play``); the report builds its own settings model from it
    (placement's ``eval.config.ReportConfig``, each other task's in its report module)."""

    #: Beside these, every task report's own options (``TaskReport.options``: ``--horizon``, ``--uavs``, ...) as
    #: fields of their names, validated by their options' types.
    model_config = ConfigDict(frozen=True, arbitrary_types_allowed=True, extra="allow")

    task: str
    runs: tuple[Path, ...] = ()
    datasets: tuple[str, ...] = ()
    out: Path | None = None
    episodes: int
    t_max: int
    p_t_db: float
    split: str | None = None
    seed: int
    test_epsilon: float
    n_boot: int
    trajectories: int
    groups: tuple[str, ...] = ()
    agents_dir: Path
    markdown: Path | None = None
    predictor: str
    search: SearchConfig
    measurement: MeasurementSettings = MeasurementSettings()
    map_error: MapErrorSettings = MapErrorSettings()
    device: Device = "auto"
    network_precision: str | None = None
    overwrite: bool = False
    strict: bool = False
    workers: int = 1
    ray_address: str | None = None
    root: Path
    quiet: bool = False

    @property
    def predictor_or_none(self) -> str | None:
        """``--predictor``'s value: a predictor's path, or None for 'none' (the searchers left out)."""
        return None if self.predictor.lower() == "none" else self.predictor

    def joined_ray(self, after: contextlib.ExitStack) -> bool:
        """Whether the report plays its methods as Ray tasks (``eval.parallel``): with ``--workers`` above 1 (a local
        Ray of that many CPUs, started here and shut down by ``after``) or ``--ray-address`` (that cluster, joined)."""
        if self.ray_address is None and self.workers == 1:
            return False
        from uavplace.infra.cluster import start_ray

        if start_ray(self.ray_address, 1, "--workers", self.workers if self.ray_address is None else None):
            import ray

            after.callback(ray.shutdown)
        return True

    def shared_settings(self, runs: list[Path]) -> dict:
        """The fields of ``eval.config.ReportSettings`` every task's report settings take from the request as they are
        (the agents ``runs`` as the report chose them; ``--network-precision`` where it was given, else the task's
        own)."""
        fields = ("episodes", "seed", "test_epsilon", "n_boot", "search", "measurement", "map_error", "device")
        given = {} if self.network_precision is None else {"network_precision": self.network_precision}
        return (
            {"runs": [str(r) for r in runs], "predictor": self.predictor_or_none} | {k: getattr(self, k) for k in fields} | given
        )


@dataclass(frozen=True)
class TaskReport:
    """How ``uavrl report --task NAME`` plays one task (its entry, ``rl.tasks.registry.TASKS``, names it)."""

    #: The report: the request and the stack its cleanups go on.
    play: Callable[[ReportRequest, contextlib.ExitStack], None]
    #: What ``uavrl report --task NAME`` plays, for ``--task``'s help.
    summary: str
    #: Its report's settings, whose ``search`` field ``--search`` changes.
    config: type[BaseModel]
    #: Its searcher's class, ``module:Class`` (imported when asked): the ``SearchConfig`` fields it does not read
    #: (``unread_settings``), and the planners it has where not every one (``planners``).
    searcher: str
    #: Whether its cities need routes (the default cities: the test cities with routes).
    routes: bool = False
    #: The request's field that bounds an episode's steps, and its option.
    budget: tuple[str, str] = ("t_max", "--t-max")
    #: Whether it takes --group and --split (the others play every user and route of the cities).
    selects_users: bool = False
    #: The ``SearchConfig`` fields the report sets itself (placement plays the searcher with the buildings and without).
    sets: frozenset[str] = frozenset()
    #: Its own options of ``uavrl report``: a settings model and the fields each is derived from
    #: (``infra.options.model_options``), read from the request by the fields' names.
    options: tuple[tuple[type[BaseModel], tuple[str, ...]], ...] = ()

    def search(self, pairs: tuple[str, ...]) -> SearchConfig:
        """The task's searcher settings (its report config's default) with ``--search``'s ``NAME=VALUE`` set; a
        setting its searcher does not read (or a planner it has not) is refused, not recorded as if it were played."""
        import importlib

        default = self.config.model_fields["search"].get_default(call_default_factory=True)
        if not pairs:  # the task's own settings: nothing to check, and the searcher (torch) stays unimported
            return default
        module, _, name = self.searcher.partition(":")
        searcher = getattr(importlib.import_module(module), name)
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


def check_runs_once(runs: list[Path], option: str) -> None:
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


def check_training_settings(runs: list[Path], request: ReportRequest) -> None:
    """Name every agent and city where the agent would play outside its training settings (``unlike_training``): one
    warning line each, or a refusal with ``--strict``."""
    from uavplace.eval.evaluate import unlike_training

    warn_or_refuse(unlike_training(runs, list(request.datasets), request.root, request.p_t_db), request.strict)


def checked_runs(runs: list[Path], request: ReportRequest) -> list[Path]:
    """``runs``, each given once (``check_runs_once``) and each named where it would play outside its training settings
    (``check_training_settings``)."""
    check_runs_once(runs, "--run")
    check_training_settings(runs, request)
    return runs


def report_folder(request: ReportRequest, tag: str) -> Path:
    """Where a task's report is written: ``--out``, else ``reports/<tag>`` (the task's ``RunTask.tag``; placement's
    is reports/ itself). The command locks it; the report writes into it."""
    return request.out or Path("reports") / tag


@contextlib.contextmanager
def reporting(what: str, quiet: bool) -> Iterator[Callable[[str], None]]:
    """A spinner saying what a tracking or fleet report is on (a log line instead when not a terminal), and the
    ``on_progress`` that updates it."""
    log = LogLines(quiet)
    with console.status(f"[bold]{what}[/]", spinner="dots") if not quiet else contextlib.nullcontext() as status:

        def on_progress(step: str) -> None:
            if status is not None:
                status.update(f"[bold]{what}[/] {step}")
            log(f"{what} {step}", last=True)

        yield on_progress


def print_table(cells: list[list[str]], title: str) -> None:
    """A table (header first) on the report's standard output."""
    stdout().print(plain_table(*cells[0], rows=cells[1:], title=title))


def say_written(markdown: Path | None, page: Path, tables: Path) -> None:
    """Copy a report's Markdown ``tables`` to ``markdown`` (when given) and say where the report and the copy are."""
    if markdown is not None:
        from uavplace.infra.files import atomic_write_text

        atomic_write_text(markdown, tables.read_text(encoding="utf-8"))
        say(f"tables (Markdown): {markdown}")
    say(f"report: {page}")

"""``uavrl report``: the evaluation protocol and its HTML report (registered in ``uavplace.cli``). The command reads
its values once into a ``ReportRequest`` and hands it to the task's report (``eval/reports/``)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from uavplace.eval.config import ReportConfig, ReportSettings
from uavplace.eval.reports import task_report
from uavplace.eval.reports.base import ReportRequest, report_folder
from uavplace.infra.console import path_option, ray_address_option, root_option
from uavplace.infra.files import exclusive_folder, shipped
from uavplace.infra.options import model_options
from uavplace.rl.cli import episode_options, task_option
from uavplace.rl.tasks.registry import TASKS
from uavplace.schemas.base import repeated


def task_options(command: Callable) -> Callable:
    """Each task report's own options (``TaskReport.options``), in the order of the tasks."""
    for name in reversed(TASKS):
        for model, fields in reversed(task_report(name).options):
            command = model_options(model, *fields)(command)
    return command


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
@task_option("; ".join(f"{name}: {task_report(name).summary}" for name in TASKS) + ".")
@task_options
@model_options(
    ReportSettings,
    "predictor",
    "device",
    "network_precision",
    unset={"network_precision": "the task's own: float32 in placement, bfloat16 in tracking and fleet"},
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
    "--measure",
    multiple=True,
    metavar="NAME=VALUE",
    help="What every method's UAV reads at a cell (a field of MeasurementSettings, rl/config.py; repeatable), e.g. "
    "--measure sigma_db=4 for an i.i.d. Gaussian error of 4 dB, --measure shadow_sigma_db=6 for correlated shadowing: "
    "the exact SINR by default; success is judged on the true SINR. The fleet task reads exactly only. Saved in the "
    "report's record.",
)
@click.option(
    "--map-error",
    "map_error",
    multiple=True,
    metavar="NAME=VALUE",
    help="How every method's 3D map differs from the traced city (a field of MapErrorSettings, rl/config.py; "
    "repeatable), e.g. --map-error height_sigma_m=2 --map-error missing_share=0.1 --map-error shift_m=1: the traced "
    "city's map by default; the cells the UAV may enter, the users' maps and the genie never err. The fleet task "
    "plays the traced map only. Saved in the report's record.",
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
    "for each such city, naming the agents (the report's findings say it too).",
)
@click.option(
    "--workers",
    type=click.IntRange(1),
    default=1,
    show_default=True,
    help="Play each city's methods, in pieces of their episodes, as Ray tasks on this many CPUs of this machine "
    "(every task; 1: one after the other in this process, torch on every core: on 2 cores the faster, "
    "docs/benchmarks.md). The numbers are the same whatever it is (eval/parallel.py).",
)
@ray_address_option("the methods (with it, --workers is the cluster's CPUs)")
@root_option
@click.option("--quiet", is_flag=True, help="No progress bar.")
def report(**values: Any) -> None:
    """Evaluate the agents, the map searcher and the baselines on the same episodes of test cities; write HTML, PNG, CSV.

    Methods: every agent, the genie (shortest path, full knowledge), the steered random walk, greedy
    hill-climbing, and the map searcher with its ablation shown no building (--predictor). Prints the results table (95 % bootstrap intervals in brackets) and the report's path;
    with several cities, one report folder each, then a summary of success and median steps per method and city, and
    one page with every city (OUT/report.html, OUT/summary.csv; OUT defaults to reports/).

    With --task NAME, that task's methods on the same episodes of each city (--task's list): its report module
    under eval/reports/ (docs/layout.md).
    """
    request = _request(values)
    from uavplace.dataset.bundle import resolve
    from uavplace.infra.files import check_replaceable_file
    from uavplace.infra.limits import check_limit

    task = task_report(request.task)
    cities = [d.split("@")[0] for d in request.datasets]
    twice = repeated(cities)
    if twice:  # one folder, table and summary row per city: two versions of one city would overwrite each other
        given = ", ".join(d for d in request.datasets if d.split("@")[0] in twice)
        raise click.UsageError(
            f"--dataset names {', '.join(twice)} more than once ({given}): one report per city; "
            "report each version with its own --out"
        )
    for dataset in request.datasets:  # a mistyped city is named, with the nearest ones, before anything heavy is loaded
        resolve(dataset, root=request.root)
    if request.markdown is not None:  # refused before any work: only a regular file or nothing is replaced
        check_replaceable_file(request.markdown)
    if not request.datasets:  # the release's cities: those built with the test role
        from uavplace.eval.cities import release_cities

        request = request.model_copy(update={"datasets": tuple(release_cities(request.root, routes=task.routes))})
    budget, option = task.budget
    check_limit("episode_steps", request.episodes * getattr(request, budget), None, f"--episodes x {option}", field="episodes")
    if not task.selects_users and (request.groups or request.split):
        raise click.UsageError(f"--task {request.task} plays every user and route of the cities: it takes no --group or --split")
    # One report into a folder at a time: a second one of the same folder, even of other agents, is refused at once
    # (both would publish, the last one winning, and both would say they wrote it).
    target = report_folder(request, TASKS[request.task].settings.tag)  # placement's: reports/ itself
    with exclusive_folder(target, "report", kind="job"), contextlib.ExitStack() as after:
        task.play(request, after)


def _request(values: dict[str, Any]) -> ReportRequest:
    """The command's values as a ``ReportRequest``, ``--search``'s pairs read as the task's searcher settings (a
    setting its searcher does not read, or any with ``--predictor none``, refused before any city is loaded: its
    searcher imports torch)."""
    if values["search"] and str(values["predictor"]).lower() == "none":
        raise click.BadParameter(
            "--predictor none leaves every searcher out: its settings would be recorded, not played", param_hint="'--search'"
        )
    from uavplace.infra.options import with_pairs
    from uavplace.rl.config import MapErrorSettings, MeasurementSettings

    measurement = with_pairs(MeasurementSettings(), values.pop("measure"), "--measure")
    map_error = with_pairs(MapErrorSettings(), values.pop("map_error"), "--map-error")
    if values["task"] == "fleet" and not measurement.exact:
        raise click.BadParameter("the fleet task reads every user's SINR exactly", param_hint="'--measure'")
    if values["task"] == "fleet" and not map_error.exact:
        raise click.BadParameter("the fleet task plays on the traced city's map", param_hint="'--map-error'")
    search = task_report(values["task"]).search(values["search"])
    from uavplace.infra.device import require_torch_device

    require_torch_device(values["device"])  # --device cuda without a GPU: refused before any city is loaded
    return ReportRequest(**(values | {"search": search, "measurement": measurement, "map_error": map_error}))

"""``uavrl report --task fleet``: every method on the same fleet episodes of each city, one page
(``eval.reports.fleet.page.make_fleet_report``)."""

from __future__ import annotations

import contextlib

from uavplace.eval.reports import base
from uavplace.eval.reports.fleet.config import FleetReportConfig
from uavplace.infra.console import command_line
from uavplace.rl.tasks.fleet.config import FleetConfig


def play(request: base.ReportRequest, after: contextlib.ExitStack) -> None:
    """The fleet report: its settings built once from the request, the page, then each city's tables."""
    from uavplace.eval.evaluate import check_unseen_runs, default_agents
    from uavplace.eval.render import difference_rows
    from uavplace.eval.reports.fleet.page import DEFAULT_AGENT, SUMMARY_TITLE, make_fleet_report, summary_rows, table_rows

    shipped = [p for p in default_agents(request.agents_dir) if p.name == DEFAULT_AGENT]
    runs = base.checked_runs(list(request.runs) or shipped + default_agents(request.agents_dir, "fleet"), request)
    check_unseen_runs(runs, list(request.datasets), request.root)
    t_max, uavs, users = request.t_max, request.uavs, request.users
    task = FleetConfig(uavs=uavs, users=users, t_max=t_max, p_t_db=request.p_t_db)
    config = FleetReportConfig(datasets=list(request.datasets), task=task, **request.shared_settings(runs))
    parallel = request.joined_ray(after)
    with base.reporting("fleet report", request.quiet) as on_progress:
        out = base.report_folder(request, "fleet")
        table, diff, page = make_fleet_report(
            config, out, root=request.root, command=command_line(), on_progress=on_progress, parallel=parallel
        )
    for city in config.datasets:
        title = (
            f"{request.episodes} fleet episodes in {city} ({uavs} UAVs, {users} users, t_max {t_max}, P_T {request.p_t_db:g} dB)"
        )
        base.print_table(table_rows(table[table["city"] == city], t_max), title)
        base.print_table(difference_rows(diff[diff["city"] == city], t_max), f"paired differences in {city}, 95 % intervals")
    if len(config.datasets) > 1:
        base.print_table(summary_rows(table, diff, t_max), SUMMARY_TITLE)
    base.say_written(request.markdown, page, page)


REPORT = base.TaskReport(
    play=play,
    summary="--uavs UAVs serve --users users at once (rl/tasks/fleet/): the oracle, the map searcher run for the fleet, "
    "the agents (--run; default: the shipped best and the fleet-trained agents under --agents-dir) run on every UAV "
    "on the users dealt to it, greedy hill-climbing and the random walk (eval/reports/fleet/page.py; OUT defaults to reports/fleet)",
    config=FleetReportConfig,
    searcher="uavplace.rl.tasks.fleet.searcher:FleetSearcher",
    options=((FleetConfig, ("uavs", "users")),),
)

"""``uavrl report --task fleet``: every method on the same fleet episodes of each city, one page
(``eval.fleet.make_fleet_report``)."""

from __future__ import annotations

import contextlib
from pathlib import Path

from uavplace.eval.config import FleetReportConfig
from uavplace.eval.reports.base import (
    ReportRequest,
    TaskReport,
    check_runs_once,
    check_training_settings,
    print_table,
    reporting,
    say_written,
)
from uavplace.infra.console import command_line


def play(request: ReportRequest, after: contextlib.ExitStack) -> None:
    """The fleet report: its settings built once from the request, the page, then each city's tables."""
    from uavplace.eval.evaluate import check_unseen_runs, default_agents
    from uavplace.eval.fleet import DEFAULT_AGENT, SUMMARY_TITLE, make_fleet_report, summary_rows, table_rows
    from uavplace.eval.render import difference_rows
    from uavplace.rl.tasks.fleet import FleetConfig

    shipped = [p for p in default_agents(request.agents_dir) if p.name == DEFAULT_AGENT]
    runs = list(request.runs) or shipped + default_agents(request.agents_dir, "fleet")
    check_runs_once(runs, "--run")
    check_unseen_runs(runs, list(request.datasets), request.root)
    check_training_settings(runs, request)
    t_max, uavs, users = request.t_max, request.uavs, request.users
    task = FleetConfig(uavs=uavs, users=users, t_max=t_max, p_t_db=request.p_t_db)
    config = FleetReportConfig(datasets=list(request.datasets), task=task, **request.shared_settings(runs))
    with reporting("fleet report", request.quiet) as on_progress:
        out = request.out or Path("reports") / "fleet"
        table, diff, page = make_fleet_report(config, out, root=request.root, command=command_line(), on_progress=on_progress)
    for city in config.datasets:
        title = f"{request.episodes} fleet episodes in {city} ({uavs} UAVs, {users} users, t_max {t_max}, P_T {request.p_t_db:g} dB)"
        print_table(table_rows(table[table["city"] == city], t_max), title)
        print_table(difference_rows(diff[diff["city"] == city], t_max), f"paired differences in {city}, 95 % intervals")
    if len(config.datasets) > 1:
        print_table(summary_rows(table, diff, t_max), SUMMARY_TITLE)
    say_written(request.markdown, page, page)


REPORT = TaskReport(
    play=play,
    routes=False,
    budget=("t_max", "--t-max"),
    selects_users=False,
    config=FleetReportConfig,
    searcher="uavplace.rl.tasks.fleet.searcher:FleetSearcher",
)

"""``uavrl report --task tracking``: every method on the same episodes of each city's routes, one page
(``eval.reports.tracking.page.make_tracking_report``)."""

from __future__ import annotations

import contextlib

from uavplace.eval.reports.base import (
    ReportRequest,
    TaskReport,
    checked_runs,
    print_table,
    report_folder,
    reporting,
    say_written,
)
from uavplace.eval.reports.tracking.config import TrackingReportConfig
from uavplace.infra.console import command_line
from uavplace.rl.tasks.tracking.config import TrackingConfig


def play(request: ReportRequest, after: contextlib.ExitStack) -> None:
    """The tracking report: its settings built once from the request, the page, then each city's table."""
    from uavplace.eval.evaluate import default_agents
    from uavplace.eval.reports.tracking.page import SUMMARY_TITLE, make_tracking_report, summary_rows, table_rows

    runs = checked_runs(list(request.runs) or default_agents(request.agents_dir, ("placement", "tracking")), request)
    horizon = request.horizon
    config = TrackingReportConfig(
        datasets=list(request.datasets),
        hold=request.hold,
        task=TrackingConfig(horizon=horizon, p_t_db=request.p_t_db, measurement=request.measurement, map_error=request.map_error),
        trajectories=request.trajectories,
        **request.shared_settings(runs),
    )
    parallel = request.joined_ray(after)
    with reporting("tracking report", request.quiet) as on_progress:
        out = report_folder(request, "tracking")
        table, page = make_tracking_report(
            config, out, root=request.root, command=command_line(), on_progress=on_progress, parallel=parallel
        )
    for city, rows in table.groupby("city", sort=False):
        title = f"{request.episodes} tracking episodes in {city} (horizon {horizon}, P_T {request.p_t_db:g} dB)"
        print_table(table_rows(rows, horizon), title)
    if table["city"].nunique() > 1:
        print_table(summary_rows(table), SUMMARY_TITLE)
    say_written(request.markdown, page, page.parent / "tracking.md")


REPORT = TaskReport(
    play=play,
    summary="a user who moves along the routes of the cities (bundles simulated with --routes; rl/tasks/tracking/): the "
    "oracle, the agents (placement agents run unchanged), the re-planning genie, the tracking searcher and the "
    "baselines, one page (eval/reports/tracking/page.py; OUT defaults to reports/tracking)",
    routes=True,
    budget=("horizon", "--horizon"),
    config=TrackingReportConfig,
    searcher="uavplace.rl.tasks.tracking.searcher:TrackingSearchPolicy",
    options=((TrackingConfig, ("horizon",)), (TrackingReportConfig, ("hold",))),
)

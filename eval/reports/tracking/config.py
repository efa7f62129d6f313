"""The tracking report's settings (``TrackingReportConfig``, saved in ``tracking.json``). Light to import."""

from __future__ import annotations

from pydantic import Field

from uavplace.eval.config import TRAJECTORIES, ReportSettings, network_precision
from uavplace.infra.device import NetworkPrecision
from uavplace.rl.config import SearchConfig
from uavplace.rl.tasks.tracking.config import MotionModel, TrackingConfig, tracking_search


class TrackingReportConfig(ReportSettings):
    """Every parameter of one tracking report (saved in ``tracking.json``): the shared report settings, the cities
    with routes, the tracking task, the hold rule and the tracking searcher's motion model and settings."""

    datasets: list[str] = Field(min_length=1, description="Cities with routes (built bundles, optionally city@version)")
    task: TrackingConfig = Field(default_factory=TrackingConfig, description="The tracking task (horizon, P_T, speeds)")
    trajectories: int = TRAJECTORIES
    hold: bool = Field(
        default=True,
        description="Tracking: also play each method that has no stay action (placement agents, the random walk, greedy "
        "hill-climbing) holding its cell while its own measurement is at or above P_T (rl/tasks/tracking/policies.py, "
        "Holding), as a row '... + hold' after the method as it is",
    )
    network_precision: NetworkPrecision = network_precision("bfloat16")
    motion: MotionModel = Field(default_factory=MotionModel, description="The tracking searcher's motion model")
    search: SearchConfig = Field(
        default_factory=tracking_search,
        description="The tracking searcher's settings (rl/tasks/tracking/config.py, tracking_search: the map searcher's "
        "with a flatter discount)",
    )

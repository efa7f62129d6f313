"""The fleet report's settings (``FleetReportConfig``, saved in ``fleet.json``). Light to import."""

from __future__ import annotations

from pydantic import Field

from uavplace.eval.config import ReportSettings, network_precision
from uavplace.infra.device import NetworkPrecision
from uavplace.rl.config import SearchConfig
from uavplace.rl.tasks.fleet.config import FleetConfig, fleet_search


class FleetReportConfig(ReportSettings):
    """How a fleet report was made (saved in ``fleet.json``): the shared report settings (the agents each run on
    every UAV; the fleet searcher's plan is its ``search.fleet_plan``), the cities and the fleet task."""

    datasets: list[str] = Field(min_length=1, description="Cities (built datasets)")
    task: FleetConfig = Field(default_factory=FleetConfig, description="The fleet task (rl/tasks/fleet/)")
    network_precision: NetworkPrecision = network_precision("bfloat16")
    search: SearchConfig = Field(
        default_factory=fleet_search,
        description="The fleet searcher's settings (rl/tasks/fleet/config.py, fleet_search: the map searcher's, its "
        "belief products in bfloat16)",
    )

"""The settings of the reports (``uavrl report``): a model per task (placement, tracking, fleet), saved beside the
report it made, from which the command's options derive (``infra.options``). Light to import: the command line reads
them before any heavy work."""

from __future__ import annotations

from pydantic import ConfigDict, Field

from uavplace.rl.config import DEFAULT_PREDICTOR, EpisodeSettings, SearchConfig
from uavplace.rl.tasks.fleet.config import FleetConfig
from uavplace.rl.tasks.tracking.config import MotionModel, TrackingConfig, tracking_search
from uavplace.schemas.base import MAX_SEED, Contract

#: The evaluation protocol's fields every report shares with ``EpisodeSettings`` (declared there once).
_EPISODE = EpisodeSettings.model_fields


class ReportSettings(Contract):
    """What every task's report takes (each task's report settings extend it): the agents, the episodes and their
    seed, the agents' random moves, the bootstrap, and the searcher's predictor and settings."""

    model_config = ConfigDict(allow_inf_nan=False)

    runs: list[str] = Field(default_factory=list, description="Agent folders (run folders or shipped agents)")
    episodes: int = _EPISODE["episodes"]
    seed: int = _EPISODE["seed"]
    test_epsilon: float = Field(
        default=0.096, ge=0, le=1, description="Probability of a random legal move of the agents (paper: 0.096)."
    )
    n_boot: int = Field(
        default=2000,
        ge=100,
        description="Bootstrap resamples of the 95 % intervals.",
        json_schema_extra={"limit": "bootstrap"},
    )
    predictor: str | None = Field(
        default=str(DEFAULT_PREDICTOR),
        description="The searcher's radio-map predictor: the physics tier's constants (a JSON file) or a tier's folder, "
        "learned or ray-traced (its model.json says which; rl.predictor.load_predictor); None: no searcher is played",
    )
    search: SearchConfig = Field(default_factory=SearchConfig, description="The searcher's settings")


#: Episodes drawn on the maps (``trajectories``), the placement and tracking reports' figure.
TRAJECTORIES = Field(
    default=3,
    ge=0,
    le=3,
    description="Episodes of the searcher (else the first agent) drawn on the maps, by rule (eval/figures.py, "
    "TRAJECTORY_RULES; tracking: EPISODE_RULES): the success closest to its median steps, the success at the 90th "
    "percentile of its successes, its first failure (0: no trajectory figure).",
)


class ReportConfig(ReportSettings, EpisodeSettings):
    """How a placement report was made (saved in ``report.json``): the shared report settings, the episodes
    (``EpisodeSettings``: step budget, P_T, users' split), the city, the groups of runs and the ablation."""

    dataset: str = Field(description="Test city (a built dataset, optionally city@version)")
    trajectories: int = TRAJECTORIES
    groups: dict[str, list[str]] = Field(
        default_factory=dict,
        description="Methods made of several runs (a preset's seeds): name -> run folders, each also one of ``runs``",
    )
    ablate: bool = Field(
        default=True,
        description="Also play every agent that reads the building map with the map blanked (MapSet.show_buildings(None): "
        "what it sees, not where it may fly), as '<agent>, no buildings', paired on the same episodes",
    )
    prediction_cache: str | None = Field(
        default=None, description="Folder of the searcher's predicted maps (None: .predictions beside the bundles)"
    )


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
    motion: MotionModel = Field(default_factory=MotionModel, description="The tracking searcher's motion model")
    search: SearchConfig = Field(
        default_factory=tracking_search,
        description="The tracking searcher's settings (rl/tasks/tracking/config.py, tracking_search: the map searcher's "
        "with a flatter discount)",
    )


class FleetReportConfig(ReportSettings):
    """How a fleet report was made (saved in ``fleet.json``): the shared report settings (the agents each run on
    every UAV; the fleet searcher's plan is its ``search.fleet_plan``), the cities and the fleet task."""

    datasets: list[str] = Field(min_length=1, description="Cities (built datasets)")
    task: FleetConfig = Field(default_factory=FleetConfig, description="The fleet task (rl/tasks/fleet/)")


class PeerConfig(Contract):
    """A peer's training budget and settings (`uavrl peer train`, eval/peer.py: Stable-Baselines3 on the shipped
    agents' cities)."""

    model_config = ConfigDict(allow_inf_nan=False)

    cpu_seconds: float | None = Field(default=None, ge=1, description="The budget of CPU seconds (instead of --match).")
    max_steps: int = Field(
        default=3_000_000,
        ge=1,
        description="Env steps at most (SB3's schedules anneal over them).",
        json_schema_extra={"limit": "train_steps"},
    )
    n_envs: int = Field(default=8, ge=1, le=64, description="Envs SB3 steps side by side.")
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="Seed of SB3's model and envs.")

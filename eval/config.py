"""The settings of the reports (``uavrl report``): a model per task (placement, tracking, fleet), saved beside the
report it made, from which the command's options derive (``infra.options``). Light to import: the command line reads
them before any heavy work."""

from __future__ import annotations

from pydantic import ConfigDict, Field

from uavplace.rl.config import DEFAULT_PREDICTOR, EpisodeSettings, SearchConfig
from uavplace.rl.tasks.fleet.config import FleetConfig
from uavplace.rl.tasks.tracking.config import MotionModel, TrackingConfig, tracking_search
from uavplace.schemas.base import MAX_SEED, Contract


class ReportConfig(EpisodeSettings):
    """How a report was made (saved in ``report.json``): the episodes (``EpisodeSettings``), the methods, the
    statistics."""

    dataset: str = Field(description="Test city (a built dataset, optionally city@version)")
    runs: list[str] = Field(default_factory=list, description="Agent folders (run folders or shipped agents)")
    test_epsilon: float = Field(
        default=0.096, ge=0, le=1, description="Probability of a random legal move of the agents (paper: 0.096)."
    )
    n_boot: int = Field(
        default=2000,
        ge=100,
        description="Bootstrap resamples of the 95 % intervals.",
        json_schema_extra={"limit": "bootstrap"},
    )
    trajectories: int = Field(
        default=3,
        ge=0,
        le=3,
        description="Episodes of the map searcher (else the first agent) drawn on the maps, by rule (eval/figures.py, "
        "TRAJECTORY_RULES): the success closest to its median steps, the success at the 90th percentile of its "
        "successes, its first failure (0: no trajectory figure).",
    )
    groups: dict[str, list[str]] = Field(
        default_factory=dict,
        description="Methods made of several runs (a preset's seeds): name -> run folders, each also one of ``runs``",
    )
    predictor: str | None = Field(
        default=str(DEFAULT_PREDICTOR),
        description="The map searcher's predictor: the physics tier's constants (a JSON file) or a tier's folder, learned or ray-traced (its model.json says which; rl.predictor.load_predictor); None: no searcher is played",
    )
    search: SearchConfig = Field(default_factory=SearchConfig, description="The map searcher's settings")
    ablate: bool = Field(
        default=True,
        description="Also play every agent that reads the building map with the map blanked (MapSet.show_buildings(None): "
        "what it sees, not where it may fly), as '<agent>, no buildings', paired on the same episodes",
    )
    prediction_cache: str | None = Field(
        default=None, description="Folder of the searcher's predicted maps (None: .predictions beside the bundles)"
    )


class TrackingReportConfig(Contract):
    """Every parameter of one tracking report (saved in ``tracking.json``)."""

    model_config = ConfigDict(allow_inf_nan=False)

    datasets: list[str] = Field(min_length=1, description="Cities with routes (built bundles, optionally city@version)")
    runs: list[str] = Field(
        default_factory=list,
        description="Agents (run folders or shipped agents): tracking agents, and placement agents run unchanged",
    )
    test_epsilon: float = Field(default=0.096, ge=0, le=1, description="Random legal move rate of the agents (paper: 0.096)")
    episodes: int = Field(default=1000, ge=1, description="Episodes per city, the same for every method")
    task: TrackingConfig = Field(default_factory=TrackingConfig, description="The tracking task (horizon, P_T, speeds)")
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="Seed of the episodes and the baselines' random moves")
    n_boot: int = Field(default=2000, ge=100, description="Bootstrap resamples of the 95 % intervals")
    trajectories: int = Field(default=3, ge=0, le=3, description="Episodes drawn on the maps, by EPISODE_RULES (0: none)")
    hold: bool = Field(
        default=True,
        description="Tracking: also play each method that has no stay action (placement agents, the random walk, greedy "
        "hill-climbing) holding its cell while its own measurement is at or above P_T (rl/tasks/tracking/policies.py, "
        "Holding), as a row '... + hold' after the method as it is",
    )
    predictor: str | None = Field(
        default=str(DEFAULT_PREDICTOR),
        description="The tracking searcher's radio-map predictor (rl/tasks/tracking/searcher.py; None: the searcher is not played)",
    )
    motion: MotionModel = Field(default_factory=MotionModel, description="The tracking searcher's motion model")
    search: SearchConfig = Field(
        default_factory=tracking_search,
        description="The tracking searcher's settings (rl/tasks/tracking/config.py, tracking_search: the map searcher's "
        "with a flatter discount)",
    )


class FleetReportConfig(Contract):
    """How a fleet report was made (saved in ``fleet.json``)."""

    datasets: list[str] = Field(min_length=1, description="Cities (built datasets)")
    episodes: int = Field(default=1000, ge=1, description="Episodes a city, the same for every method")
    seed: int = Field(default=0, ge=0, le=MAX_SEED, description="Seed of the episodes and of every random move")
    n_boot: int = Field(default=2000, ge=100, description="Bootstrap resamples for the 95 % intervals")
    task: FleetConfig = Field(default_factory=FleetConfig, description="The fleet task (rl/tasks/fleet/)")
    runs: list[str] = Field(
        default_factory=list, description="Agents' run folders (placement or fleet-trained), each run on every UAV"
    )
    test_epsilon: float = Field(default=0.096, ge=0, le=1, description="Random legal move rate of the agents")
    predictor: str | None = Field(
        default=str(DEFAULT_PREDICTOR),
        description="The fleet searcher's predictor (rl.predictor.load_predictor); None: no searcher",
    )
    search: SearchConfig = Field(
        default_factory=SearchConfig,
        description="The fleet searcher's settings (its plan: fleet_plan; rl/tasks/fleet/searcher.py)",
    )


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

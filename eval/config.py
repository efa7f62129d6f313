"""The settings of a placement report (``uavrl report``): one model, saved in ``report.json``, from which the
command's options derive (``infra.options``). Light to import: the command line reads it before any heavy work."""

from __future__ import annotations

from pydantic import Field

from uavplace.rl.config import DEFAULT_PREDICTOR, EpisodeSettings, SearchConfig


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
        description="Episodes of the first agent drawn on the maps, by rule (eval/figures.py, TRAJECTORY_RULES): the "
        "success closest to its median steps, the success at the 90th percentile of its successes, its first failure "
        "(0: no trajectory figure).",
    )
    groups: dict[str, list[str]] = Field(
        default_factory=dict,
        description="Methods made of several runs (a preset's seeds): name -> run folders, each also one of ``runs``",
    )
    predictor: str | None = Field(
        default=str(DEFAULT_PREDICTOR),
        description="The map searcher's predictor: the physics tier's constants (a JSON file) or a learned tier (a folder; rl.belief.load_predictor); None: no searcher is played",
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

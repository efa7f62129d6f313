"""The settings of the reports (``uavrl report``): the base every task's report settings extend (``ReportSettings``;
each task's own model is in its report module, ``eval/reports/<task>.py``) and placement's, each saved beside the
report it made, from which the command's options derive (``infra.options``). Light to import: the command line reads
them before any heavy work."""

from __future__ import annotations

from pydantic import ConfigDict, Field
from pydantic.fields import FieldInfo

from uavplace.infra.device import DEVICE_HELP, Device, NetworkPrecision
from uavplace.rl.config import DEFAULT_PREDICTOR, EpisodeSettings, MapErrorSettings, MeasurementSettings, SearchConfig
from uavplace.schemas.base import MAX_SEED, Contract

#: The evaluation protocol's fields every report shares with ``EpisodeSettings`` (declared there once).
_EPISODE = EpisodeSettings.model_fields


def network_precision(default: str) -> FieldInfo:
    """The ``network_precision`` field of a report's settings, with its task's ``default``."""
    return Field(
        default=default,
        description="The agents' networks' arithmetic as they act (rl/agent/dqn.py, DQNPolicy): 'float32', or "
        "'bfloat16' (the layers before the heads under torch's bfloat16 autocast, the heads in float32: 2 to 4 x "
        "faster on a CPU with bfloat16 units; moves may differ, validated per report in docs/benchmarks.md)",
    )


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
        description="The map searcher's radio-map predictor (docs/predictor.md): a tier's folder, learned (`uavrl "
        "train-predictor`) or ray-traced (`uavrl trace-predictor`; its model.json says which), or the physics tier's "
        "constants (data/agents/searcher/predictor.json, `uavrl fit-predictor`); 'none' (None in a record): the task's "
        "searcher and its ablation are left out. Its predicted maps are cached under ROOT/.predictions/.",
    )
    search: SearchConfig = Field(default_factory=SearchConfig, description="The searcher's settings")
    measurement: MeasurementSettings = Field(
        default_factory=MeasurementSettings,
        description="What every method's UAV reads at a cell (rl/config.py, MeasurementSettings): the exact SINR by "
        "default; success is judged on the true SINR",
    )
    map_error: MapErrorSettings = Field(
        default_factory=MapErrorSettings,
        description="How every method's 3D map differs from the traced city (rl/config.py, MapErrorSettings): the "
        "traced city's by default; the genie and the users' maps never err",
    )
    network_precision: NetworkPrecision = network_precision("float32")
    device: Device = Field(
        default="auto",
        description=f"Where the agents' networks and the searchers' belief products run: {DEVICE_HELP} "
        "(docs/benchmarks.md says what moves to a GPU)",
    )


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

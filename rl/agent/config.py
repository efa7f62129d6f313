"""A learning run's settings: ``DQNConfig`` (every hyperparameter, saved with the run), the named presets
(``PRESETS``, ``preset_config``) and ``--set PART.FIELD=VALUE`` (``parse_settings``)."""

from __future__ import annotations

import json
from typing import Literal

from pydantic import ConfigDict, Field, ValidationError, model_validator

from uavplace.infra.limits import limits, over_limit
from uavplace.rl.tasks.placement.config import EnvConfig, PlacementTask
from uavplace.rl.tasks.registry import TASKS, LearnerTask
from uavplace.schemas import InputError
from uavplace.schemas.base import MAX_SEED, Contract, validation_message


class DQNConfig(Contract):
    """Every hyperparameter of a run (saved with it); ``PRESETS`` holds the named sets."""

    model_config = ConfigDict(allow_inf_nan=False)

    preset: str = Field(default="custom", description="Name of the preset this config came from")
    agent: Literal["dqn", "blind"] = Field(
        default="dqn", description="dqn: height map + SINR memory (the paper's proposed agent); blind: SINR memory only."
    )
    total_steps: int = Field(
        default=7_000_000,
        ge=1,
        description="Environment steps (all envs together).",
        json_schema_extra={"limit": "train_steps"},
    )
    num_envs: int = Field(default=8, ge=1, le=65_536, description="Episodes acted on in parallel (batched env)")
    learner: Literal["replay", "pqn"] = Field(
        default="replay",
        description="replay: double DQN from a replay buffer with a target network (the paper's); pqn: Q(lambda) on "
        "each rollout of the batched env, no replay, no target network (rl/agent/pqn.py)",
    )
    rollout_steps: int = Field(default=16, ge=1, le=100_000, description="PQN: moves of every env per rollout (then the updates)")
    q_lambda: float = Field(default=0.65, ge=0, le=1, description="PQN: lambda of the Q(lambda) returns (0: one-step)")
    epochs: int = Field(
        default=4, ge=1, le=10_000, description="PQN: passes over each rollout, in shuffled minibatches of batch_size"
    )
    layer_norm: bool = Field(default=False, description="Layer norm after each fully connected layer (PQN's stabiliser)")
    recurrent: bool = Field(
        default=False,
        description="A GRU cell between the network's features and its heads: a memory of the episode beyond the window, "
        "reset at each episode's start (PQN only: it learns on whole rollouts, from the state each began with)",
    )
    buffer_size: int = Field(default=500_000, ge=1, description="Replay capacity in transitions (FIFO)")
    batch_size: int = Field(default=20, ge=1, le=1_000_000, description="Transitions per gradient step")
    train_every: int = Field(default=3, ge=1, description="Environment steps per gradient step (replay learner)")
    learning_starts: int = Field(default=10_000, ge=0, description="Environment steps before the first update (replay learner)")
    gamma: float = Field(default=0.99, gt=0, le=1, description="Discount factor")
    n_step: int = Field(default=1, ge=1, le=1000, description="Steps of the return before bootstrapping")
    lr_start: float = Field(default=1e-4, gt=0, description="Learning rate at the start (annealed linearly)")
    lr_end: float = Field(default=1e-5, gt=0, description="Learning rate at the end")
    grad_clip: float = Field(default=10.0, gt=0, description="Max global gradient norm")
    target_update: int = Field(
        default=10_000, ge=1, description="Environment steps between target-network copies (replay learner)"
    )
    eps_start: float = Field(default=1.0, ge=0, le=1, description="Exploration rate at the start")
    eps_end: float = Field(default=0.0, ge=0, le=1, description="Exploration rate at the end of the annealing")
    eps_fraction: float = Field(default=1.0, gt=0, le=1, description="Share of total_steps over which epsilon anneals")
    p_repeat: float = Field(default=0.4, ge=0, le=1, description="Share of exploratory moves that repeat the previous move")
    network: Literal["paper", "fovea"] = Field(
        default="paper",
        description="paper: 3 convolutions + fully connected (QNetwork); fovea: centre + pooled surround, fully connected",
    )
    fovea: int = Field(
        default=15, ge=3, le=1001, description="Fovea network: side of the centre crop and of the pooled surround [cells]"
    )
    pool_extremes: bool = Field(
        default=False,
        description="Fovea network: the surround max- and min-pooled as well as averaged (a lane of open cells, a "
        "wall, an unvisited cell in a block stay visible)",
    )
    pool_middle: bool = Field(
        default=False,
        description="Fovea network: a third view, the centre 2 * fovea + 1 cells at half resolution (3 x 3 means, "
        "stride 2), between the full-resolution centre and the pooled surround",
    )
    hidden: int = Field(default=256, ge=1, description="Width of the fully connected layers")
    conv_channels: tuple[int, int, int] = Field(default=(32, 64, 64), description="Filters of the 3 convolutions")
    dropout: float = Field(default=0.4, ge=0, lt=1, description="Dropout after the fully connected layer")
    aux_genie: float = Field(
        default=0.0,
        ge=0,
        description="Weight of an auxiliary loss (training only): a second head on the Q-network's features learns "
        "the genie's move at each replayed observation (cross-entropy over the moves that start a shortest path); "
        "privileged information shapes the features, the Q head alone acts (0: off, the paper's)",
    )
    eval_every: int = Field(
        default=100_000,
        ge=1,
        description="Environment steps between evaluations of held-out users (the best checkpoint).",
    )
    eval_episodes: int = Field(default=200, ge=1, description="Episodes per evaluation (fixed, seeded)")
    eval_split: Literal["train", "val", "test"] | None = Field(
        default="val", description="Users the evaluation plays (val: held-out users of the training cities)"
    )
    test_epsilon: float = Field(default=0.096, ge=0, le=1, description="Random legal move rate when evaluating (paper: 0.096)")
    test_revisit_penalty: float = Field(
        default=0.0,
        ge=0,
        description="When evaluating, subtracted from the Q-value of a move once per earlier visit of this episode to the "
        "cell it leads to, so that the greedy move breaks out of loops (0: the paper's argmax)",
    )
    train_revisit_penalty: float = Field(
        default=0.0,
        ge=0,
        description="When training, the greedy move maximises Q less this times the earlier visits of the cell it "
        "leads to: the test rule's revisit penalty (test_revisit_penalty) in the moves it learns from (0: plain argmax)",
    )
    test_aux_weight: float = Field(
        default=0.0,
        ge=0,
        description="When evaluating, this times the log-probability the genie-move head (aux_genie) gives a move is "
        "added to its Q-value (the head reads the same observation; 0: the Q head alone acts)",
    )
    eval_t_max: int = Field(default=500, ge=1, description="Step budget of evaluation episodes (paper: 500)")
    seed: int = Field(
        default=0, ge=0, le=MAX_SEED, description="Seed of the whole run (envs, exploration, replay sampling, torch)."
    )
    ensemble: int = Field(
        default=1,
        ge=1,
        description="Networks acting as one agent, the mean of their Q values (each with its own recurrent state): "
        "written by `uavrl ensemble` from runs of one config; a training run is one network (1)",
    )
    device: str = Field(
        default="auto", description="Where the networks train: auto (CUDA if present, else CPU), cpu, cuda, cuda:N"
    )
    env: EnvConfig = Field(default_factory=lambda: EnvConfig(t_max=800, rotate=True), description="Training environment")
    task: LearnerTask = Field(
        default_factory=PlacementTask,
        description="The task learnt (its kind) and its settings. placement: find a user who stands still (the "
        "paper's task, 4 moves; the env is `env`); tracking: keep a user who walks its route covered "
        "(rl/tasks/tracking/; 5 actions, stay the fifth; `env` is not read; every training and validation city needs "
        "routes, `uavdata simulate --routes N`; best.pt is the network that covers the most of the horizon on the "
        "validation cities' routes; the preset's revisit penalties are off); fleet: several UAVs serve several users "
        "(rl/tasks/fleet/: one network on every UAV, each playing `env`'s placement observation of the users dealt to "
        "it; best.pt is the network that serves every user in the most fleet episodes of the validation cities; --set fleet.uavs=2 --set fleet.users=3 "
        "are the defaults, --set init=data/agents/best starts from a trained network).",
    )
    init: str | None = Field(
        default=None,
        description="A trained network whose weights start the run (a run or ensemble folder, or its best.pt; the "
        "same network as this config's); None: random weights",
    )
    init_member: int = Field(default=0, ge=0, description="With init an ensemble: the member whose weights start the run")

    @model_validator(mode="before")
    @classmethod
    def _task_of_a_record(cls, data: object) -> object:
        """A record written before the task held its settings (``"task": "tracking"`` beside ``"tracking": {...}``)
        read as the task it describes."""
        if isinstance(data, dict) and isinstance(data.get("task", "placement"), str):
            data = dict(data)
            kind = data.pop("task", "placement")
            own = {t.settings.prefix: data.pop(t.settings.prefix, None) for t in TASKS.values() if t.settings.prefix}
            data["task"] = {"kind": kind, **(own.get(kind) or {})}
        return data

    @model_validator(mode="after")
    def _rollout_holds_a_batch(self) -> DQNConfig:
        if self.learner == "pqn" and self.batch_size > self.num_envs * self.rollout_steps:
            raise ValueError(
                f"batch_size {self.batch_size} exceeds a PQN rollout (num_envs x rollout_steps = "
                f"{self.num_envs * self.rollout_steps} samples)"
            )
        if self.recurrent and self.learner != "pqn":
            raise ValueError("recurrent needs learner=pqn (the replay learner samples single transitions, not sequences)")
        if self.test_aux_weight > 0 and self.aux_genie <= 0:
            raise ValueError("test_aux_weight needs a network with a genie-move head (trained with aux_genie > 0)")
        task = self.task
        if not task.channels and (self.env.belief_channel or self.env.context_zoom):
            raise ValueError(f"a {task.kind} run deals each UAV a changing set of users: no belief or context channel")
        if self.env.fleet_channel and task.kind != "fleet":
            raise ValueError(f"env.fleet_channel marks the fleet's other UAVs: a fleet run's, not a {task.kind} run's")
        if not task.revisits and (self.train_revisit_penalty or self.test_revisit_penalty):
            # A user who moves brings the UAV back to cells it has stood in: placement's loop breaker is wrong here.
            raise ValueError(f"train_revisit_penalty and test_revisit_penalty are placement's: 0 in a {task.kind} run")
        return self

    @model_validator(mode="after")
    def _within_limits(self) -> DQNConfig:
        """The loops a config drives are bounded by the resource limits (``infra.limits``), checked when it is made
        or read from a run.json, before any work; the network's and the replay's sizes are checked where they are built."""
        for field, limit, value in (
            ("total_steps", "train_steps", self.total_steps),
            ("eval_episodes", "episodes", self.eval_episodes),
            ("eval_t_max", "t_max", self.eval_t_max),
            ("env.t_max", "t_max", self.env.t_max),
            ("task.t_max", "t_max", getattr(self.task, "t_max", 0)),
        ):
            if value > getattr(limits(), limit):
                raise ValueError(over_limit(limit, value, field))
        return self

    @property
    def sequences_per_batch(self) -> int:
        """Recurrent PQN: the whole env rollouts in a minibatch (``batch_size`` samples, at least one rollout)."""
        return max(1, self.batch_size // self.rollout_steps)

    @property
    def n_actions(self) -> int:
        """The network's outputs: the 4 moves, and in the tracking task stay as well."""
        return self.task.actions

    def observation(self) -> tuple[int, int]:
        """``(channels, window)`` of the observations the network reads, in its task."""
        task = self.task.playing(self)
        return task.num_channels, task.window

    def env_config(self, *, evaluation: bool = False) -> EnvConfig:
        """The training environment, or (``evaluation``) the test protocol's: no symmetry (views numbered as in
        any other unrotated ``MapSet``), the evaluation step budget and split, no training aid (shaping,
        far-start curriculum, city weights)."""
        blind = self.agent == "blind"
        if evaluation:
            update = {"rotate": False, "symmetries": 4, "t_max": self.eval_t_max, "split": self.eval_split}
            update |= {"shaping": 0.0, "far_starts": 0.0, "city_weights": {}}
            return self.env.model_copy(update={"blind": blind} | update)
        return self.env.model_copy(update={"blind": blind, "shaping_gamma": self.gamma})


PRESETS: dict[str, dict] = {
    # The paper's agent (docs/method.md): batch 20, an update per 3 env steps, 5e5 replay, gamma 0.99,
    # epsilon 1 -> 0 over the run, t_max 800 in training, about 7 M steps.
    "paper": {},
    # Minutes on a CPU: for tests, CI and smoke runs.
    "fast": {
        "total_steps": 40_000,
        "num_envs": 16,
        "buffer_size": 40_000,
        "batch_size": 64,
        "train_every": 8,
        "learning_starts": 2_000,
        "n_step": 3,
        "lr_start": 1e-3,
        "lr_end": 1e-4,
        "target_update": 2_000,
        "eps_end": 0.05,
        "eps_fraction": 0.5,
        "hidden": 128,
        "conv_channels": (16, 32, 32),
        "eval_every": 10_000,
        "eval_episodes": 100,
        "env": {"t_max": 200, "rotate": True},
    },
    # The foveated network, 64 envs acting in one batch, 3-step returns, batches of 128 every 16 env steps, no
    # dropout, the visited-cells channel, a success bonus of 100, best.pt chosen on 1000 fixed validation episodes, a
    # revisit penalty of 1 per earlier visit when acting, and an auxiliary head that learns the genie's move (training
    # only). How each setting was chosen: experiments/log/learner.md.
    "best-dqn": {
        "total_steps": 300_000,
        "num_envs": 64,
        "buffer_size": 200_000,
        "batch_size": 128,
        "train_every": 16,
        "learning_starts": 10_000,
        "n_step": 3,
        "lr_start": 5e-4,
        "lr_end": 5e-5,
        "target_update": 10_000,
        "eps_end": 0.02,
        "eps_fraction": 0.3,
        "network": "fovea",
        "hidden": 256,
        "dropout": 0.0,
        "eval_every": 50_000,
        "eval_episodes": 1000,
        "test_revisit_penalty": 1.0,
        "aux_genie": 1.0,
        "env": {"t_max": 300, "rotate": True, "visited_channel": True, "success_bonus": 100.0},
    },
}
# best-dqn learnt by PQN (rl/agent/pqn.py) instead of replay DQN: rollouts of 128 envs x 16 moves, Q(lambda 0.65)
# returns, 4 epochs of batches of 128, layer norm, no replay and no target network (best-dqn's replay fields stay,
# unread).
PRESETS["best-pqn"] = PRESETS["best-dqn"] | {
    "learner": "pqn",
    "num_envs": 128,
    "rollout_steps": 16,
    "epochs": 4,
    "layer_norm": True,
}
# Ours: best-pqn with a GRU cell before the heads (a memory of the episode beyond the window), the homing channel (the
# best SINR measured so far as a cone around its cell), the revisit penalty in its training moves too, discounting at
# 0.98, learnt on rollouts of 32 moves in 64 envs. The shipped agent is three seeds of it as one (`uavrl ensemble`).
PRESETS["best"] = PRESETS["best-pqn"] | {
    "recurrent": True,
    "num_envs": 64,
    "rollout_steps": 32,
    "train_revisit_penalty": 1.0,
    "gamma": 0.98,
    "env": PRESETS["best-pqn"]["env"] | {"homing_channel": True},
}
# The hybrid of the map searcher and the learner (docs/searcher.md): best with the searcher's belief as a channel.
PRESETS["hybrid"] = PRESETS["best"] | {"env": PRESETS["best"]["env"] | {"belief_channel": True}}


#: What a preset changes when it learns a task without placement's revisit penalty (``RunTask.revisits``, tracking): a
#: user who moves brings the UAV back to cells it has stood in.
NO_REVISITS = {"train_revisit_penalty": 0.0, "test_revisit_penalty": 0.0}
#: The nested configs ``--set PART.FIELD=VALUE`` reaches.
NESTED = {"env": EnvConfig.model_fields} | {
    t.settings.prefix: {k: f for k, f in t.settings.model_fields.items() if k != "kind"}
    for t in TASKS.values()
    if t.settings.prefix
}


def parse_settings(settings: list[str] | tuple[str, ...]) -> dict:
    """``["lr_start=1e-3", "env.shaping=1"]`` -> ``{"lr_start": 1e-3, "env": {"shaping": 1}}`` (values as JSON
    where they parse, else strings); ``InputError`` naming the setting that has no ``=`` or an unknown field."""
    out: dict = {}
    for item in settings:
        key, sep, raw = item.partition("=")
        parts = key.strip().split(".")
        known = DQNConfig.model_fields if len(parts) == 1 else NESTED.get(parts[0], {})
        if not sep or len(parts) > 2 or parts[-1] not in known:
            raise InputError(
                None,
                f"{item!r}: expected FIELD=VALUE or PART.FIELD=VALUE (PART one of {', '.join(NESTED)}) with a known field",
                field="set",
            )
        try:
            value = json.loads(raw)
        except ValueError:
            value = raw
        (out.setdefault(parts[0], {}) if len(parts) == 2 else out)[parts[-1]] = value
    return out


def preset_config(name: str, **overrides: object) -> DQNConfig:
    """A preset's ``DQNConfig`` with ``overrides`` (an ``env`` dict overrides single env fields);
    ``InputError`` when a value does not validate."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r} (known: {', '.join(PRESETS)})")
    default_env = DQNConfig.model_fields["env"].default_factory().model_dump()  # type: ignore[misc]
    env = default_env | dict(PRESETS[name].get("env", {})) | dict(overrides.pop("env", None) or {})  # type: ignore[arg-type]
    given = {t.settings.prefix: overrides.pop(t.settings.prefix, None) for t in TASKS.values() if t.settings.prefix}
    values = dict(PRESETS[name]) | {"preset": name} | overrides | {"env": env}
    task = TASKS.get(str(values.pop("task", "placement")))
    if task is None:
        raise InputError(None, f"unknown task (known: {', '.join(TASKS)})", field="task")
    for field, value in given.items():
        if value and task.settings.prefix != field:
            raise InputError(None, f"{field} settings are for --task {field}", field=field)
    if not task.settings.revisits:  # the preset's learner without placement's loop breaker
        values = values | NO_REVISITS | {k: overrides[k] for k in NO_REVISITS if k in overrides}
    try:
        # the preset's training rotation (env.rotate) for the task too, unless its own rotate says otherwise
        rotate = {"rotate": env["rotate"]} if "rotate" in task.settings.model_fields else {}
        values["task"] = task.settings(**(rotate | (given.get(task.settings.prefix) or {})))
        return DQNConfig(**(values | {"env": EnvConfig(**env)}))
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise InputError(None, message, field=field) from None

"""`uavrl report`: the paper's evaluation protocol on a test city, and a self-contained HTML report.

The recipe (``make_report``):

1. load the test city's bundle and every agent (a run folder or a shipped agent folder);
2. draw the episodes once (seeded): a uniformly random user, then a uniformly random valid start;
3. play them with every method (the learned agents, the genie, the steered random walk, greedy
   hill-climbing), batched, the same episodes for all;
4. tabulate success rate and steps to P_T with paired bootstrap 95 % intervals, beside the paper's;
5. draw the CDF of steps to P_T, the training curves, a few trajectories;
6. write ``report.html`` (figures embedded), the PNGs, the tables (CSV and Parquet), every
   episode (Parquet) and ``report.json`` (config and provenance) into a temporary folder that is
   renamed into place.
"""

from __future__ import annotations

import base64
import datetime as dt
import functools
import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from pydantic import Field

from uavplace.dataset.bundle import Bundle, load_bundle, read_manifest, resolve
from uavplace.dataset.difficulty import valid_starts
from uavplace.eval.metrics import STATS, bootstrap_table, difference_table, ecdf, format_stat, group_tables
from uavplace.rl.agent.checkpoint import load_tensors
from uavplace.rl.agent.dqn import DQNConfig
from uavplace.rl.agent.train import (
    RUN_JSON,
    RunRecord,
    policy_from_checkpoint,
    read_run_json,
    settings_unlike,
    training_users,
)
from uavplace.rl.config import EnvConfig
from uavplace.rl.maps import MapSet
from uavplace.rl.policies import GeniePolicy, GreedyPolicy, Policy, RandomWalkPolicy
from uavplace.rl.rollout import run_episodes, summarise
from uavplace.rl.searcher import (
    DEFAULT_PREDICTOR,
    PREDICTIONS,
    SEARCHER,
    MapSearchPolicy,
    PredictionCache,
    SearchConfig,
    load_predictor,
)
from uavplace.schemas import InputError
from uavplace.schemas.base import MAX_SEED, Contract, uavplace_version
from uavplace.schemas.bundle import BundleManifest
from uavplace.schemas.files import atomic_directory, atomic_write_text, check_replaceable

#: The paper's test-city results (docs/method.md, "The paper's results"): success within t_max = 500, median steps.
PAPER = {
    "dqn": {"row": "proposed", "success": 0.90, "median_steps": 44.0},
    "blind": {"row": "blind", "success": 0.66, "median_steps": 69.0},
    "genie": {"row": "genie", "success": 1.00, "median_steps": 14.0},
}
BASELINES = (GeniePolicy.name, RandomWalkPolicy.name, GreedyPolicy.name)
#: Episodes in the training curves' running mean (the paper's 100).
RUNNING_WINDOW = 100
#: A report folder's marker: only a folder holding it is ever replaced.
REPORT_JSON = "report.json"


class ReportConfig(Contract):
    """How a report was made (saved in ``report.json``)."""

    dataset: str = Field(description="Test city (a built dataset, optionally city@version)")
    runs: list[str] = Field(default_factory=list, description="Agent folders (run folders or shipped agents)")
    episodes: int = Field(default=1000, ge=1, description="Episodes, the same for every method")
    t_max: int = Field(default=500, ge=1, description="Step budget per episode (paper: 500 at test)")
    p_t_db: float = Field(default=5.0, description="SINR target P_T [dB]")
    test_epsilon: float = Field(default=0.096, ge=0, le=1, description="Random legal move rate of the agents (paper: 0.096)")
    seed: int = Field(
        default=0, ge=0, le=MAX_SEED, description="Seed of the episodes, the agents' random moves and the baselines"
    )
    n_boot: int = Field(default=2000, ge=100, description="Bootstrap resamples for the 95 % intervals")
    trajectories: int = Field(
        default=3, ge=0, le=3, description="Episodes drawn for the first agent, by TRAJECTORY_RULES in order (0: none)"
    )
    split: str | None = Field(default=None, description="Users of this split only (None: all users of the city)")
    groups: dict[str, list[str]] = Field(
        default_factory=dict,
        description="Methods made of several runs (a preset's seeds): name -> run folders, each also one of ``runs``",
    )
    predictor: str | None = Field(
        default=str(DEFAULT_PREDICTOR),
        description="The map searcher's predictor: the physics tier's constants (a JSON file) or a learned tier (a folder; rl.searcher.load_predictor); None: no searcher is played",
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


@dataclass
class Agent:
    """A trained policy and where it came from."""

    name: str
    folder: Path
    config: DQNConfig
    run: RunRecord | None  # run.json (None: a bare checkpoint folder)
    policy: Policy
    best_eval: dict | None  # the evaluation that chose best.pt
    metrics: pd.DataFrame | None  # metrics.parquet: one row per training episode (None: not shipped)

    @property
    def trained_on(self) -> dict[str, str]:
        """Training city -> bundle version (empty when unknown)."""
        return dict(self.run.datasets) if self.run is not None else {}

    @property
    def selected_on(self) -> dict[str, str]:
        """Validation city -> bundle version: where best.pt was chosen (empty when unknown or none)."""
        return dict(self.run.val_datasets) if self.run is not None else {}


@dataclass
class Report:
    out: Path
    table: pd.DataFrame  # bootstrap_table + paper columns
    differences: pd.DataFrame  # difference_table against the references (the blind paper agent, the genie)
    episodes: pd.DataFrame  # every method's episodes, with a "method" column
    config: ReportConfig
    rows: list[list[str]]  # the table as text (table_rows)
    diff_rows: list[list[str]]  # the differences as text (difference_rows)
    figures: dict[str, Figure | None]  # in the report folder
    provenance: dict  # report.json
    group_rows: list[list[str]] | None = None  # the groups of seeds as text (group_rows), when --group was given


def agent_name(config: DQNConfig) -> str:
    """The method's name in tables: the paper's ``DQN`` and ``blind DQN``, or the learner that trained it (``PQN``,
    ``+ GRU`` for a recurrent core, ``x N`` for an ensemble of N runs), then the preset (and the tracking task):
    ``DQN (paper)``, ``PQN + GRU (best)``, ``PQN + GRU x 3 (best)``, ``PQN + GRU (best, tracking)``."""
    learner = "PQN" if config.learner == "pqn" else "DQN"
    core = " + GRU" if config.recurrent else ""
    members = f" x {config.ensemble}" if config.ensemble > 1 else ""
    task = ", tracking" if config.task == "tracking" else ""
    return f"{'' if config.agent == 'dqn' else 'blind '}{learner}{core}{members} ({config.preset}{task})"


def has_record(folder: Path) -> bool:
    """Whether ``folder`` holds a ``run.json`` entry of any kind: read (and refused when it is not a regular file) by
    ``read_run_json``, never taken for a bare checkpoint folder."""
    return os.path.lexists(folder / RUN_JSON)


def load_agent(folder: str | Path, epsilon: float, seed: int, task: str | None = "placement") -> Agent:
    """A run folder (``run.json`` + ``checkpoints/best.pt``) as an evaluable agent; ``InputError`` if it is not one,
    or if it learnt another task than ``task`` (None: either)."""
    folder = Path(folder)
    ckpt = folder / "checkpoints" / "best.pt"
    if not ckpt.is_file():
        raise InputError(folder, "no checkpoints/best.pt (not a training run, or it never evaluated)")
    run = read_run_json(folder) if has_record(folder) else None  # a run.json that is no file is refused there
    ck = load_tensors(ckpt)
    policy, config = policy_from_checkpoint(ck, ckpt, epsilon=epsilon, seed=seed)
    if run is not None and run.config.model_dump() != config.model_dump():
        held, played = run.config.model_dump(), config.model_dump()
        differ = [k for k in held if held[k] != played[k]]
        raise InputError(folder / RUN_JSON, f"its config is not the one checkpoints/best.pt was trained with ({', '.join(differ)} "
                         "differ): the report would describe another agent than it plays", field="config")  # fmt: skip
    if task is not None and config.task != task:
        how = "`uavrl report --task tracking`" if config.task == "tracking" else "a placement report"
        raise InputError(folder, f"a {config.task} agent, not a {task} one: {how} plays it", field="task")
    policy.name = agent_name(config)
    metrics = None
    if (folder / "metrics.parquet").is_file():
        try:
            metrics = pd.read_parquet(folder / "metrics.parquet")
        except (OSError, ValueError) as exc:
            raise InputError(folder / "metrics.parquet", f"unreadable ({str(exc)[:160]})") from None
    return Agent(policy.name, folder, config, run, policy, ck.get("eval"), metrics)


def default_agents(root: str | Path = "data/agents", task: str | None = "placement") -> list[Path]:
    """The shipped agents: every folder under ``root`` with a ``checkpoints/best.pt``, in name order; those that
    learnt ``task`` (by their ``run.json``; None: every agent, as the tracking report plays placement agents too)."""
    root = Path(root)
    found = sorted(p for p in root.iterdir() if (p / "checkpoints" / "best.pt").is_file()) if root.is_dir() else []
    return [p for p in found if task is None or not has_record(p) or read_run_json(p).config.task == task]


def unlike_training(runs: list[Path], datasets: list[str], root: str | Path, p_t_db: float) -> list[str]:
    """One line per (run, city) where the run's agent would play a bundle built with settings none of its training
    cities had (grid, altitude, noise: ``run.json``'s ``bundle_settings``), or at another P_T than it was trained
    at. A run that records no settings (older than the record, or a bare checkpoint) is not judged."""
    manifests = [read_manifest(resolve(d, root=root)) for d in datasets]
    lines = []
    for run in runs:
        record = read_run_json(run) if has_record(Path(run)) else None
        if record is None or not record.bundle_settings:
            continue
        for manifest in manifests:
            unlike = settings_unlike(record, manifest, p_t_db)
            if unlike:
                lines.append(f"{Path(run).name} on {manifest.city}@{manifest.version}: {'; '.join(unlike)}: the agent "
                             "plays outside what it was trained on")  # fmt: skip
    return lines


def evaluate(
    config: ReportConfig,
    bundle: Bundle,
    agents: list[Agent],
    on_progress: Callable[[str, int, int], None] | None = None,
    baselines: list[Policy] | None = None,
    seen: Callable[[MapSet], None] | None = None,
    episodes: np.ndarray | None = None,
) -> dict[str, pd.DataFrame]:
    """Play the same ``config.episodes`` episodes with every method; ``{method: run_episodes frame}``.

    Each agent plays in the environment it was trained for (its window, channels, memory values)
    with the report's ``t_max`` and ``P_T``; the episodes are drawn once from the users of the city.
    ``baselines``: the policies played beside the agents (default: ``baseline_policies``). ``seen``: applied to
    each agent's maps before it plays (e.g. ``MapSet.show_buildings``: what the agents see, not where they move).
    ``episodes``: the specs to play (``MapSet.sample_episodes`` of the city's maps at the report's settings, e.g. drawn
    on a twin city and kept where ``can_start``), instead of the ``config.episodes`` drawn with ``config.seed``.
    """
    base = EnvConfig(t_max=config.t_max, p_t_db=config.p_t_db, split=config.split, rotate=False)
    maps = {"": MapSet([bundle], base)}
    if episodes is None:
        episodes = maps[""].episode_list(config.episodes, config.seed)  # as `uavrl baselines`
    elif not maps[""].can_start(episodes).all():
        raise ValueError("evaluate: an episode given does not start on a start cell of this city")
    shown = shown_method(agents)
    record = np.arange(len(episodes)) if config.trajectories else None  # the rule picks among all episodes
    methods: list[tuple[str, Policy, MapSet]] = []
    for a in agents:
        env = a.config.env_config(evaluation=True).model_copy(
            update={"t_max": config.t_max, "p_t_db": config.p_t_db, "split": config.split}
        )
        key = env.model_dump_json()
        if key not in maps:
            maps[key] = MapSet([bundle], env)
            if seen is not None:
                seen(maps[key])
        methods.append((a.name, a.policy, maps[key]))
    if baselines is None:
        baselines = baseline_policies(config, base, cache=config.prediction_cache or bundle.path.parent.parent / PREDICTIONS)
    methods += [(p.name, p, maps[""]) for p in baselines]
    names = [m[0] for m in methods]
    if len(set(names)) != len(names):
        raise ValueError(f"two methods share a name: {names}")
    results = {}
    for name, policy, mapset in methods:
        report = None if on_progress is None else (lambda done, total, name=name: on_progress(name, done, total))
        specs = mapset.episodes_from(episodes, maps[""])  # an agent's window pads its canvas by another margin
        results[name] = run_episodes(mapset, policy, specs, on_step=report, record=record if name == shown else None)
    return results


def baseline_policies(config: ReportConfig, env: EnvConfig, cache: str | Path | None = None) -> list[Policy]:
    """The genie, the steered random walk and greedy hill-climbing, seeded as the report is (their names are the
    table's); then, with ``config.predictor``, the map searcher and its ablation shown no building (``rl.searcher``), their
    predicted maps kept in ``cache`` (None: not on disk)."""
    out: list[Policy] = [GeniePolicy(), RandomWalkPolicy(seed=config.seed), GreedyPolicy(env.p_h_db, seed=config.seed)]
    if config.predictor is not None:
        predictor = load_predictor(config.predictor)
        cache = PredictionCache(cache)
        for buildings in (True, False):
            out.append(MapSearchPolicy(predictor, config.search.model_copy(update={"buildings": buildings}), cache))
    return out


def results_table(results: dict[str, pd.DataFrame], config: ReportConfig) -> pd.DataFrame:
    """``bootstrap_table`` plus the paper's success and median steps where the paper has the method."""
    table = bootstrap_table(results, n_boot=config.n_boot, seed=config.seed)
    paper_key = {name: _paper_key(name) for name in table["method"]}
    table["paper_success"] = [PAPER[k]["success"] if k else np.nan for k in paper_key.values()]
    table["paper_median_steps"] = [PAPER[k]["median_steps"] if k else np.nan for k in paper_key.values()]
    return table


#: The suffix of a method played with the building map blanked, and the reference column of its cost.
NO_BUILDINGS, WITH_BUILDINGS = ", no buildings", "the same with buildings"


def _blanked(config: ReportConfig, bundle: Bundle, agents: list[Agent], on_progress) -> dict[str, pd.DataFrame]:  # noqa: ANN001
    """The agents that read the building map, played again on the same episodes with the map blanked."""
    sighted = [a for a in agents if not a.config.env_config(evaluation=True).blind]  # a blind agent reads no map
    readers = [load_agent(a.folder, config.test_epsilon, config.seed) for a in sighted]
    for reader, agent in zip(readers, sighted, strict=True):
        reader.name = reader.policy.name = agent.name + NO_BUILDINGS
    if not readers:
        return {}
    return evaluate(config, bundle, readers, on_progress, baselines=[], seen=lambda m: m.show_buildings(None))


def ablation_table(results: dict[str, pd.DataFrame], config: ReportConfig) -> pd.DataFrame:
    """The map ablation's cost: for every method ``X`` played also as ``X, no buildings``, the paired difference
    ``(X, no buildings) - X``, its reference named ``WITH_BUILDINGS`` (a column of its own in the differences)."""
    parts = []
    for name in results:
        if name.endswith(NO_BUILDINGS) and name[: -len(NO_BUILDINGS)] in results:
            plain = name[: -len(NO_BUILDINGS)]
            d = difference_table({plain: results[plain], name: results[name]}, [plain], n_boot=config.n_boot,
                                 seed=config.seed)  # fmt: skip
            parts.append(d[d["method"] == name].assign(against=WITH_BUILDINGS))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def references(methods: list[str]) -> list[str]:
    """What every method is compared with, in order: the paper's blind agent (the baseline of the paper's claim), the
    genie (the bound), the shipped best learner and the map searcher (its ablation's cost is the difference)."""
    blind = [m for m in methods if m.startswith("blind ") and m.endswith("(paper)")]
    best = [m for m in methods if m.endswith("(best)") and not m.startswith("blind ")]
    return blind + [m for m in methods if m == "genie"] + best + [m for m in methods if m == SEARCHER]


def difference_rows(differences: pd.DataFrame, t_max: int) -> list[list[str]]:
    """The paired differences as text cells (header first): per method, success and median steps minus each reference."""
    refs = list(dict.fromkeys(differences["against"]))
    header = ["method", *(f"{label} - {ref}" for ref in refs for label in ("success", "median steps"))]
    rows = [header]
    for method, group in differences.groupby("method", sort=False):
        cells = [str(method)]
        for ref in refs:
            for stat in ("success", "median_steps"):
                r = group[(group["against"] == ref) & (group["stat"] == stat)]
                cells.append("-" if r.empty else _difference_cell(stat, r.iloc[0]))
        rows.append(cells)
    return rows


def groups_of(config: ReportConfig, agents: list[Agent]) -> dict[str, list[str]]:
    """``config.groups`` with each run folder replaced by its agent's name in the results."""
    by_folder = {str(Path(r)): a.name for r, a in zip(config.runs, agents, strict=True)}
    return {g: [by_folder[str(Path(r))] for r in runs] for g, runs in config.groups.items()}


def group_rows(
    table: pd.DataFrame, differences: pd.DataFrame, groups: dict[str, list[str]], *, references_too: bool = False
) -> list[list[str]]:
    """``group_tables`` as text cells (header first): each group's runs, success and median steps (mean over its runs,
    interval, the runs' range), then each difference against a reference (the references' own rows only with
    ``references_too``)."""
    refs = list(dict.fromkeys(differences["against"]))
    header = ["group", "runs", "success", "median steps",
              *(f"{label} - {ref}" for ref in refs for label in ("success", "median steps"))]  # fmt: skip
    rows = [header]
    for group in (g for g in groups if references_too or g not in refs):
        cells = [group, ", ".join(groups[group])]
        for stat in ("success", "median_steps"):
            r = table[(table["group"] == group) & (table["stat"] == stat)].iloc[0]
            scale, unit = (100, " %") if stat == "success" else (1, "")
            value = (
                "undefined"
                if np.isnan(r["value"])
                else f"{scale * r['value']:.1f}{unit} [{scale * r['lo']:.1f}, {scale * r['hi']:.1f}]"
            )
            spec = ".1f" if stat == "success" else "g"
            cells.append(f"{value} ({scale * r['run_min']:{spec}}-{scale * r['run_max']:{spec}})")
        for ref in refs:
            for stat in ("success", "median_steps"):
                r = differences[(differences["group"] == group) & (differences["against"] == ref) & (differences["stat"] == stat)]
                cells.append("-" if r.empty else _difference_cell(stat, r.iloc[0]))
        rows.append(cells)
    return rows


def _difference_cell(stat: str, r: pd.Series) -> str:
    if np.isnan(r["difference"]):
        return f"undefined ({100 * r['undefined_share']:.0f} % of resamples: a median beyond t_max)"
    if stat == "success":
        return f"{100 * r['difference']:+.1f} points [{100 * r['lo']:+.1f}, {100 * r['hi']:+.1f}]"
    values = (r["difference"], r["lo"], r["hi"])
    if all(float(v).is_integer() for v in values):  # one run's medians: whole steps
        return f"{r['difference']:+g} [{r['lo']:+g}, {r['hi']:+g}]"
    return f"{r['difference']:+.1f} [{r['lo']:+.1f}, {r['hi']:+.1f}]"  # a mean over runs


def _paper_key(method: str) -> str | None:
    if method.endswith(NO_BUILDINGS):  # the paper played no method on a blanked map
        return None
    if method == "genie":
        return "genie"
    if not method.endswith("(paper)"):  # the paper's numbers stand beside the paper's agents only
        return None
    return "blind" if method.startswith("blind ") else "dqn"


def shown_method(agents: list[Agent]) -> str:
    """The method whose trajectories the report draws: the first agent, else the genie."""
    return agents[0].name if agents else "genie"


def upper_bound_db(bundles: list[Bundle], p_t_db: float) -> float:
    """The paper's training bound on the mean SINR gain: mean over users, then start cells, of P_T - start SINR.

    Users and starts as training draws them (``rl.agent.train.training_users``) with at least one
    valid start (``dataset.difficulty.valid_starts``).
    """
    per_user = []
    for b in bundles:
        for u in training_users(b):
            starts = valid_starts(b.blocked, b.dead[u], b.sinr_db[u], p_t_db)
            if starts.any():
                per_user.append(float(np.mean(p_t_db - b.sinr_db[u][starts])))
    return float(np.mean(per_user))


# -- figures --------------------------------------------------------------------------------------
def _pyplot():
    """pyplot off-screen, with text taken as it is: a name with ``$`` (a run folder's) is never parsed as mathtext."""
    import matplotlib

    matplotlib.use("Agg")
    matplotlib.rcParams["text.parse_math"] = False
    import matplotlib.pyplot as plt

    return plt


def plot_cdf(results: dict[str, pd.DataFrame], t_max: int, out: Path) -> Figure:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9.5, 4.8), constrained_layout=True)
    for name, df in results.items():
        s, f = ecdf(df, t_max)
        ax.step(s, f, where="post", label=f"{name} ({100 * f[-1]:.1f} %)", linewidth=1.3 if name in BASELINES else 2.0)
    ax.set_xscale("symlog", linthresh=10)
    ax.set_xlim(0, t_max)
    ticks = [t for t in (0, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000) if t <= t_max]
    ax.set_xticks(ticks, [str(t) for t in ticks])
    ax.set_ylim(0, 1.01)
    ax.set_xlabel("steps to reach P_T (linear to 10, logarithmic above)")
    ax.set_ylabel("share of episodes that reached P_T")
    n = len(next(iter(results.values())))
    ax.set_title(f"CDF of steps to P_T ({n} episodes, t_max {t_max})")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, title="method (success within t_max)", title_fontsize=8)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    caption = (
        f"Share of the {n} episodes that reached P_T within a given number of steps, one curve per method, all "
        f"methods on the same episodes (users drawn uniformly, then start cells uniformly among the legal live cells "
        f"below P_T). A curve ends at t_max = {t_max}; its height there is the method's success rate (in the legend)."
    )
    return Figure(out, caption)


def by_episode_start(metrics: pd.DataFrame, num_envs: int, t_max: int) -> pd.DataFrame:
    """Training episodes (``metrics.parquet`` rows, logged when they end) ordered by the step at which they started
    (``start``: the end step less ``length`` moves of ``num_envs`` steps each), without those started after the last
    step that guarantees every episode begun by then had ended (``t_max`` moves before the log's end)."""
    start = metrics["step"].to_numpy() - metrics["length"].to_numpy() * num_envs
    out = metrics.assign(start=start).sort_values("start", kind="stable")
    return out[out["start"] <= metrics["step"].max() - t_max * num_envs].reset_index(drop=True)


def plot_training(agents: list[Agent], bounds: dict[str, float], out: Path, notes: dict[str, str] | None = None) -> Figure | None:
    """One row per agent, on its own step axis: the success rate and the mean SINR gain of its last 100 training episodes."""
    curves = [a for a in agents if a.metrics is not None and len(a.metrics)]
    if not curves:
        return None
    plt = _pyplot()
    fig, axes = plt.subplots(len(curves), 2, figsize=(11, 2.9 * len(curves)), constrained_layout=True, squeeze=False)
    for (ax_ok, ax_gain), a in zip(axes, curves, strict=True):
        # An ensemble's metrics hold each member's training episodes (a ``member`` column): one curve per member.
        runs = a.metrics.groupby("member", sort=False) if "member" in a.metrics else [(None, a.metrics)]
        for member, df in runs:
            df = by_episode_start(df, a.config.num_envs, a.config.env.t_max)
            full = np.arange(len(df)) >= RUNNING_WINDOW - 1  # the window holds 100 episodes from here on
            for ax, column, scale in ((ax_ok, "success", 100.0), (ax_gain, "sinr_gain_db", 1.0)):
                rolling = scale * df[column].astype(float).rolling(RUNNING_WINDOW, min_periods=1).mean()
                line = ax.plot(df["start"][full], rolling[full], linewidth=1.6, label=member)[0]
                ax.plot(df["start"][:RUNNING_WINDOW], rolling[:RUNNING_WINDOW], color=line.get_color(), alpha=0.3, linewidth=1)
        for ax in (ax_ok, ax_gain):
            ax.grid(alpha=0.3)
            ax.set_xlabel("training step at the episode's start")
        if "member" in a.metrics:
            ax_ok.legend(fontsize=7, loc="lower right", title="members", title_fontsize=7)
        key = ", ".join(f"{c}@{v}" for c, v in a.trained_on.items())
        if key in bounds:
            ax_gain.axhline(bounds[key], color="black", linestyle="--", linewidth=1,
                            label=f"every episode ends exactly at P_T ({bounds[key]:.1f} dB)")  # fmt: skip
            ax_gain.legend(fontsize=7, loc="lower right")
        env = a.config.env
        ax_ok.set_ylim(0, 100)
        ax_ok.set_ylabel("success, last 100 [%]")
        ax_gain.set_ylabel("SINR gain, last 100 [dB]")
        ax_ok.set_title(
            f"{a.name}: t_max {env.t_max}, {a.config.total_steps:,} steps, epsilon {a.config.eps_start:g} -> {a.config.eps_end:g}",
            fontsize=9,
        )
        ax_gain.set_title(f"{a.name}: SINR at the end - SINR at the start", fontsize=9)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    where = "; ".join(f"{k}: {v}" for k, v in (notes or {}).items())
    caption = (
        f"Training curves, one row per agent on its own step axis: the share of successful training episodes (left) "
        f"and the mean SINR gain (final minus start SINR; right), each over the last {RUNNING_WINDOW} training episodes "
        f"by the step at which they started (faint: the first {RUNNING_WINDOW - 1} episodes, a partial window). By start, "
        f"not by end: the first episodes to end are the quick successes, since a failure lasts t_max; the curves stop "
        f"where episodes started later might not have ended when training did. Training episodes explore (epsilon in the "
        f"title) and stop at the training t_max. Dashed: the paper's training bound, the mean over training users and "
        f"start cells of P_T - start SINR, i.e. the gain if every episode ended exactly at P_T; a successful episode "
        f"ends on the first cell at or above P_T, so the curve can pass it." + (f" Bound computed on: {where}." if where else "")
    )
    return Figure(out, caption)


#: How the trajectories figure picks the shown agent's episodes, in order (``ReportConfig.trajectories`` of them):
#: rule name -> what it picks (``longest success`` stands in for ``failure`` when the agent never fails).
TRAJECTORY_RULES = {
    "median": "median: the success whose steps are closest to the agent's median steps to P_T",
    "p90": "p90: the success at the 90th percentile of the successes' steps",
    "failure": "failure: the first failed episode (none: the longest success)",
}
TRAJECTORY_RULES["longest success"] = TRAJECTORY_RULES["failure"]


def pick_trajectories(results: dict[str, pd.DataFrame], agent: str, count: int) -> list[tuple[int, str]]:
    """``(episode, rule name)`` for the first ``count`` of ``TRAJECTORY_RULES``, distinct episodes (ties: the lowest
    number); a rule with no episode to show (no success, no failure) is skipped."""
    df = results[agent]
    ok = df[df["success"]].sort_values(["steps", "episode"])
    failed = df[~df["success"]].sort_values("episode")
    picks: list[tuple[int, str]] = []

    def add(episode: int, rule: str) -> None:
        if episode not in [e for e, _ in picks]:
            picks.append((int(episode), rule))

    if len(ok):
        median = summarise(df)["median_steps"]
        median = median if np.isfinite(median) else float(ok["steps"].max())
        add(ok.assign(d=(ok["steps"] - median).abs()).sort_values(["d", "episode"])["episode"].iloc[0], "median")
        p90 = np.quantile(ok["steps"].to_numpy(), 0.9, method="inverted_cdf")
        add(ok[ok["steps"] == p90]["episode"].iloc[0], "p90")
    if len(failed):
        add(failed["episode"].iloc[0], "failure")
    elif len(ok):
        add(ok["episode"].iloc[-1], "longest success")
    return picks[:count]


def plot_trajectories(
    bundle: Bundle, results: dict[str, pd.DataFrame], agent: str, picks: list[tuple[int, str]], p_t_db: float, out: Path
) -> Figure | None:
    if not picks:
        return None
    plt = _pyplot()
    import matplotlib
    from matplotlib import patheffects
    from matplotlib.lines import Line2D

    df = results[agent].set_index("episode")
    g = bundle.manifest.grid
    extent = (g.x_min_m, g.x_max_m, g.y_min_m, g.y_max_m)
    fig, axes = plt.subplots(2, len(picks), figsize=(4.2 * len(picks), 8.2), constrained_layout=True, squeeze=False)
    for j, (ep, rule) in enumerate(picks):
        row = df.loc[ep]
        user = int(row["user"])
        cells = results[agent].attrs["paths"][ep]  # [T + 1, 2] (iy, ix) map cells
        px = g.x_min_m + (cells[:, 1] + 0.5) * g.spacing_m
        py = g.y_min_m + (cells[:, 0] + 0.5) * g.spacing_m
        urow = bundle.users.iloc[user]
        outcome = f"{int(row['steps'])} steps" if row["success"] else f"P_T not reached in {int(row['steps'])} steps"
        for i, ax in enumerate(axes[:, j]):
            if i == 0:
                im = ax.imshow(bundle.height_rel_m, origin="lower", extent=extent, cmap="viridis")
                ax.set_title(f"{rule}: episode {ep}, user {user}\n{outcome} (genie {int(row['genie_steps'])})", fontsize=10)
                label = "building height - altitude [m]"
            else:
                # Open cells only: dead ones grey (masked), blocked ones drawn apart in black, never as flyable SINR.
                sinr = np.ma.masked_array(bundle.sinr_db[user], mask=bundle.dead[user] | bundle.blocked)
                im = ax.imshow(sinr, origin="lower", extent=extent, cmap=matplotlib.colormaps["magma"].with_extremes(bad="0.75"))
                ax.imshow(np.ma.masked_array(np.ones(bundle.shape), mask=~bundle.blocked), origin="lower", extent=extent,
                          cmap=matplotlib.colors.ListedColormap(["0.05"]), vmin=0, vmax=1)  # fmt: skip
                target = (bundle.sinr_db[user] >= p_t_db) & ~bundle.dead[user] & ~bundle.blocked
                ax.contour(target, levels=[0.5], origin="lower", extent=extent, colors="cyan", linewidths=0.8)
                label = "SINR [dB]"
            for color, width in (("black", 1.6), ("white", 0.6)):  # a white line on a black one: seen on any colour
                ax.contour(bundle.blocked, levels=[0.5], origin="lower", extent=extent, colors=color, linewidths=width)
            ax.plot(px, py, color="red", linewidth=1.4)
            ax.plot(px[0], py[0], "o", color="lime", markeredgecolor="black")
            ax.plot(px[-1], py[-1], "s", color="red", markeredgecolor="black")
            if np.isfinite(urow["x_m"]) and np.isfinite(urow["y_m"]):
                ax.plot(urow["x_m"], urow["y_m"], "*", color="cyan", markersize=13, markeredgecolor="black")
            ax.set_xlabel("x [m]", fontsize=10)
            ax.set_ylabel("y [m]", fontsize=10)
            ax.tick_params(labelsize=9)
            fig.colorbar(im, ax=ax, shrink=0.8).set_label(label, fontsize=9)
    handles = [
        Line2D([], [], color="red", linewidth=1.4, label="UAV path"),
        Line2D([], [], marker="o", color="lime", markeredgecolor="black", linestyle="", label="start"),
        Line2D([], [], marker="s", color="red", markeredgecolor="black", linestyle="", label="end"),
        Line2D([], [], marker="*", color="cyan", markersize=11, markeredgecolor="black", linestyle="", label="user"),
        Line2D(
            [],
            [],
            color="white",
            linewidth=1,
            path_effects=[patheffects.withStroke(linewidth=2.6, foreground="black")],
            label="building edge (blocked)",
        ),
        Line2D([], [], color="cyan", linewidth=1, label=f"P_T = {p_t_db:g} dB contour"),
    ]
    legend = fig.legend(handles=handles, loc="outside lower center", ncol=6, fontsize=10, facecolor="0.85")
    legend.get_frame().set_edgecolor("0.5")
    fig.suptitle(f"{agent} in {bundle.city}", fontsize=12)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    n = len(df)
    caption = (
        f"{agent}: {len(picks)} of its {n} episodes in {bundle.city}, chosen by rule, not by eye: "
        + "; ".join(dict.fromkeys(TRAJECTORY_RULES[rule] for _, rule in picks))
        + ". Top: building height minus the flight altitude (blocked cells, where buildings rise above the UAV, inside "
        "the white-on-black edges). Bottom: the user's SINR map over the open cells; black: blocked cells (a building "
        "above the UAV: never flown, no SINR shown); grey: open cells no ray reached (dead); cyan contour: the open "
        f"cells at or above P_T = {p_t_db:g} dB. Red: the UAV's path; green circle: start; red square: end; star: the user."
    )
    return Figure(out, caption)


# -- the report -----------------------------------------------------------------------------------
@dataclass
class Figure:
    path: Path
    caption: str


#: Where the paper columns come from: the paper's table of 1000 test episodes in its unseen city (docs/method.md).
PAPER_SOURCE = (
    "Paper columns: the row of the paper's test-city table named in brackets (proposed: topology + SINR; blind: SINR "
    "only; genie), 1000 episodes in its unseen city, t_max 500 (docs/method.md)"
)


def _figure(fig: Figure | None, number: int, alt: str) -> dict:
    """What the templates' ``figure`` macro draws: the PNG inlined (base64), numbered, with its caption."""
    data = None if fig is None else base64.b64encode(fig.path.read_bytes()).decode("ascii")
    return {"number": number, "alt": alt, "data": data, "caption": None if fig is None else fig.caption}


@functools.cache
def _templates():  # noqa: ANN202 - a jinja2.Environment
    """The report pages' Jinja2 templates (``eval/templates/``), autoescaped: every value is text."""
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("uavplace.eval", "templates"), autoescape=True, undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
    )  # fmt: skip


def table_rows(table: pd.DataFrame, t_max: int) -> list[list[str]]:
    """The results table as text cells (header first): each statistic with its 95 % interval, then the paper's."""
    header = ["method", *STATS.values(), "paper: success", "paper: median steps"]
    rows = [header]
    for r in table.to_dict("records"):
        cells = [r["method"]]
        cells += [format_stat(s, r[s], r[f"{s}_lo"], r[f"{s}_hi"], t_max) for s in STATS]
        key = _paper_key(r["method"])
        cells += ["-" if np.isnan(r["paper_success"]) else f"{100 * r['paper_success']:.0f} % ({PAPER[key]['row']})"]
        cells += ["-" if np.isnan(r["paper_median_steps"]) else f"{r['paper_median_steps']:g} ({PAPER[key]['row']})"]
        rows.append(cells)
    return rows


_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:14px;display:block;overflow-x:auto;max-width:100%}
td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}td{white-space:nowrap}.prov td{white-space:normal}
td:first-child,th:first-child{text-align:left}th{background:#f3f3f3}img{max-width:100%}
figure{margin:1.5em 0}figcaption{font-size:14px;color:#333;max-width:1000px}
pre{background:#f7f7f7;padding:8px;overflow-x:auto;font-size:12px}.prov td,.prov th{text-align:left;vertical-align:top}"""


def render_section(config: ReportConfig, rows: list[list[str]], figures: dict[str, Figure | None], provenance: dict,
                   first_figure: int = 1, diff_rows: list[list[str]] | None = None,
                   group_rows: list[list[str]] | None = None) -> str:  # fmt: skip
    """One city's results (``templates/section.html.j2``): how the episodes were drawn, the table, the differences,
    then its captioned figures (those in ``figures``: the CDF, the training curves, the trajectories, numbered from
    ``first_figure``)."""
    p = provenance
    penalised = {n: a["config"].get("test_revisit_penalty", 0.0) for n, a in p["agents"].items()}
    penalties = "; ".join(f"{n}: less {v:g} per earlier visit of the episode to the cell the move leads to"
                          for n, v in penalised.items() if v)  # fmt: skip
    alt = {"cdf": "CDF of steps to P_T in " + p["test_city"], "training": "training curves"}
    alt["trajectories"] = "trajectories in " + p["test_city"]
    shown = [_figure(figures[key], first_figure + i, alt[key]) for i, key in enumerate(k for k in alt if k in figures)]
    return _templates().get_template("section.html.j2").render(
        city=p["test_city"], bundle=p["test_bundle"], episodes=config.episodes, t_max=config.t_max,
        p_t=f"{config.p_t_db:g}", penalties=penalties, epsilon=f"{config.test_epsilon:g}", n_boot=config.n_boot,
        users=p.get("users", "all"), paper_source=PAPER_SOURCE, rows=rows, diff_rows=diff_rows, group_rows=group_rows,
        figures=shown,
    )  # fmt: skip


def provenance_rows(provenances: list[dict]) -> list[list[str]]:
    """What made the report, readable: the command, the bundles tested on and every agent (runs, cities, commands)."""
    first = provenances[0]
    rows = [["what", "value"]]
    rows.append(["report command", first["command"]])
    when = first["created_utc"] if len(provenances) == 1 else f"{first['created_utc']} to {provenances[-1]['created_utc']}"
    made = f"{when}, uavplace {first['uavplace_version']}"  # several cities: from the first city's report to the last's
    if "torch" in first:  # reports from before the threads were recorded lack it
        made += f", torch {first['torch']['version']} on {first['torch']['threads']} threads"
    rows.append(["made", made])
    for p in provenances:
        c = p["test_bundle_config"]
        rows.append([f"test city {p['test_city']}", f"bundle {p['test_bundle']}: grid {c.get('grid_m')} m, altitude "
                     f"{c.get('altitude_m')} m, noise + interference {c.get('noise_dbm')} dBm, role {c.get('role')}"])  # fmt: skip
    for name, a in first["agents"].items():
        trained = ", ".join(f"{k}@{v}" for k, v in (a["trained_on"] or {}).items()) or "unknown"
        selected = ", ".join(f"{k}@{v}" for k, v in (a.get("selected_on") or {}).items()) or "its training cities' held-out users"
        best = a["best_eval"] or {}
        members = a["config"].get("ensemble", 1)
        chosen = (f"the mean of {members} runs' best.pt" if members > 1
                  else f"best.pt from step {best.get('step')}" if best else "best.pt")  # fmt: skip
        rows.append([f"agent {name}", f"{a['folder']}; {a['config']['total_steps']:,} steps; trained on {trained}; "
                     f"selected on {selected}; {chosen}"])  # fmt: skip
        for i, cmd in enumerate(a["commands"] or ["(not recorded)"]):
            rows.append([f"agent {name}: command {i + 1}", cmd])
    return rows


def render_page(
    sections: list[str],
    provenances: list[dict],
    summary: list[list[str]] | None = None,
    training: Figure | None = None,
    caption: str = "",
) -> str:
    """The whole report (``templates/page.html.j2``): with several cities a summary table and the training curves
    (Figure 1) first, then a section per city (``render_section``'s HTML), then the provenance. Self-contained: the
    style and the figures are inlined."""
    import markupsafe

    raw = provenances[0] if len(provenances) == 1 else provenances
    # One city: its report's time. Several: the page's own, when the last city was done (the first city's is earlier).
    made = provenances[0]["created_utc"] if summary is None else dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    return _templates().get_template("page.html.j2").render(
        generator=GENERATOR, cities=", ".join(p["test_city"] for p in provenances), css=markupsafe.Markup(_CSS),
        made=made, command=provenances[0]["command"], summary=summary, caption=caption,
        training=_figure(training, 1, "training curves"), sections=[markupsafe.Markup(s) for s in sections],
        provenance=provenance_rows(provenances), raw=json.dumps(raw, indent=2),
    )  # fmt: skip


@dataclass(frozen=True)
class _Record:
    """What ``check_unseen`` reads of an agent, from its ``run.json`` alone."""

    folder: Path
    trained_on: dict[str, str]
    selected_on: dict[str, str]


def check_unseen_runs(runs: list[Path], datasets: list[str], root: str | Path) -> None:
    """``check_unseen`` of every run against every city, from the runs' ``run.json`` and the bundles' manifests only:
    a several-city command refuses before its first city's work (a run without ``run.json`` is judged when loaded)."""
    records = {Path(r): read_run_json(r) for r in runs if has_record(Path(r))}
    seen = [_Record(r, dict(x.datasets), dict(x.val_datasets)) for r, x in records.items()]
    for d in datasets:
        check_unseen(seen, read_manifest(resolve(d, root=root)))


def check_unseen(agents: list[Agent] | list[_Record], bundle: Bundle | BundleManifest) -> None:
    """``InputError`` unless every agent is new to ``bundle``'s city: neither trained nor selected there, by name or
    by bundle version (a copied or renamed test city has the same version)."""
    for a in agents:
        same = [city for city, version in {**a.trained_on, **a.selected_on}.items() if version == bundle.version]
        if same and bundle.city not in same:  # the same bundle under another name: a copied or renamed city
            raise InputError(
                a.folder, f"trained or selected on bundle {bundle.version} (as {', '.join(same)}), which is this test "
                f"city's ({bundle.city}): not an unseen-city evaluation", field="datasets",
            )  # fmt: skip
        if bundle.city in a.trained_on:
            raise InputError(
                a.folder, f"was trained in {bundle.city}, the test city: not an unseen-city evaluation", field="datasets"
            )
        if bundle.city in a.selected_on:
            raise InputError(
                a.folder, f"selected its checkpoint in {bundle.city}, the test city: not an unseen-city evaluation",
                field="val_datasets",
            )  # fmt: skip


def make_report(
    config: ReportConfig,
    out: str | Path,
    *,
    root: str | Path = "data/processed",
    command: str = "",
    on_progress: Callable[[str, int, int], None] | None = None,
) -> Report:
    """Evaluate every method on ``config.dataset`` and write the report folder ``out`` (atomically).

    Everything that can fail is checked before the first episode: the output
    folder (replaced only if it is a report, ``report.json``), the test bundle,
    every agent (weights only), and that no agent was trained in the test city.
    A training city whose bundle is not built here only loses its upper bound.
    """
    out = Path(out)
    check_replaceable(out, REPORT_JSON, "report")
    bundle = load_bundle(config.dataset, root=root)
    agents = [load_agent(r, config.test_epsilon, config.seed) for r in config.runs]
    check_unseen(agents, bundle)
    names = [a.name for a in agents]
    for a in agents:  # same agent and preset twice: tell them apart by folder
        if names.count(a.name) > 1:
            a.name = a.policy.name = f"{a.name} [{a.folder.name}]"
    bounds, bound_notes = training_bounds(agents, root, config.p_t_db)

    results = evaluate(config, bundle, agents, on_progress)
    if config.ablate:
        results |= _blanked(config, bundle, agents, on_progress)
    table = results_table(results, config)
    refs = references(list(results))
    differences = pd.concat(
        [difference_table(results, refs, n_boot=config.n_boot, seed=config.seed), ablation_table(results, config)],
        ignore_index=True,
    )
    named = groups_of(config, agents)  # the --group runs by their names in the results; references as groups of one
    groups = named | {r: [r] for r in refs}
    grouped = group_tables(results, groups, refs, n_boot=config.n_boot, seed=config.seed) if named else None
    episodes = pd.concat([_plain(df.assign(method=name)) for name, df in results.items()], ignore_index=True)
    with atomic_directory(out, marker=REPORT_JSON, what="report") as tmp:
        figures: dict[str, Figure | None] = {"cdf": plot_cdf(results, config.t_max, tmp / "cdf.png")}
        figures["training"] = plot_training(agents, bounds, tmp / "training.png", bound_notes)
        shown = shown_method(agents)
        picked = pick_trajectories(results, shown, config.trajectories)
        figures["trajectories"] = plot_trajectories(bundle, results, shown, picked, config.p_t_db, tmp / "trajectories.png")
        table.to_csv(tmp / "results.csv", index=False)
        differences.to_csv(tmp / "differences.csv", index=False)
        if grouped is not None:
            pd.concat([grouped[0], grouped[1]], keys=["group", "difference"], names=["table"]).reset_index(level=0).to_csv(
                tmp / "groups.csv", index=False
            )
        table.to_parquet(tmp / "results.parquet", index=False)
        episodes.to_parquet(tmp / "episodes.parquet", index=False)
        provenance = {
            "command": command,
            "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            "uavplace_version": uavplace_version(),
            # For the record: the episodes do not depend on the threads or on what was evaluated before
            # (rl.randomness; tests/test_env.py plays them at 1 and 2 threads).
            "torch": {"version": torch.__version__, "threads": torch.get_num_threads()},
            "report_config": json.loads(config.model_dump_json()),
            "test_city": bundle.city,
            "test_bundle": bundle.version,
            "users": int(table["users"].iloc[0]),
            "test_bundle_config": json.loads(bundle.manifest.config.model_dump_json()),
            "upper_bounds_db": bounds,
            "upper_bounds_notes": bound_notes,
            "trajectories": {"agent": shown, "episodes": [e for e, _ in picked], "rules": [r for _, r in picked]},
            "figures": {k: v.caption for k, v in figures.items() if v is not None},
            "agents": {
                a.name: {
                    "folder": str(a.folder),
                    "trained_on": a.trained_on or None,
                    "selected_on": a.selected_on or None,
                    "commands": a.run.commands if a.run is not None else None,
                    "best_eval": a.best_eval,
                    "config": json.loads(a.config.model_dump_json()),
                }
                for a in agents
            },
        }
        rows = table_rows(table, config.t_max)
        diff_rows = difference_rows(differences, config.t_max)
        grows = None if grouped is None else group_rows(*grouped, groups)
        provenance["groups"] = named or None
        section = render_section(config, rows, figures, provenance, diff_rows=diff_rows, group_rows=grows)
        (tmp / "report.html").write_text(render_page([section], [provenance]), encoding="utf-8")
        (tmp / REPORT_JSON).write_text(json.dumps(provenance, indent=2) + "\n", encoding="utf-8")
    figures = {k: None if v is None else Figure(out / v.path.name, v.caption) for k, v in figures.items()}
    return Report(out, table, differences, episodes, config, rows, diff_rows, figures, provenance, grows)


#: The marker of a report page: ``write_summary_page`` replaces only a page that carries it.
GENERATOR = "uavplace report"


def check_summary_page(out: str | Path) -> None:
    """``InputError`` unless ``out/report.html`` and ``out/summary.csv`` are absent or a report's own (checked before any
    episode is played, so a refusal costs nothing)."""
    page, table = Path(out) / "report.html", Path(out) / "summary.csv"
    if page.is_symlink() or table.is_symlink():
        raise InputError(page, "is a symbolic link: not replaced")
    if page.exists() and f'<meta name="generator" content="{GENERATOR}">' not in page.read_text(
        encoding="utf-8", errors="replace"
    ):
        raise InputError(page, "exists and is not a uavplace report: not replaced (choose another --out)")
    if table.exists() and not page.exists():
        raise InputError(table, "exists without a report page beside it: not replaced (choose another --out)")


def write_summary_page(reports: list[Report], out: str | Path, t_max: int) -> Path:
    """``out/report.html``: the summary table (method x city), then each city's section, then the provenance;
    ``out/summary.csv`` the same figures as numbers (``summary_frame``). Written to temporary files renamed into place."""
    out = Path(out)
    summary = summary_rows(reports, t_max)
    sections = []
    for i, r in enumerate(reports):  # the training curves once, above the cities (Figure 1); each city: CDF, trajectories
        figures = {k: v for k, v in r.figures.items() if k != "training"}
        sections.append(render_section(r.config, r.rows, figures, r.provenance, first_figure=2 + 2 * i, diff_rows=r.diff_rows))
    page = render_page(sections, [r.provenance for r in reports], summary, reports[0].figures.get("training"),
                       summary_caption(reports))  # fmt: skip
    for name, text in (("report.html", page), ("summary.csv", summary_frame(reports).to_csv(index=False))):
        atomic_write_text(out / name, text)
    return out / "report.html"


def markdown_table(rows: list[list[str]]) -> str:
    """Text cells (header first) as a Markdown table."""
    escape = str.maketrans({"|": "\\|"})
    lines = ["| " + " | ".join(c.translate(escape) for c in rows[0]) + " |", "|" + "---|" * len(rows[0])]
    return "\n".join(lines + ["| " + " | ".join(c.translate(escape) for c in r) + " |" for r in rows[1:]])


def markdown_tables(reports: list[Report], t_max: int) -> str:
    """Every table of the reports as Markdown: per city its results and paired differences (each with what it is),
    then, with several cities, the summary with its caption."""
    parts = []
    for r in reports:
        p = r.provenance
        parts.append(f"**{p['test_city']}** ({r.config.episodes} episodes of {p.get('users', '?')} users, bundle "
                     f"{p['test_bundle']}, t_max {r.config.t_max}, P_T {r.config.p_t_db:g} dB; 95 % intervals over users, "
                     "then episodes)")  # fmt: skip
        parts.append(markdown_table(r.rows))
        if len(r.diff_rows) > 1:
            parts.append(f"Paired differences in {p['test_city']}, method minus reference (95 % intervals):")
            parts.append(markdown_table(r.diff_rows))
        if r.group_rows is not None:
            parts.append(f"Groups of runs in {p['test_city']}: mean over runs [95 % interval over runs, users, episodes] "
                         "(the runs' range), differences paired in users and episodes:")  # fmt: skip
            parts.append(markdown_table(r.group_rows))
    if len(reports) > 1:
        parts.append(summary_caption(reports))
        parts.append(markdown_table(summary_rows(reports, t_max)))
    return "\n\n".join(parts) + "\n"


def summary_caption(reports: list[Report]) -> str:
    """What the summary's cells are: episodes and users per city, what the intervals resample."""
    per_city = ", ".join(
        f"{r.provenance['test_city']}: {r.config.episodes} episodes of {r.provenance.get('users', '?')} users" for r in reports
    )
    n_boot = reports[0].config.n_boot
    return (
        f"Success rate and median steps to P_T (failures count as beyond t_max {reports[0].config.t_max}) in each unseen "
        f"city ({per_city}); brackets: 95 % paired bootstrap intervals ({n_boot} resamples of the users, then of the "
        "episodes of each drawn user). Differences with intervals are in each city's section and in summary.csv."
    )


def summary_rows(reports: list[Report], t_max: int) -> list[list[str]]:
    """Header then one row per method: ``success [interval] / median steps [interval]`` in each report's city (``-``
    where not played)."""
    cities = [r.provenance["test_city"] for r in reports]
    cells: dict[str, dict[str, str]] = {}
    for city, r in zip(cities, reports, strict=True):
        for rec in r.table.to_dict("records"):
            cells.setdefault(rec["method"], {})[city] = " / ".join(
                format_stat(s, rec[s], rec[f"{s}_lo"], rec[f"{s}_hi"], t_max=t_max) for s in ("success", "median_steps")
            )
    return [["method", *(f"{c}: success / median steps" for c in cities)]] + [
        [m, *(c.get(city, "-") for city in cities)] for m, c in cells.items()
    ]


#: The columns of ``summary.csv`` taken from each report's table.
SUMMARY_STATS = ("success", "median_steps", "steps_over_genie", "medians_ratio", "spl")


def summary_frame(reports: list[Report]) -> pd.DataFrame:
    """``summary.csv``: one row per (city, method), numbers only: episodes, users, each of ``SUMMARY_STATS`` with its
    interval (inf: beyond t_max), and the paired differences against the blind paper agent (``minus_blind_paper``) and
    the genie (``minus_genie``) with theirs (NaN where undefined or not played)."""
    rows = []
    for r in reports:
        city = r.provenance["test_city"]
        for rec in r.table.to_dict("records"):
            row: dict[str, object] = {"city": city, "method": rec["method"], "episodes": rec["episodes"], "users": rec["users"]}
            for stat in SUMMARY_STATS:
                row |= {stat: rec[stat], f"{stat}_lo": rec[f"{stat}_lo"], f"{stat}_hi": rec[f"{stat}_hi"]}
            for ref in references(list(r.table["method"])):
                kind = "genie" if ref == "genie" else "blind_paper"
                d = r.differences[(r.differences["method"] == rec["method"]) & (r.differences["against"] == ref)]
                for stat in ("success", "median_steps"):
                    one = d[d["stat"] == stat]
                    values = (np.nan,) * 3 if one.empty else tuple(one.iloc[0][["difference", "lo", "hi"]])
                    names = (f"{stat}_minus_{kind}", f"{stat}_minus_{kind}_lo", f"{stat}_minus_{kind}_hi")
                    row |= dict(zip(names, values, strict=True))
            rows.append(row)
    return pd.DataFrame(rows)


def training_bounds(agents: list[Agent], root: str | Path, p_t_db: float) -> tuple[dict[str, float], dict[str, str]]:
    """The upper bound of each distinct training set (``city@version, ...`` -> dB), and notes on where it came from.

    The run's exact bundles when they are built here; else the latest bundle
    of each of its cities (a rebuild of the same raw data with the same
    options gives the same maps under a new version), noted; else no bound,
    noted. A missing training bundle never stops a report: the curves come
    from the run's ``metrics.parquet``.
    """
    bounds: dict[str, float] = {}
    notes: dict[str, str] = {}
    for a in agents:
        key = ", ".join(f"{c}@{v}" for c, v in a.trained_on.items())
        if not key or key in bounds or key in notes:
            continue
        try:
            bundles = [load_bundle(c, v, root=root) for c, v in a.trained_on.items()]
        except InputError as err:
            try:
                bundles = [load_bundle(c, root=root) for c in a.trained_on]
            except InputError:
                notes[key] = f"no bound: {err}"
                continue
            notes[key] = "computed on " + ", ".join(f"{b.city}@{b.version}" for b in bundles) + f" (latest; {err})"
        bounds[key] = upper_bound_db(bundles, p_t_db)
    return bounds, notes


def _plain(df: pd.DataFrame) -> pd.DataFrame:
    df.attrs = {}  # the recorded paths stay with the per-method frames
    return df

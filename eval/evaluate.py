"""The report's evaluation, a public API: agents loaded from run folders, the same episodes played by every method,
the tables of results and of the map ablation (what ``uavrl report``, the sweeps and the experiments call)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from uavplace.dataset.bundle import Bundle, load_bundle, read_manifest, resolve
from uavplace.dataset.difficulty import valid_starts
from uavplace.eval.config import ReportConfig, ReportSettings
from uavplace.eval.metrics import bootstrap_table, difference_table
from uavplace.infra.files import shipped
from uavplace.infra.tensors import load_tensors
from uavplace.rl.agent.checkpoint import best_checkpoint
from uavplace.rl.agent.config import DQNConfig
from uavplace.rl.agent.runs import RUN_JSON, RunRecord, policy_from_checkpoint, read_run_json, settings_unlike
from uavplace.rl.belief import PREDICTIONS, PredictionCache
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.policies import GeniePolicy, GreedyPolicy, Policy, RandomWalkPolicy
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.tasks.placement.searcher import SEARCHER, MapSearchPolicy
from uavplace.rl.tasks.registry import TASKS
from uavplace.rl.world.cities import training_users
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.view import PublicMaps
from uavplace.schemas import InputError
from uavplace.schemas.bundle import BundleManifest

#: The paper's test-city results (docs/method.md, "The paper's results"): success within t_max = 500, median steps.
PAPER = {
    "dqn": {"row": "proposed", "success": 0.90, "median_steps": 44.0},
    "blind": {"row": "blind", "success": 0.66, "median_steps": 69.0},
    "genie": {"row": "genie", "success": 1.00, "median_steps": 14.0},
}


BASELINES = (GeniePolicy.name, RandomWalkPolicy.name, GreedyPolicy.name)


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


def agent_name(config: DQNConfig) -> str:
    """The method's name in tables: the paper's ``DQN`` and ``blind DQN``, or the learner that trained it (``PQN``,
    ``+ GRU`` for a recurrent core, ``x N`` for an ensemble of N runs), then the preset (and the task, but placement,
    and whether a fleet agent sees the other UAVs, ``EnvConfig.fleet_channel``): ``DQN (paper)``, ``PQN + GRU (best)``,
    ``PQN + GRU x 3 (best)``, ``PQN + GRU (best, tracking)``, ``PQN + GRU (best, fleet)``, ``PQN + GRU (best, fleet,
    sees the fleet)``."""
    learner = "PQN" if config.learner == "pqn" else "DQN"
    core = " + GRU" if config.recurrent else ""
    members = f" x {config.ensemble}" if config.ensemble > 1 else ""
    tag = config.task.tag
    task = (f", {tag}" if tag else "") + (", sees the fleet" if config.env.fleet_channel else "")
    return f"{'' if config.agent == 'dqn' else 'blind '}{learner}{core}{members} ({config.preset}{task})"


def has_record(folder: Path) -> bool:
    """Whether ``folder`` holds a ``run.json`` entry of any kind: read (and refused when it is not a regular file) by
    ``read_run_json``, never taken for a bare checkpoint folder."""
    return os.path.lexists(folder / RUN_JSON)


def load_agent(
    folder: str | Path,
    epsilon: float,
    seed: int,
    task: str | None = "placement",
    device: str = "cpu",
    precision: str = "float32",
) -> Agent:
    """A run folder (``run.json`` + ``checkpoints/best.pt``) as an evaluable agent, its network on ``device``
    (``infra.device``'s setting) acting in ``precision`` (``DQNPolicy``); ``InputError`` if it is not one, or if it
    learnt another task than ``task`` (None: either)."""
    folder = Path(folder)
    ckpt = best_checkpoint(folder)
    run = read_run_json(folder) if has_record(folder) else None  # a run.json that is no file is refused there
    ck = load_tensors(ckpt)
    policy, config = policy_from_checkpoint(ck, ckpt, epsilon=epsilon, seed=seed, device=device, precision=precision)
    if run is not None and run.config.model_dump() != config.model_dump():
        held, played = run.config.model_dump(), config.model_dump()
        differ = [k for k in held if held[k] != played[k]]
        raise InputError(
            folder / RUN_JSON,
            f"its config is not the one checkpoints/best.pt was trained with ({', '.join(differ)} "
            "differ): the report would describe another agent than it plays",
            field="config",
        )
    if task is not None and config.task.kind != task:
        raise InputError(
            folder, f"a {config.task.kind} agent, not a {task} one: {TASKS[config.task.kind].played_by} plays it", field="task"
        )
    policy.name = agent_name(config)
    metrics = None
    if (folder / "metrics.parquet").is_file():
        try:
            metrics = pd.read_parquet(folder / "metrics.parquet")
        except (OSError, ValueError) as exc:
            raise InputError(folder / "metrics.parquet", f"unreadable ({str(exc)[:160]})") from None
    return Agent(policy.name, folder, config, run, policy, ck.get("eval"), metrics)


def report_agent(folder: str | Path, settings: ReportSettings, task: str | None = "placement") -> Agent:
    """``load_agent`` as a report plays it: its ``settings``' random moves, seed, device and network precision."""
    return load_agent(folder, settings.test_epsilon, settings.seed, task, settings.device, settings.network_precision)


#: Where the shipped agents live: the project's ``data/agents``, wherever a command runs.
SHIPPED_AGENTS = shipped("data/agents")


def default_agents(root: str | Path = SHIPPED_AGENTS, task: str | tuple[str, ...] | None = "placement") -> list[Path]:
    """The shipped agents: every folder under ``root`` (default: the project's ``data/agents``, wherever the command
    runs) with a ``checkpoints/best.pt``, in name order; those that learnt ``task`` or one of the tasks given (by
    their ``run.json``; None: every agent)."""
    root = Path(root)
    tasks = (task,) if isinstance(task, str) else task
    found = sorted(p for p in root.iterdir() if (p / "checkpoints" / "best.pt").is_file()) if root.is_dir() else []
    return [p for p in found if tasks is None or not has_record(p) or read_run_json(p).config.task.kind in tasks]


def unlike_training(runs: list[Path], datasets: list[str], root: str | Path, p_t_db: float) -> list[str]:
    """One line per city and difference where runs' agents would play a bundle built with settings none of their
    training cities had (grid, altitude, noise: ``run.json``'s ``bundle_settings``), or at another P_T than they were
    trained at, naming the runs. A run that records no settings (older than the record, or a bare checkpoint) is not
    judged."""
    manifests = [read_manifest(resolve(d, root=root)) for d in datasets]
    records = [(Path(run).name, read_run_json(run)) for run in runs if has_record(Path(run))]
    records = [(name, record) for name, record in records if record.bundle_settings]
    found: dict[tuple[str, str], list[str]] = {}  # (city@version, what differs): the runs, in order
    for manifest in manifests:
        for name, record in records:
            unlike = settings_unlike(record, manifest, p_t_db)
            if unlike:
                found.setdefault((f"{manifest.city}@{manifest.version}", "; ".join(unlike)), []).append(name)
    lines = []
    for (city, unlike), names in found.items():
        if len(names) == 1:
            lines.append(f"{names[0]} on {city}: {unlike}: the agent plays outside what it was trained on")
        else:
            who = ", ".join(names[:-1]) + f" and {names[-1]}"
            lines.append(f"{who} on {city}: {unlike}: the agents play outside what they were trained on")
    return lines


def evaluate(
    config: ReportConfig,
    bundle: Bundle,
    agents: list[Agent],
    on_progress: Callable[[str, int, int], None] | None = None,
    baselines: list[Policy] | None = None,
    seen: Callable[[MapSet], None] | None = None,
    episodes: np.ndarray | None = None,
    parallel: bool = False,
) -> dict[str, pd.DataFrame]:
    """Play the same ``config.episodes`` episodes with every method; ``{method: run_episodes frame}``.

    Each agent plays in the environment it was trained for (its window, channels, memory values)
    with the report's ``t_max`` and ``P_T``; the episodes are drawn once from the users of the city.
    ``baselines``: the policies played beside the agents (default: ``baseline_policies``). ``seen``: applied to
    each agent's maps before it plays (e.g. ``MapSet.show_buildings``: what the agents see, not where they move).
    ``episodes``: the specs to play (``MapSet.sample_episodes`` of the city's maps at the report's settings, e.g. drawn
    on a twin city and kept where ``can_start``), instead of the ``config.episodes`` drawn with ``config.seed``.
    ``parallel``: the methods' rollouts as Ray tasks (``eval.parallel``; Ray started or joined by the caller), the
    same frames as one after the other here.
    """
    maps = {"": MapSet([bundle], report_env(config))}
    if episodes is None:
        episodes = maps[""].episode_list(config.episodes, config.seed)  # as `uavrl baselines`
    elif not maps[""].can_start(episodes).all():
        raise ValueError("evaluate: an episode given does not start on a start cell of this city")
    record = np.arange(len(episodes)) if config.trajectories else None  # the rule picks among all episodes
    methods: list[tuple[str, Policy, MapSet]] = []
    for a in agents:
        env = agent_env(config, a)
        key = env.model_dump_json()
        if key not in maps:
            maps[key] = MapSet([bundle], env)
            if seen is not None:
                seen(maps[key])
        methods.append((a.name, a.policy, maps[key]))
    if baselines is None:
        baselines = default_baselines(config, bundle)
    methods += [(p.name, p, maps[""]) for p in baselines]
    names = [m[0] for m in methods]
    if len(set(names)) != len(names):
        raise ValueError(f"two methods share a name: {names}")
    shown = shown_method(agents, names)
    results = {}
    # Each method's episodes on its own canvas (an agent's window pads its canvas by another margin), made once.
    specs = {name: mapset.episodes_from(episodes, maps[""]) for name, _, mapset in methods}
    for name, policy, mapset in methods:  # the searchers' predicted maps first, shown as they are made (the agents that
        if hasattr(policy, "on_predict"):  # read the belief find them in the cache); the same maps as made on first use
            if on_progress is not None:
                policy.on_predict = lambda done, total, name=name: on_progress(predicted_maps(name), done, total)
            public = PublicMaps.of(mapset)
            for canvas in np.unique(mapset.view_map[specs[name][:, 0].astype(np.int64)]):  # the canvases they fly over
                policy.canvas_maps(public, int(canvas))
    recorded = {name: record if name == shown else None for name, _, _ in methods}
    if parallel:
        from uavplace.eval.parallel import Method, play_on_ray

        on_ray = [Method(name, policy, mapset, specs[name], recorded[name]) for name, policy, mapset in methods]
        return play_on_ray(on_ray, run_episodes, on_progress=on_progress)
    for name, policy, mapset in methods:
        report = None if on_progress is None else (lambda done, total, name=name: on_progress(name, done, total))
        results[name] = run_episodes(mapset, policy, specs[name], on_step=report, record=recorded[name])
    return results


def predicted_maps(method: str) -> str:
    """The name of the stage in which ``method`` (a searcher) makes its predicted maps, before it plays."""
    return f"{method}: predicted maps"


def stages(methods: list[tuple[str, Policy]]) -> list[str]:
    """The stages ``evaluate`` goes through for ``methods`` (``(name, policy)``), in its order: every searcher's
    predicted maps, then every method's episodes (what a progress display counts)."""
    return [predicted_maps(name) for name, policy in methods if hasattr(policy, "on_predict")] + [n for n, _ in methods]


def default_baselines(config: ReportConfig, bundle: Bundle) -> list[Policy]:
    """``baseline_policies`` at the report's settings, the predicted maps cached beside the city's bundles (or in
    ``config.prediction_cache``)."""
    cache = config.prediction_cache or bundle.path.parent.parent / PREDICTIONS
    return baseline_policies(config, report_env(config), cache=cache)


def agent_env(config: ReportConfig, agent: Agent) -> EnvConfig:
    """The env the report plays ``agent`` in: its own evaluation env at the report's horizon, P_T, split,
    measurement and map error."""
    return agent.config.env_config(evaluation=True).model_copy(
        update={
            "t_max": config.t_max,
            "p_t_db": config.p_t_db,
            "split": config.split,
            "measurement": config.measurement,
            "map_error": config.map_error,
        }
    )


def report_env(config: ReportConfig) -> EnvConfig:
    """The environment every baseline plays in at the report's settings (agents keep their own window)."""
    return EnvConfig(
        t_max=config.t_max,
        p_t_db=config.p_t_db,
        split=config.split,
        rotate=False,
        measurement=config.measurement,
        map_error=config.map_error,
    )


def baseline_policies(config: ReportConfig, env: EnvConfig, cache: str | Path | None = None) -> list[Policy]:
    """The genie, the steered random walk and greedy hill-climbing, seeded as the report is (their names are the
    table's); then, with ``config.predictor``, the map searcher and its ablation shown no building
    (``rl.tasks.placement.searcher``), their predicted maps kept in ``cache`` (None: not on disk)."""
    out: list[Policy] = [GeniePolicy(), RandomWalkPolicy(seed=config.seed), GreedyPolicy(env.p_h_db, seed=config.seed)]
    if config.predictor is not None:
        predictor = load_predictor(config.predictor)
        cache = PredictionCache(cache)
        for buildings in (True, False):
            search = config.search.model_copy(update={"buildings": buildings})
            out.append(MapSearchPolicy(predictor, search, cache, device=config.device))
    return out


def results_table(results: dict[str, pd.DataFrame], config: ReportConfig) -> pd.DataFrame:
    """``bootstrap_table`` plus the paper's success and median steps where the paper has the method."""
    table = bootstrap_table(results, n_boot=config.n_boot, seed=config.seed)
    keys = [paper_key(name) for name in table["method"]]
    table["paper_success"] = [PAPER[k]["success"] if k else np.nan for k in keys]
    table["paper_median_steps"] = [PAPER[k]["median_steps"] if k else np.nan for k in keys]
    return table


#: The suffix of a method played with the building map blanked, and the reference column of its cost.
NO_BUILDINGS, WITH_BUILDINGS = ", no buildings", "the same with buildings"


def blanked_agents(config: ReportConfig, agents: list[Agent]) -> list[Agent]:
    """The agents that read the building map, loaded again and named ``X, no buildings``: ``evaluate`` them with
    ``blanked_results`` (the same episodes, the map blanked)."""
    sighted = [a for a in agents if not a.config.env_config(evaluation=True).blind]  # a blind agent reads no map
    readers = [report_agent(a.folder, config) for a in sighted]
    for reader, agent in zip(readers, sighted, strict=True):
        reader.name = reader.policy.name = agent.name + NO_BUILDINGS
    return readers


def blanked_results(
    config: ReportConfig,
    bundle: Bundle,
    readers: list[Agent],
    on_progress: Callable[[str, int, int], None] | None,
    parallel: bool = False,
) -> dict[str, pd.DataFrame]:
    """``blanked_agents`` played on the report's episodes with the building map blanked (what they see, not where
    they move)."""
    if not readers:
        return {}
    blank = lambda m: m.show_buildings(None)  # noqa: E731
    return evaluate(config, bundle, readers, on_progress, baselines=[], seen=blank, parallel=parallel)


def ablation_table(results: dict[str, pd.DataFrame], config: ReportConfig) -> pd.DataFrame:
    """The map ablation's cost: for every method ``X`` played also as ``X, no buildings``, the paired difference
    ``(X, no buildings) - X``, its reference named ``WITH_BUILDINGS`` (a column of its own in the differences)."""
    parts = []
    for name in results:
        if name.endswith(NO_BUILDINGS) and name[: -len(NO_BUILDINGS)] in results:
            plain = name[: -len(NO_BUILDINGS)]
            d = difference_table({plain: results[plain], name: results[name]}, [plain], n_boot=config.n_boot, seed=config.seed)
            parts.append(d[d["method"] == name].assign(against=WITH_BUILDINGS))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def references(methods: list[str]) -> list[str]:
    """What every method is compared with, in order: the paper's blind agent (the baseline of the paper's claim), the
    genie (the bound), the shipped best learner and the map searcher (its ablation's cost is the difference)."""
    blind = [m for m in methods if m.startswith("blind ") and m.endswith("(paper)")]
    best = [m for m in methods if m.endswith("(best)") and not m.startswith("blind ")]
    return blind + [m for m in methods if m == "genie"] + best + [m for m in methods if m == SEARCHER]


def groups_of(config: ReportConfig, agents: list[Agent]) -> dict[str, list[str]]:
    """``config.groups`` with each run folder replaced by its agent's name in the results."""
    by_folder = {str(Path(r)): a.name for r, a in zip(config.runs, agents, strict=True)}
    return {g: [by_folder[str(Path(r))] for r in runs] for g, runs in config.groups.items()}


def shown_method(agents: list[Agent], methods: Iterable[str]) -> str:
    """The method whose trajectories the report draws: the map searcher where it plays (what the report leads with,
    eval/findings.py), else the first agent, else the genie."""
    if SEARCHER in methods:
        return SEARCHER
    return agents[0].name if agents else "genie"


def upper_bound_db(bundles: list[Bundle], p_t_db: float) -> float:
    """The paper's training bound on the mean SINR gain: mean over users, then start cells, of P_T - start SINR.

    Users and starts as training draws them (``rl.world.cities.training_users``) with at least one
    valid start (``dataset.difficulty.valid_starts``).
    """
    per_user = []
    for b in bundles:
        for u in training_users(b):
            starts = valid_starts(b.blocked, b.dead[u], b.sinr_db[u], p_t_db)
            if starts.any():
                per_user.append(float(np.mean(p_t_db - b.sinr_db[u][starts])))
    return float(np.mean(per_user))


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
                a.folder,
                f"trained or selected on bundle {bundle.version} (as {', '.join(same)}), which is this test "
                f"city's ({bundle.city}): not an unseen-city evaluation",
                field="datasets",
            )
        if bundle.city in a.trained_on:
            raise InputError(
                a.folder, f"was trained in {bundle.city}, the test city: not an unseen-city evaluation", field="datasets"
            )
        if bundle.city in a.selected_on:
            raise InputError(
                a.folder,
                f"selected its checkpoint in {bundle.city}, the test city: not an unseen-city evaluation",
                field="val_datasets",
            )


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
        names = list(a.trained_on)
        cities = ", ".join(names) if len(names) <= 3 else f"{', '.join(names[:2])} and {len(names) - 2} more"
        try:
            bundles = [load_bundle(c, v, root=root) for c, v in a.trained_on.items()]
        except InputError:
            try:
                bundles = [load_bundle(c, root=root) for c in a.trained_on]
            except InputError:  # said in words: a caption is no place for an error message
                notes[key] = f"no bound: the training cities ({cities}) are not built here"
                continue
            notes[key] = (
                f"computed on the latest builds of the training cities ({cities}): the run's own versions are not built here"
            )
        bounds[key] = upper_bound_db(bundles, p_t_db)
    return bounds, notes


def paper_key(method: str) -> str | None:
    if method.endswith(NO_BUILDINGS):  # the paper played no method on a blanked map
        return None
    if method == "genie":
        return "genie"
    if not method.endswith("(paper)"):  # the paper's numbers stand beside the paper's agents only
        return None
    return "blind" if method.startswith("blind ") else "dqn"

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
import html
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from pydantic import Field

from dataset.bundle import Bundle, load_bundle
from dataset.difficulty import valid_starts
from eval.metrics import STATS, bootstrap_table, ecdf, format_stat
from rl.agent.checkpoint import load_tensors
from rl.agent.dqn import DQNConfig
from rl.agent.train import RUN_JSON, RunRecord, policy_from_checkpoint, read_run_json, training_users
from rl.config import EnvConfig
from rl.maps import MapSet
from rl.policies import GeniePolicy, GreedyPolicy, Policy, RandomWalkPolicy
from rl.rollout import run_episodes
from schemas import InputError
from schemas.base import Contract, uavplace_version
from schemas.files import atomic_directory, check_replaceable

#: The paper's test-city results (docs/method.md, "The paper's results"): success within t_max = 500, median steps.
PAPER = {
    "dqn": {"label": "proposed (topology + SINR)", "success": 0.90, "median_steps": 44.0},
    "blind": {"label": "blind (SINR only)", "success": 0.66, "median_steps": 69.0},
    "genie": {"label": "genie", "success": 1.00, "median_steps": 14.0},
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
    seed: int = Field(default=0, description="Seed of the episodes, the agents' random moves and the baselines")
    n_boot: int = Field(default=2000, ge=100, description="Bootstrap resamples for the 95 % intervals")
    trajectories: int = Field(default=3, ge=0, description="Successful episodes drawn per agent")
    split: str | None = Field(default=None, description="Users of this split only (None: all users of the city)")


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
    episodes: pd.DataFrame  # every method's episodes, with a "method" column


def agent_name(config: DQNConfig) -> str:
    return f"{'DQN' if config.agent == 'dqn' else 'blind DQN'} ({config.preset})"


def load_agent(folder: str | Path, epsilon: float, seed: int) -> Agent:
    """A run folder (``run.json`` + ``checkpoints/best.pt``) as an evaluable agent; ``InputError`` if it is not one."""
    folder = Path(folder)
    ckpt = folder / "checkpoints" / "best.pt"
    if not ckpt.is_file():
        raise InputError(folder, "no checkpoints/best.pt (not a training run, or it never evaluated)")
    run = read_run_json(folder) if (folder / RUN_JSON).is_file() else None
    ck = load_tensors(ckpt)
    policy, config = policy_from_checkpoint(ck, ckpt, epsilon=epsilon, seed=seed)
    policy.name = agent_name(config)
    metrics = None
    if (folder / "metrics.parquet").is_file():
        try:
            metrics = pd.read_parquet(folder / "metrics.parquet")
        except (OSError, ValueError) as exc:
            raise InputError(folder / "metrics.parquet", f"unreadable ({str(exc)[:160]})") from None
    return Agent(policy.name, folder, config, run, policy, ck.get("eval"), metrics)


def default_agents(root: str | Path = "data/agents") -> list[Path]:
    """The shipped agents: every folder under ``root`` with a ``checkpoints/best.pt``, in name order."""
    root = Path(root)
    return sorted(p for p in root.iterdir() if (p / "checkpoints" / "best.pt").is_file()) if root.is_dir() else []


def evaluate(
    config: ReportConfig,
    bundle: Bundle,
    agents: list[Agent],
    on_progress: Callable[[str, int, int], None] | None = None,
    baselines: list[Policy] | None = None,
) -> dict[str, pd.DataFrame]:
    """Play the same ``config.episodes`` episodes with every method; ``{method: run_episodes frame}``.

    Each agent plays in the environment it was trained for (its window, channels, memory values)
    with the report's ``t_max`` and ``P_T``; the episodes are drawn once from the users of the city.
    ``baselines``: the policies played beside the agents (default: ``baseline_policies``).
    """
    base = EnvConfig(t_max=config.t_max, p_t_db=config.p_t_db, split=config.split, rotate=False)
    maps = {"": MapSet([bundle], base)}
    episodes = maps[""].sample_episodes(config.episodes, np.random.default_rng(config.seed))  # as `uavrl baselines`
    shown = shown_method(agents)
    record = np.arange(config.episodes)[: max(50, 10 * config.trajectories)] if config.trajectories else None
    methods: list[tuple[str, Policy, MapSet]] = []
    for a in agents:
        env = a.config.env_config(evaluation=True).model_copy(
            update={"t_max": config.t_max, "p_t_db": config.p_t_db, "split": config.split}
        )
        key = env.model_dump_json()
        if key not in maps:
            maps[key] = MapSet([bundle], env)
        methods.append((a.name, a.policy, maps[key]))
    methods += [(p.name, p, maps[""]) for p in (baseline_policies(config, base) if baselines is None else baselines)]
    names = [m[0] for m in methods]
    if len(set(names)) != len(names):
        raise ValueError(f"two methods share a name: {names}")
    results = {}
    for name, policy, mapset in methods:
        report = None if on_progress is None else (lambda done, total, name=name: on_progress(name, done, total))
        results[name] = run_episodes(mapset, policy, episodes, on_step=report, record=record if name == shown else None)
    return results


def baseline_policies(config: ReportConfig, env: EnvConfig) -> list[Policy]:
    """The genie, the steered random walk and greedy hill-climbing, seeded as the report is (their names are the table's)."""
    return [GeniePolicy(), RandomWalkPolicy(seed=config.seed), GreedyPolicy(env.p_h_db, seed=config.seed)]


def results_table(results: dict[str, pd.DataFrame], config: ReportConfig) -> pd.DataFrame:
    """``bootstrap_table`` plus the paper's success and median steps where the paper has the method."""
    table = bootstrap_table(results, n_boot=config.n_boot, seed=config.seed)
    paper_key = {name: _paper_key(name) for name in table["method"]}
    table["paper_success"] = [PAPER[k]["success"] if k else np.nan for k in paper_key.values()]
    table["paper_median_steps"] = [PAPER[k]["median_steps"] if k else np.nan for k in paper_key.values()]
    return table


def _paper_key(method: str) -> str | None:
    if method == "genie":
        return "genie"
    if method.startswith("blind DQN"):
        return "blind"
    if method.startswith("DQN"):
        return "dqn"
    return None


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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_cdf(results: dict[str, pd.DataFrame], t_max: int, out: Path) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.8), constrained_layout=True)
    for name, df in results.items():
        s, f = ecdf(df, t_max)
        ax.step(
            s,
            f,
            where="post",
            label=f"{name} ({100 * f[-1]:.0f} %)",
            linewidth=1.3 if name in BASELINES else 2.0,
        )
    ax.set_xscale("symlog", linthresh=10)
    ax.set_xlim(0, t_max)
    ax.set_ylim(0, 1.01)
    ax.set_xlabel("steps to reach P_T")
    ax.set_ylabel("share of episodes")
    ax.set_title(f"CDF of steps to P_T ({len(next(iter(results.values())))} episodes, t_max {t_max})")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_training(agents: list[Agent], bounds: dict[str, float], out: Path, notes: dict[str, str] | None = None) -> Path | None:
    curves = []
    for a in agents:
        if a.metrics is not None and len(a.metrics):
            curves.append((a.name, a.metrics))
    if not curves:
        return None
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.5), constrained_layout=True)
    for name, df in curves:
        # The running mean in full only once its window is full: before, a mean of a few episodes (which can
        # overshoot any bound) is drawn faint.
        rolling = df["sinr_gain_db"].rolling(RUNNING_WINDOW, min_periods=1).mean()
        full = np.arange(len(df)) >= RUNNING_WINDOW - 1
        line = ax.plot(df["step"][full], rolling[full], label=name)[0]
        ax.plot(df["step"][:RUNNING_WINDOW], rolling[:RUNNING_WINDOW], color=line.get_color(), alpha=0.3, linewidth=1)
    for key, bound in bounds.items():
        note = (notes or {}).get(key, "")
        where = note.split(" (")[0] if note.startswith("computed on") else key  # the bundles it was computed on
        ax.axhline(bound, color="black", linestyle="--", linewidth=1, label=f"upper bound, {where} ({bound:.1f} dB)")
    ax.set_xlabel("training step")
    ax.set_ylabel("mean SINR gain over the last 100 episodes [dB]")
    ax.set_title(f"Training curves (faint: the first {RUNNING_WINDOW} episodes, a partial window)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def pick_trajectories(results: dict[str, pd.DataFrame], agent: str, count: int) -> list[int]:
    """Up to ``count`` recorded successful episodes of ``agent``, the longest genie paths first, distinct users."""
    df = results[agent]
    paths = df.attrs.get("paths", {})
    ok = df[df["success"] & df["episode"].isin(list(paths))].sort_values(["genie_steps", "episode"], ascending=[False, True])
    return ok.drop_duplicates("user")["episode"].head(count).tolist()


def plot_trajectories(
    bundle: Bundle, results: dict[str, pd.DataFrame], agent: str, episodes: list[int], out: Path
) -> Path | None:
    if not episodes:
        return None
    plt = _pyplot()
    import matplotlib

    df = results[agent].set_index("episode")
    g = bundle.manifest.grid
    extent = (g.x_min_m, g.x_max_m, g.y_min_m, g.y_max_m)
    fig, axes = plt.subplots(2, len(episodes), figsize=(4.2 * len(episodes), 7.6), constrained_layout=True, squeeze=False)
    for j, ep in enumerate(episodes):
        row = df.loc[ep]
        user = int(row["user"])
        cells = results[agent].attrs["paths"][ep]  # [T + 1, 2] (iy, ix) map cells
        px = g.x_min_m + (cells[:, 1] + 0.5) * g.spacing_m
        py = g.y_min_m + (cells[:, 0] + 0.5) * g.spacing_m
        urow = bundle.users.iloc[user]
        for i, ax in enumerate(axes[:, j]):
            if i == 0:
                im = ax.imshow(bundle.height_rel_m, origin="lower", extent=extent, cmap="viridis")
                ax.set_title(
                    f"episode {ep}: user {user}, {int(row['steps'])} steps (genie {int(row['genie_steps'])})", fontsize=9
                )
                label = "building height - altitude [m]"
            else:
                sinr = np.ma.masked_array(bundle.sinr_db[user], mask=bundle.dead[user])
                im = ax.imshow(sinr, origin="lower", extent=extent, cmap=matplotlib.colormaps["magma"].with_extremes(bad="0.75"))
                label = "SINR [dB]"
            ax.contour(bundle.blocked, levels=[0.5], origin="lower", extent=extent, colors="white", linewidths=0.4)
            ax.plot(px, py, color="red", linewidth=1.4)
            ax.plot(px[0], py[0], "o", color="lime", markeredgecolor="black", label="start")
            ax.plot(px[-1], py[-1], "s", color="red", markeredgecolor="black", label="end (P_T reached)")
            if np.isfinite(urow["x_m"]) and np.isfinite(urow["y_m"]):
                ax.plot(urow["x_m"], urow["y_m"], "*", color="cyan", markersize=13, markeredgecolor="black", label="user")
            ax.set_xlabel("x [m]", fontsize=8)
            ax.set_ylabel("y [m]", fontsize=8)
            ax.tick_params(labelsize=7)
            fig.colorbar(im, ax=ax, shrink=0.8).set_label(label, fontsize=7)
    axes[0, 0].legend(fontsize=7, loc="upper left")
    fig.suptitle(f"{agent}: successful episodes in {bundle.city}", fontsize=10)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


# -- the report -----------------------------------------------------------------------------------
def _img(path: Path | None, alt: str) -> str:
    if path is None:
        return f"<p><em>{html.escape(alt)}: nothing to draw.</em></p>"
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def table_rows(table: pd.DataFrame, t_max: int) -> list[list[str]]:
    """The results table as text cells (header first): each statistic with its 95 % interval, then the paper's."""
    header = ["method", *STATS.values(), "paper: success", "paper: median steps"]
    rows = [header]
    for r in table.to_dict("records"):
        cells = [r["method"]]
        cells += [format_stat(s, r[s], r[f"{s}_lo"], r[f"{s}_hi"]).replace("> t_max", f"> {t_max}") for s in STATS]
        cells += ["-" if np.isnan(r["paper_success"]) else f"{100 * r['paper_success']:.0f} %"]
        cells += ["-" if np.isnan(r["paper_median_steps"]) else f"{r['paper_median_steps']:g}"]
        rows.append(cells)
    return rows


def _html_table(rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in rows[0])
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows[1:])
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:14px}td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}
td:first-child,th:first-child{text-align:left}th{background:#f3f3f3}img{max-width:100%}
pre{background:#f7f7f7;padding:8px;overflow-x:auto;font-size:12px}"""


def render_html(config: ReportConfig, rows: list[list[str]], figures: dict[str, Path | None], provenance: dict) -> str:
    p = provenance
    notes = (
        f"{config.episodes} episodes in <b>{html.escape(p['test_city'])}</b> (bundle {html.escape(p['test_bundle'])}), "
        f"users drawn uniformly, then a start cell uniformly among the legal, live cells below P_T; "
        f"the same episodes for every method. t_max {config.t_max}, P_T {config.p_t_db:g} dB; the agents take the "
        f"legal move of highest Q, or a random legal move with probability {config.test_epsilon:g}. Steps to P_T of a "
        f"failed episode count as &gt; t_max. Brackets: paired bootstrap 95 % intervals ({config.n_boot} resamples)."
    )
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>uavplace report: {html.escape(p["test_city"])}</title>
<style>{_CSS}</style></head><body>
<h1>uavplace: UAV placement for a user of unknown location</h1>
<p>Made {html.escape(p["created_utc"])} by <code>{html.escape(p["command"])}</code> (uavplace {html.escape(p["uavplace_version"])}).</p>
<h2>1. Results in the test city</h2>
<p>{notes}</p>
{_html_table(rows)}
<h2>2. Steps to reach P_T</h2>
{_img(figures.get("cdf"), "CDF of steps to P_T")}
<h2>3. Training curves</h2>
{_img(figures.get("training"), "training curves")}
<h2>4. Trajectories</h2>
{_img(figures.get("trajectories"), "trajectories")}
<h2>5. Provenance</h2>
<pre>{html.escape(json.dumps(p, indent=2))}</pre>
</body></html>
"""


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
    for a in agents:
        if bundle.city in a.trained_on:
            raise InputError(
                a.folder, f"was trained in {bundle.city}, the test city: not an unseen-city evaluation", field="datasets"
            )
        if bundle.city in a.selected_on:
            raise InputError(
                a.folder, f"selected its checkpoint in {bundle.city}, the test city: not an unseen-city evaluation",
                field="val_datasets",
            )  # fmt: skip
    names = [a.name for a in agents]
    for a in agents:  # same agent and preset twice: tell them apart by folder
        if names.count(a.name) > 1:
            a.name = a.policy.name = f"{a.name} [{a.folder.name}]"
    bounds, bound_notes = training_bounds(agents, root, config.p_t_db)

    results = evaluate(config, bundle, agents, on_progress)
    table = results_table(results, config)
    episodes = pd.concat([_plain(df.assign(method=name)) for name, df in results.items()], ignore_index=True)
    with atomic_directory(out, marker=REPORT_JSON, what="report") as tmp:
        figures: dict[str, Path | None] = {"cdf": plot_cdf(results, config.t_max, tmp / "cdf.png")}
        figures["training"] = plot_training(agents, bounds, tmp / "training.png", bound_notes)
        shown = shown_method(agents)
        picked = pick_trajectories(results, shown, config.trajectories)
        figures["trajectories"] = plot_trajectories(bundle, results, shown, picked, tmp / "trajectories.png")
        table.to_csv(tmp / "results.csv", index=False)
        table.to_parquet(tmp / "results.parquet", index=False)
        episodes.to_parquet(tmp / "episodes.parquet", index=False)
        provenance = {
            "command": command,
            "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            "uavplace_version": uavplace_version(),
            "report_config": json.loads(config.model_dump_json()),
            "test_city": bundle.city,
            "test_bundle": bundle.version,
            "test_bundle_config": json.loads(bundle.manifest.config.model_dump_json()),
            "upper_bounds_db": bounds,
            "upper_bounds_notes": bound_notes,
            "trajectories": {"agent": shown, "episodes": picked},
            "agents": {
                a.name: {
                    "folder": str(a.folder),
                    "trained_on": a.trained_on or None,
                    "command": a.run.command if a.run is not None else None,
                    "best_eval": a.best_eval,
                    "config": json.loads(a.config.model_dump_json()),
                }
                for a in agents
            },
        }
        rows = table_rows(table, config.t_max)
        (tmp / "report.html").write_text(render_html(config, rows, figures, provenance), encoding="utf-8")
        (tmp / REPORT_JSON).write_text(json.dumps(provenance, indent=2) + "\n", encoding="utf-8")
    return Report(out, table, episodes)


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

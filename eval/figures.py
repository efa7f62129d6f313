"""The report's figures: the CDF of steps to P_T, the performance profiles, the training curves and the trajectories
(matplotlib, Agg)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from uavplace.dataset.bundle import Bundle
from uavplace.eval.evaluate import BASELINES, NO_BUILDINGS, Agent
from uavplace.eval.metrics import PROFILE_TAUS, ecdf
from uavplace.rl.world.stats import summarise
from uavplace.schemas.constants import reaches_target

#: Episodes in the training curves' running mean (the paper's 100).
RUNNING_WINDOW = 100


# -- figures --------------------------------------------------------------------------------------
def _pyplot():
    """pyplot off-screen, with text taken as it is: a name with ``$`` (a run folder's) is never parsed as mathtext."""
    import matplotlib

    matplotlib.use("Agg")
    matplotlib.rcParams["text.parse_math"] = False
    import matplotlib.pyplot as plt

    return plt


#: Ten colours told apart in print and by most colour-blind readers (matplotlib's tab10).
_COLOURS = tuple(f"tab:{c}" for c in "blue orange green red purple brown pink olive cyan gray".split())


def draw_blocked(ax, blocked: np.ndarray, extent: tuple[float, ...]) -> None:  # noqa: ANN001 - an Axes
    """The cells the UAV may not enter, in near-black over whatever ``ax`` shows (a map's other cells untouched)."""
    import matplotlib.colors

    ax.imshow(
        np.ma.masked_array(np.ones(blocked.shape), mask=~blocked),
        origin="lower",
        extent=extent,
        cmap=matplotlib.colors.ListedColormap(["0.05"]),
        vmin=0,
        vmax=1,
    )


def method_styles(methods: list[str]) -> dict[str, dict]:
    """Each method's line: the genie black; every other method its own colour (the eleventh on repeat the first colour
    dash-dotted, and so on); a method played with the buildings blanked (``X, no buildings``) dashed in ``X``'s colour.
    Baselines thinner. Keyword arguments for ``Axes.plot``."""
    styles: dict[str, dict] = {}
    own = [m for m in methods if not (m.endswith(NO_BUILDINGS) and m[: -len(NO_BUILDINGS)] in methods)]
    plain = [m for m in own if m != "genie"]
    for i, m in enumerate(plain):
        styles[m] = {"color": _COLOURS[i % len(_COLOURS)], "linestyle": ("-", "-.", ":")[i // len(_COLOURS) % 3]}
    if "genie" in own:
        styles["genie"] = {"color": "black", "linestyle": "-"}
    for m in methods:
        if m not in styles:
            styles[m] = {"color": styles[m[: -len(NO_BUILDINGS)]]["color"], "linestyle": "--"}
        styles[m]["linewidth"] = 1.3 if m in BASELINES else 2.0
    return styles


def _legend_in_curve_order(ax, lines: dict, heights: dict[str, float], title: str) -> None:  # noqa: ANN001 - an Axes
    """The legend beside the plot, its entries (``lines``: each method's Line2D) in the order of the curves' right ends
    (``heights``), top first."""
    order = sorted(lines, key=lambda m: -heights[m])
    beside = {"loc": "upper left", "bbox_to_anchor": (1.02, 1.0), "fontsize": 8, "title_fontsize": 8}
    ax.legend([lines[m] for m in order], [lines[m].get_label() for m in order], title=title, **beside)


def plot_cdf(results: dict[str, pd.DataFrame], t_max: int, out: Path) -> Figure:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9.5, 4.8), constrained_layout=True)
    styles = method_styles(list(results))
    lines, heights = {}, {}
    for name, df in results.items():
        s, f = ecdf(df, t_max)
        lines[name] = ax.step(s, f, where="post", label=f"{name} ({100 * f[-1]:.1f} %)", **styles[name])[0]
        heights[name] = f[-1]
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
    _legend_in_curve_order(ax, lines, heights, "method (success within t_max)")
    fig.savefig(out, dpi=110)
    plt.close(fig)
    caption = (
        f"Share of the {n} episodes that reached P_T within a given number of steps, one curve per method, all "
        f"methods on the same episodes (users drawn uniformly, then start cells uniformly among the legal live cells "
        f"below P_T). A curve ends at t_max = {t_max}; its height there is the method's success rate (in the legend, "
        "in the order of the curves' ends). Dashed: a method shown no building, in its method's colour."
    )
    return Figure(out, caption)


def plot_profiles(bands: dict[str, np.ndarray], where: str, out: Path, taus: np.ndarray = PROFILE_TAUS) -> Figure:
    """The performance profiles (``eval.metrics.profiles``): for each method the share of episodes solved within tau x
    the genie's steps, tau from 1 to 10, with its 95 % bootstrap band; ``where`` names the episodes (a city, or the
    test cities pooled)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9.5, 4.8), constrained_layout=True)
    styles = method_styles(list(bands))
    lines = {}
    for name, (value, lo, hi) in bands.items():
        lines[name] = ax.step(taus, value, where="post", label=f"{name} ({100 * value[-1]:.1f} %)", **styles[name])[0]
        ax.fill_between(taus, lo, hi, step="post", color=styles[name]["color"], alpha=0.12, linewidth=0)
    ax.set_xlim(taus[0], taus[-1])
    ax.set_ylim(0, 1.01)
    ax.set_xlabel("tau: steps / the genie's steps in the same episode")
    ax.set_ylabel("share of episodes solved within tau x the genie's steps")
    ax.set_title(f"Performance profiles, {where}")
    ax.grid(alpha=0.3)
    heights = {m: b[0][-1] for m, b in bands.items()}
    _legend_in_curve_order(ax, lines, heights, f"method (within {taus[-1]:g} x the genie)")
    fig.savefig(out, dpi=110)
    plt.close(fig)
    caption = (
        f"Performance profiles in {where}: for each method, the share of episodes that reached P_T within tau times the "
        "genie's steps in the same episode (a failure never does), tau from 1 (as fast as the genie) to "
        f"{taus[-1]:g}; shaded: 95 % bootstrap bands that resample the users, then their episodes (within each city "
        "when cities are pooled), as rliable draws score distributions. A curve above another is better at every "
        "tolerance; the legend is in the order of the curves' right ends."
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
            ax_gain.axhline(
                bounds[key],
                color="black",
                linestyle="--",
                linewidth=1,
                label=f"every episode ends exactly at P_T ({bounds[key]:.1f} dB)",
            )
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
    where = "; ".join(dict.fromkeys((notes or {}).values()))  # in words, once each: which bound, and why not another
    caption = (
        f"Training curves, one row per agent on its own step axis: the share of successful training episodes (left) "
        f"and the mean SINR gain (final minus start SINR; right), each over the last {RUNNING_WINDOW} training episodes "
        f"by the step at which they started (faint: the first {RUNNING_WINDOW - 1} episodes, a partial window). By start, "
        f"not by end: the first episodes to end are the quick successes, since a failure lasts t_max; the curves stop "
        f"where episodes started later might not have ended when training did. Training episodes explore (epsilon in the "
        f"title) and stop at the training t_max. Dashed: the paper's training bound, the mean over training users and "
        f"start cells of P_T - start SINR, i.e. the gain if every episode ended exactly at P_T; a successful episode "
        f"ends on the first cell at or above P_T, so the curve can pass it." + (f" The bound: {where}." if where else "")
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
                draw_blocked(ax, bundle.blocked, extent)
                target = reaches_target(bundle.sinr_db[user], p_t_db, bundle.dead[user], ~bundle.blocked)
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

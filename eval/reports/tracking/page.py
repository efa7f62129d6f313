"""``uavrl report --task tracking``: the moving-user task (``rl.tasks.tracking``) evaluated and written as a report.

Every method plays the same episodes of each city (routes, start times and start cells drawn from the report's
seed): the oracle (the most covered steps possible: the upper bound), the agents, the placement genie re-planned
every step, the tracking searcher (``rl.tasks.tracking.searcher``: the map searcher's belief carried through time), the steered
random walk and greedy hill-climbing; each method that cannot stay also holding its cell
while it covers the user (``rl.tasks.tracking.Holding``). Per method and city: the median steps to first reach P_T, the
coverage after it, the median longest outage, the share of the horizon covered and that share as a fraction of the
oracle's. Intervals are paired bootstrap 95 % intervals that resample the routes (a route plays the part a user
plays in placement: its episodes are alike), then the episodes of each drawn route (``eval.metrics.resample_counts``).

The folder ``OUT`` (default ``reports/tracking``) holds ``tracking.html`` (self-contained, the placement report's
style), ``tracking.csv`` (every statistic with its interval), ``tracking.md``, ``episodes.parquet``, per city
``<city>-coverage.png`` (the share of episodes covered at each step) and ``<city>-episodes.png`` (three episodes
on the maps, chosen by ``EPISODE_RULES``), and ``tracking.json`` (the config and what the report was made from).
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import Agent, check_unseen, report_agent
from uavplace.eval.figures import Figure, _pyplot, draw_blocked
from uavplace.eval.metrics import _weighted_quantile, resample_counts
from uavplace.eval.render import _CSS, _figure, _templates
from uavplace.eval.reports.tracking.config import TrackingReportConfig
from uavplace.infra.console import markdown_table
from uavplace.infra.files import atomic_directory, check_replaceable
from uavplace.rl.belief import PREDICTIONS, PredictionCache
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.policies import GreedyPolicy, RandomWalkPolicy
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.tasks.tracking import (
    Holding,
    MovesOnly,
    OraclePolicy,
    PlacementInTracking,
    ReplanningGenie,
    RouteSet,
    TrackingAgent,
    TrackingConfig,
    TrackingEpisodes,
    TrackingSearchPolicy,
    run_tracking,
)
from uavplace.schemas import InputError
from uavplace.schemas.base import uavplace_version
from uavplace.schemas.constants import reaches_target

TRACKING_JSON = "tracking.json"
#: Statistic -> (column header, how episodes are summarised).
STATS = {
    "first_reach": ("median steps to first reach P_T", "median"),
    "coverage": ("coverage after first reach", "mean"),
    "longest_outage": ("median longest outage [steps]", "median"),
    "covered_share": ("share of the horizon covered", "mean"),
}
UPPER_BOUND = "oracle"
#: The method every other is compared with, paired (covered share minus its): the best baseline that reads the map.
REFERENCE = "re-planning genie"
#: The title of ``summary_rows``'s table (every city side by side).
SUMMARY_TITLE = (
    "Share of the horizon covered in every city (as a fraction of the oracle's, 95 % interval over routes, then episodes)"
)
#: The episodes drawn on the maps, of the best method that is not the oracle, by its covered share.
EPISODE_RULES = ("the 10th percentile of its covered share", "its median covered share", "the 90th percentile")
_QUANTILES = (0.1, 0.5, 0.9)
_SHORT = ("10th percentile", "median", "90th percentile")


def tracking_methods(
    task: TrackingConfig, seed: int, agents: list[Agent] = (), hold: bool = True, searcher: TrackingSearchPolicy | None = None
) -> list:
    """The methods of the report: the upper bound first, then the agents (tracking agents on the observations they
    were trained with, ``TrackingAgent``; placement agents run unchanged, ``PlacementInTracking``), then the
    re-planning genie, the tracking searcher (when given) and the baselines. With ``hold``, every method that cannot
    stay (the placement agents, the random walk, greedy hill-climbing) is also played holding its cell while it covers
    the user (``Holding``), right after itself; tracking agents, the searcher, the genie and the oracle stay already."""
    played = []
    for a in agents:
        if isinstance(a.config.task, TrackingConfig):  # trained on the task: its own observation, it stays already
            played.append(TrackingAgent(a.policy, a.config.task.playing(a.config), a.name))
        else:
            played += _and_holding(PlacementInTracking(a.policy, a.config.env_config(evaluation=True), a.name), hold)
    baselines = [MovesOnly(RandomWalkPolicy(seed=seed)), MovesOnly(GreedyPolicy(task.p_h_db, seed=seed))]
    searchers = [] if searcher is None else [searcher]
    return [OraclePolicy(), *played, ReplanningGenie(), *searchers, *(m for b in baselines for m in _and_holding(b, hold))]


def _and_holding(method, hold: bool) -> list:  # noqa: ANN001 - a tracking method without a stay action
    return [method, Holding(method)] if hold else [method]


def _summary(values: np.ndarray, how: str, weights: np.ndarray) -> np.ndarray:
    """Each bootstrap replicate's summary ``[B]`` of ``values`` ``[n]`` under ``weights`` ``[B, n]``."""
    if how == "median":
        return _weighted_quantile(values, weights, 0.5)
    return weights @ values / weights.sum(axis=1)


def tracking_table(results: dict[str, TrackingEpisodes], n_boot: int, seed: int) -> pd.DataFrame:
    """One row per method: each statistic of ``STATS``, the covered share as a fraction of the oracle's, and the
    covered share minus the re-planning genie's (``REFERENCE``), with paired 95 % intervals (routes, then episodes
    within each drawn route; the same resamples for every method)."""
    first = next(iter(results.values())).table
    n = len(first)
    counts = resample_counts(first["route"].to_numpy(), n, n_boot, seed).astype(np.float64)
    ones = np.ones((1, n))
    bound, reference = results.get(UPPER_BOUND), results.get(REFERENCE)
    rows = []
    for name, res in results.items():
        row: dict[str, object] = {
            "city": first["city"].iloc[0],
            "method": name,
            "episodes": n,
            "routes": int(first["route"].nunique()),
        }
        for stat, (_, how) in STATS.items():
            v = res.table[stat].to_numpy(dtype=np.float64)
            row[stat] = float(_summary(v, how, ones)[0])
            lo, hi = np.quantile(_summary(v, how, counts), [0.025, 0.975], method="inverted_cdf")
            row[f"{stat}_lo"], row[f"{stat}_hi"] = float(lo), float(hi)
        if bound is not None:
            mine, best = res.table["covered_share"].to_numpy(), bound.table["covered_share"].to_numpy()
            row["of_oracle"] = float(mine.mean() / best.mean()) if best.mean() > 0 else np.nan
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = (counts @ mine) / (counts @ best)
            row["of_oracle_lo"], row["of_oracle_hi"] = (float(x) for x in np.nanquantile(ratio, [0.025, 0.975]))
        if reference is not None and name != REFERENCE:
            diff = res.table["covered_share"].to_numpy() - reference.table["covered_share"].to_numpy()
            row["minus_reference"] = float(diff.mean())
            lo, hi = np.quantile(counts @ diff / counts.sum(axis=1), [0.025, 0.975])
            row["minus_reference_lo"], row["minus_reference_hi"] = float(lo), float(hi)
        rows.append(row)
    return pd.DataFrame(rows)


def findings(table: pd.DataFrame, horizon: int) -> list[str]:
    """One sentence per city of ``table`` (``tracking_table``'s rows of every city): the method other than the oracle
    and the re-planning genie that keeps the user covered for the largest share of the horizon, as a fraction of the
    oracle's, and against the re-planning genie (paired)."""
    out = []
    for city, rows in table.groupby("city", sort=False):
        rivals = rows[~rows["method"].isin([UPPER_BOUND, REFERENCE])]
        if rivals.empty:
            continue
        r = rivals.sort_values("covered_share", ascending=False, kind="stable").iloc[0].to_dict()
        text = (
            f"In {city}, {r['method']} keeps the link for the largest share of the horizon: {_cell('covered_share', r, horizon)}"
        )
        if "of_oracle" in r and np.isfinite(r["of_oracle"]):
            text += f", {_cell('of_oracle', r, horizon)} of the oracle's"
        if "minus_reference" in r and np.isfinite(r["minus_reference"]):
            text += f"; against the {REFERENCE}, paired: {_cell('minus_reference', r, horizon)}"
        out.append(text + ".")
    return out


def _cell(stat: str, r: dict, horizon: int) -> str:
    v, lo, hi = r[stat], r[f"{stat}_lo"], r[f"{stat}_hi"]
    if stat in ("first_reach",):
        shown = lambda x: f"> {horizon}" if not np.isfinite(x) else f"{x:g}"  # noqa: E731
        return f"{shown(v)} [{shown(lo)}, {shown(hi)}]"
    if stat == "longest_outage":
        return f"{v:g} [{lo:g}, {hi:g}]"
    if stat == "minus_reference":
        return f"{v:+.3f} [{lo:+.3f}, {hi:+.3f}]"
    return f"{v:.3f} [{lo:.3f}, {hi:.3f}]"


def table_rows(table: pd.DataFrame, horizon: int) -> list[list[str]]:
    """The table as text cells (header first)."""
    rows = [["method", *(h for h, _ in STATS.values()), "covered share / the oracle's", f"covered share - the {REFERENCE}'s"]]
    for r in table.to_dict("records"):
        cells = [r["method"], *(_cell(s, r, horizon) for s in STATS)]
        for stat in ("of_oracle", "minus_reference"):
            cells.append("-" if stat not in r or np.isnan(r[stat]) else _cell(stat, r, horizon))
        rows.append(cells)
    return rows


def summary_rows(table: pd.DataFrame) -> list[list[str]]:
    """Every city side by side (header first): per method, in the report's order, each city's mean share of the
    horizon covered, then that share as a fraction of the oracle's with its interval ("-": not played there)."""
    cities = list(dict.fromkeys(table["city"]))
    rows = [["method", *cities]]
    for method, group in table.groupby("method", sort=False):
        by_city = group.set_index("city")
        cells = [method]
        for city in cities:
            r = by_city.loc[city] if city in by_city.index else None
            cells.append(
                "-" if r is None else f"{r.covered_share:.3f} ({r.of_oracle:.2f} [{r.of_oracle_lo:.2f}, {r.of_oracle_hi:.2f}])"
            )
        rows.append(cells)
    return rows


def tables_markdown(tables: list[pd.DataFrame], horizon: int) -> str:
    """``tracking.md``: each city's table (``tracking_table``), then, with several cities, ``summary_rows``'s."""
    md = [f"### {t['city'].iloc[0]}\n\n" + markdown_table(table_rows(t, horizon)) for t in tables]
    if len(tables) > 1:
        md.append(f"### {SUMMARY_TITLE}\n\n" + markdown_table(summary_rows(pd.concat(tables, ignore_index=True))))
    return "\n\n".join(md) + "\n"


def plot_coverage(results: dict[str, TrackingEpisodes], task: TrackingConfig, step_s: float, city: str, out: Path) -> Figure:
    """The share of episodes covered at each step, one curve per method."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9.5, 4.2), constrained_layout=True)
    t = np.arange(1, task.horizon + 1)
    for name, res in results.items():
        share = res.covered.mean(axis=0)
        ax.plot(
            t,
            share,
            label=f"{name} ({res.covered.mean():.3f})",
            linewidth=2.0 if name == UPPER_BOUND else 1.4,
            linestyle="--" if name == UPPER_BOUND else "-",
        )
    ax.set_xlim(1, task.horizon)
    ax.set_ylim(0, 1.01)
    ax.set_xlabel(f"step (one step: {step_s:g} s, a {task.uav_speed_mps:g} m/s UAV crossing one cell)")
    ax.set_ylabel("share of episodes covered")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, title="method (share of the horizon)", title_fontsize=8)
    ax.set_title(f"{city}: coverage over time")
    fig.savefig(out, dpi=110)
    plt.close(fig)
    n = len(next(iter(results.values())).table)
    caption = (
        f"{city}: the share of the {n} episodes in which the UAV covers the user (SINR at or above P_T = "
        f"{task.p_t_db:g} dB) at each step, one curve per method, all on the same episodes; in the legend, the "
        "mean over the horizon (the share of the horizon covered). The oracle, dashed, is the upper bound."
    )
    return Figure(out, caption)


def pick_episodes(results: dict[str, TrackingEpisodes], count: int) -> tuple[str, list[int]]:
    """The method drawn (the best by mean covered share that is not the oracle) and its episodes at the quantiles of
    ``EPISODE_RULES`` of its covered share (ties: the lowest episode index)."""
    candidates = {k: v for k, v in results.items() if k != UPPER_BOUND} or results
    method = max(candidates, key=lambda k: (candidates[k].table["covered_share"].mean(), k))
    share = candidates[method].table["covered_share"].to_numpy()
    order = np.argsort(share, kind="stable")
    return method, [int(order[min(len(order) - 1, int(q * len(order)))]) for q in _QUANTILES[:count]]


def plot_episodes(routes: RouteSet, res: TrackingEpisodes, method: str, picked: list[int], city: str, out: Path) -> Figure | None:
    """Each picked episode on two maps: the heights with the user's route and the UAV's path, and the share of the
    episode's steps at which each cell would have covered the user, with the same path."""
    if not picked:
        return None
    import matplotlib
    from matplotlib.lines import Line2D

    plt = _pyplot()
    task, p = routes.config, routes.maps.pad
    fig, axes = plt.subplots(len(picked), 2, figsize=(11, 4.6 * len(picked)), constrained_layout=True, squeeze=False)
    for row, e in enumerate(picked):
        r = int(res.table["route"].iloc[e])
        b = routes.bundles[routes.bundle[r]]
        ny, nx = b.shape
        g = b.manifest.grid
        extent = (g.x_min_m, g.x_max_m, g.y_min_m, g.y_max_m)
        points = res.points[e]
        covered = reaches_target(
            routes.sinr[points[1:], p : p + ny, p : p + nx], task.p_t_db, routes.dead[points[1:], p : p + ny, p : p + nx]
        )
        share = np.ma.masked_array(covered.mean(axis=0), mask=b.blocked)
        px = g.x_min_m + (res.path[e, :, 1] - p + 0.5) * g.spacing_m
        py = g.y_min_m + (res.path[e, :, 0] - p + 0.5) * g.spacing_m
        offset = sum(len(routes.bundles[i].routes) for i in range(routes.bundle[r]))  # rows of earlier bundles
        user = b.routes.iloc[points - offset]  # the user's position at each step
        route = b.routes.iloc[routes.first[r] - offset : routes.first[r] - offset + routes.count[r]]
        m = res.table.iloc[e]
        for col, ax in enumerate(axes[row]):
            if col == 0:
                im = ax.imshow(b.height_rel_m, origin="lower", extent=extent, cmap="viridis")
                fig.colorbar(im, ax=ax, shrink=0.8, label="height above ground [m]")
            else:
                im = ax.imshow(share, origin="lower", extent=extent, cmap=matplotlib.colormaps["magma"], vmin=0, vmax=1)
                draw_blocked(ax, b.blocked, extent)
                fig.colorbar(im, ax=ax, shrink=0.8, label="share of the steps the cell covers the user")
            ax.plot(route["x_m"], route["y_m"], color="cyan", linewidth=3, alpha=0.6, zorder=3)
            ax.plot(user["x_m"].iloc[0], user["y_m"].iloc[0], "*", color="cyan", markersize=13, markeredgecolor="black", zorder=5)
            ax.plot(
                user["x_m"].iloc[-1], user["y_m"].iloc[-1], "*", color="magenta", markersize=13, markeredgecolor="black", zorder=5
            )
            for color, width in (("black", 1.6), ("white", 0.6)):
                ax.plot(px, py, color=color, linewidth=width, zorder=4)
            ax.plot(px[0], py[0], "o", color="lime", markeredgecolor="black", zorder=5)
            ax.plot(px[-1], py[-1], "s", color="red", markeredgecolor="black", zorder=5)
            ax.set_title(
                f"episode {e} ({_SHORT[row]}): covered {m['covered_share']:.2f}, first reach {m['first_reach']:g}", fontsize=9
            )
    handles = [
        Line2D([], [], color="white", linewidth=2, label="UAV path"),
        Line2D([], [], marker="o", color="lime", markeredgecolor="black", linestyle="", label="UAV start"),
        Line2D([], [], marker="s", color="red", markeredgecolor="black", linestyle="", label="UAV end"),
        Line2D([], [], color="cyan", linewidth=3, alpha=0.6, label="user's route"),
        Line2D([], [], marker="*", color="cyan", markeredgecolor="black", linestyle="", markersize=11, label="user start"),
        Line2D([], [], marker="*", color="magenta", markeredgecolor="black", linestyle="", markersize=11, label="user end"),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncol=6, fontsize=8, facecolor="0.85")
    fig.savefig(out, dpi=90)
    plt.close(fig)
    caption = (
        f"{city}: three episodes of {method} (the best method but the oracle by its mean covered share), picked "
        f"at {', '.join(EPISODE_RULES[: len(picked)])} of its covered share. Left: heights; right: the share of "
        "the episode's steps at which each cell would have covered the user (blocked cells black). The user walks "
        "the cyan route (to its end and back) from the cyan star to the magenta one; the UAV's path is the white "
        "line from the green circle to the red square."
    )
    return Figure(out, caption)


def _play_cities_on_ray(
    cities: list[tuple], searcher: TrackingSearchPolicy | None, on_progress: Callable[[str], None] | None
) -> list[dict[str, TrackingEpisodes]]:
    """Every city's methods as Ray tasks in one go (``eval.parallel``), so that no worker waits for a city's last
    piece or its tables before the next city starts: each city's ``{method: episodes}``, as played one after another.
    The searcher's maps of every city are made first, here, and kept in the cache the tasks read."""
    from uavplace.eval.parallel import Method, play_on_ray

    on_ray, named = [], {}
    for number, (b, routes, episodes, methods) in enumerate(cities, 1):
        if searcher is not None:
            searcher.predict(routes)
        for p in methods:
            key = f"{number}/{p.name}"  # a method's name is its own only within its city
            named[key] = (number, b.city, p.name)
            on_ray.append(Method(key, p, routes, episodes, options={"record": True}))

    def told(key: str, done: int, total: int) -> None:
        if on_progress is not None:
            number, city, name = named[key]
            on_progress(f"city {number} of {len(cities)}: {city}, {name}: {done} of {total} episodes")

    played: list[dict[str, TrackingEpisodes]] = [{} for _ in cities]
    for key, episodes in play_on_ray(on_ray, run_tracking, TrackingEpisodes.joined, told).items():
        number, _, name = named[key]
        played[number - 1][name] = episodes
    return played


def make_tracking_report(
    config: TrackingReportConfig,
    out: str | Path,
    *,
    root: str | Path = "data/processed",
    command: str = "",
    on_progress: Callable[[str], None] | None = None,
    parallel: bool = False,
) -> tuple[pd.DataFrame, Path]:
    """Evaluate every method on each city of ``config`` and write the report folder ``out`` (atomically; an existing
    folder is replaced only if it is a tracking report). Returns the table (every city) and the page. ``parallel``:
    the methods' rollouts as Ray tasks (``eval.parallel``; Ray started or joined by the caller), the same episodes as
    one after the other here."""
    out = Path(out)
    check_replaceable(out, TRACKING_JSON, "tracking report")
    bundles = [load_bundle(name, root=root) for name in config.datasets]
    agents = [report_agent(r, config, None) for r in config.runs]
    for b in bundles:
        if b.routes is None:
            raise InputError(
                b.path,
                "this bundle has no routes: simulate them with `uavdata simulate ... --routes N`, then ingest and build",
                field="routes",
            )
        check_unseen(agents, b)
    sections, provenance, figures_all = [], [], []
    per_city: list[tuple] = []
    searcher = None
    if config.predictor is not None:
        cache = PredictionCache(Path(root) / PREDICTIONS)
        placement = MapSearchPolicy(load_predictor(config.predictor), config.search, cache, device=config.device)
        searcher = TrackingSearchPolicy(placement, config.motion)
    cities = []  # (bundle, its routes, its episodes, its methods), every city's before any is played
    for b in bundles:
        routes = RouteSet([b], config.task)
        try:
            episodes = routes.sample_episodes(config.episodes, np.random.default_rng([config.seed, 7]))
        except ValueError:  # no start below P_T with a target reachable: P_T above or below every route's maps
            raise InputError(
                b.path,
                f"at P_T = {config.task.p_t_db:g} dB no route has a start time and a cell below "
                "P_T from which a cell at P_T is reachable: choose another --p-t-db",
                field="p_t_db",
            ) from None
        cities.append((b, routes, episodes, tracking_methods(config.task, config.seed, agents, config.hold, searcher)))
    if parallel:
        played = _play_cities_on_ray(cities, searcher, on_progress)
    else:
        played = []
        for number, (b, routes, episodes, methods) in enumerate(cities, 1):
            results: dict[str, TrackingEpisodes] = {}
            for j, policy in enumerate(methods, 1):
                if on_progress is not None:
                    on_progress(f"city {number} of {len(cities)}: {b.city}, method {j} of {len(methods)}: {policy.name}")
                results[policy.name] = run_tracking(routes, policy, episodes, record=True)
            played.append(results)
    per_city = [
        (b, routes, results, tracking_table(results, config.n_boot, config.seed))
        for (b, routes, _, _), results in zip(cities, played, strict=True)
    ]
    with atomic_directory(out, marker=TRACKING_JSON, what="tracking report") as tmp:
        number = 1
        for b, routes, results, table in per_city:
            step_s = float(routes.step_s[0])
            figs = [plot_coverage(results, config.task, step_s, b.city, tmp / f"{b.city}-coverage.png")]
            method, picked = pick_episodes(results, config.trajectories)
            figs.append(plot_episodes(routes, results[method], method, picked, b.city, tmp / f"{b.city}-episodes.png"))
            shown = [
                _figure(f, number + i, alt)
                for i, (f, alt) in enumerate(zip(figs, ("coverage over time", "episodes"), strict=True))
            ]
            number += len(shown)
            rows = table_rows(table, config.task.horizon)
            kinds = routes.names
            sections.append(
                _templates()
                .get_template("tracking_section.html.j2")
                .render(
                    city=b.city,
                    bundle=b.version,
                    episodes=config.episodes,
                    routes=routes.num_routes,
                    kinds=", ".join(sorted({k for _, _, k in kinds})),
                    horizon=config.task.horizon,
                    step_s=f"{step_s:g}",
                    speed=f"{config.task.uav_speed_mps:g}",
                    p_t=f"{config.task.p_t_db:g}",
                    n_boot=config.n_boot,
                    rows=rows,
                    figures=shown,
                )
            )
            provenance.append(
                {
                    "city": b.city,
                    "bundle": b.version,
                    "routes": routes.num_routes,
                    "route_points": len(b.routes),
                    "drawn": {"method": method, "episodes": picked},
                }
            )
            figures_all += [f.caption for f in figs if f is not None]
            episodes_frame = pd.concat([r.table.assign(method=name) for name, r in results.items()], ignore_index=True)
            episodes_frame.to_parquet(tmp / f"{b.city}-episodes.parquet", index=False)
        tables = [t for *_, t in per_city]
        table = pd.concat(tables, ignore_index=True)
        table.to_csv(tmp / "tracking.csv", index=False)
        (tmp / "tracking.md").write_text(tables_markdown(tables, config.task.horizon), encoding="utf-8")
        record = {
            "command": command,
            "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            "uavplace_version": uavplace_version(),
            "config": json.loads(config.model_dump_json()),
            "cities": provenance,
            "figures": figures_all,
            "agents": {
                a.name: {"folder": str(a.folder), "trained_on": a.trained_on or None, "selected_on": a.selected_on or None}
                for a in agents
            },
        }
        import markupsafe

        page = (
            _templates()
            .get_template("tracking.html.j2")
            .render(
                css=markupsafe.Markup(_CSS),
                cities=", ".join(b.city for b in bundles),
                made=record["created_utc"],
                command=command,
                sections=[markupsafe.Markup(s) for s in sections],
                raw=json.dumps(record, indent=2),
                findings=findings(table, config.task.horizon),
            )
        )
        (tmp / "tracking.html").write_text(page, encoding="utf-8")
        (tmp / TRACKING_JSON).write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return table, out / "tracking.html"

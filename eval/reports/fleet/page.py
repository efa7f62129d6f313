"""``uavrl report --task fleet``: the fleet task (``rl.tasks.fleet``) evaluated on the same episodes of each city.

Every method plays the same episodes (``FleetMaps.episode_list`` of the report's seed): the oracle (the fewest steps
until every user is served, knowing every map: the bound), the map searcher run for the fleet, placement agents run
independently on every UAV (``FleetPlacement``: by default the shipped ``best``), greedy hill-climbing and the steered
random walk per UAV. Per method and city the placement report's statistics, with the oracle in the
genie's place: success (every user served at one step within ``t_max``), median and 75th percentile steps, the
ratios to the oracle's steps and SPL against the oracle; intervals are paired bootstrap 95 % intervals that resample
the user sets, then the episodes of each (``eval.metrics``); paired differences against the oracle and against
the first independent agent (greedy hill-climbing without one): the baseline every fleet method must beat.

The folder ``OUT`` (default ``reports/fleet``) holds ``fleet.html`` (self-contained, the placement and tracking
reports' style), ``fleet.md`` (every table and figure), per city
``<city>-episodes.png`` (the first method's episodes at the 10th, 50th and 90th percentiles of its steps on the
heights: every UAV's path, every user's position), ``results.csv``,
``differences.csv``, ``episodes.parquet`` and ``fleet.json`` (the config and the bundle versions), replaced only
if it is a fleet report (``fleet.json``).
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from uavplace.dataset.bundle import Bundle, load_bundle
from uavplace.eval.evaluate import report_agent
from uavplace.eval.figures import Figure
from uavplace.eval.findings import city_findings, difference_cell
from uavplace.eval.metrics import bootstrap_table, difference_table
from uavplace.eval.render import _CSS, _figure, _templates, difference_rows
from uavplace.eval.reports.fleet.config import FleetReportConfig
from uavplace.infra.console import markdown_list, markdown_table
from uavplace.infra.files import atomic_directory, check_replaceable
from uavplace.rl.belief import PREDICTIONS, PredictionCache
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.fleet import (
    FleetConfig,
    FleetGreedy,
    FleetMaps,
    FleetPlacement,
    FleetRandomWalk,
    FleetSearcher,
    run_fleet,
)
from uavplace.rl.world.stats import STATS, format_stat
from uavplace.schemas.base import InputError, uavplace_version

FLEET_JSON = "fleet.json"
ORACLE = "oracle"
#: The placement agent each UAV runs by default (``uavrl report --task fleet`` without ``--run``), from ``--agents-dir``,
#: beside every shipped agent trained on the fleet task (``uavrl train --task fleet``).
DEFAULT_AGENT = "best"


#: The agents' tasks the fleet report plays, each with the prefix of its name in the tables (None: the placement
#: agent's, the UAVs playing it independently; "": a fleet-trained agent's name says it, PQN + GRU (best, fleet)).
_FLEET_PREFIX: dict[str, str | None] = {"placement": None, "fleet": ""}


def fleet_results(
    config: FleetReportConfig,
    bundle: Bundle,
    root: Path,
    on_progress: Callable[[str], None] | None = None,
    parallel: bool = False,
) -> dict[str, pd.DataFrame]:
    """``{method: run_fleet frame}`` of one city's bundle, the oracle first. ``parallel``: the methods' rollouts as
    Ray tasks (``eval.parallel``; Ray started or joined by the caller), the same frames as one after the other."""
    city = bundle.city
    maps = FleetMaps.of([bundle], config.task)
    episodes = maps.episode_list(config.episodes, config.seed)
    policies = []
    if config.predictor is not None:
        cache = PredictionCache(Path(root) / PREDICTIONS)
        searcher = FleetSearcher(load_predictor(config.predictor), config.search, cache, device=config.device)
        policies.append(searcher.bind(maps))
    for run in config.runs:
        agent = report_agent(run, config, None)
        if agent.config.task.kind not in _FLEET_PREFIX:
            raise InputError(
                run, f"a {agent.config.task.kind} agent: the fleet plays placement agents and fleet-trained ones", field="task"
            )
        prefix = _FLEET_PREFIX[agent.config.task.kind]
        policies.append(
            FleetPlacement(agent.policy, agent.config.env_config(evaluation=True), agent.name, prefix=prefix).bind(maps)
        )
    policies += [FleetRandomWalk(config.seed), FleetGreedy(config.seed)]
    kept = [np.arange(len(episodes))] + [None] * (len(policies) - 1)  # the first method's paths: the figure draws three
    results: dict[str, pd.DataFrame] = {}
    if parallel:
        from uavplace.eval.parallel import Method, play_on_ray

        def told(name: str, done: int, total: int) -> None:
            if on_progress is not None:
                on_progress(f"{city}, {name}: {done} of {total} episodes")

        for p in policies:  # the searcher's maps made once here, kept in the cache the tasks read
            if isinstance(p, FleetSearcher):
                p.predict()
        on_ray = [Method(p.name, p, maps, episodes, record) for p, record in zip(policies, kept, strict=True)]
        results = play_on_ray(on_ray, run_fleet, on_progress=told)
    else:
        for i, (policy, record) in enumerate(zip(policies, kept, strict=True)):
            if on_progress is not None:
                on_progress(f"{city}, method {i + 1} of {len(policies)}: {policy.name}")
            results[policy.name] = run_fleet(maps, policy, episodes, record=record)
    first = next(iter(results.values()))
    reached = first["oracle_steps"] <= config.task.t_max
    oracle = first.assign(success=reached, steps=first["oracle_steps"].where(reached, config.task.t_max + 1))
    oracle.attrs = {}
    return {ORACLE: oracle.assign(spl=reached.astype(float))} | results


def reference(results: dict[str, pd.DataFrame]) -> str:
    """The baseline every fleet method is compared with, paired: the first independent agent, else greedy."""
    return next((m for m in results if m.startswith(FleetPlacement.prefix)), FleetGreedy.name)


#: The episodes the figure draws: the shown method's steps at these percentiles (failures count as beyond t_max).
PERCENTILES = (10, 50, 90)


def picked_episodes(frame: pd.DataFrame) -> list[tuple[int, int]]:
    """(percentile, episode) for ``PERCENTILES``: the episode whose steps are the order statistic at each."""
    order = frame.sort_values(["steps", "episode"], kind="stable")["episode"].to_numpy()
    return [(q, int(order[min(len(order) - 1, int(q / 100 * len(order)))])) for q in PERCENTILES]


def plot_fleet_episodes(bundle: Bundle, frame: pd.DataFrame, method: str, config: FleetConfig, out: Path) -> str:
    """Three of ``method``'s episodes (``picked_episodes``) on the city's heights: every UAV's path and every user's
    position; saves ``out`` and returns the figure's caption."""
    from uavplace.eval.figures import _pyplot

    plt = _pyplot()
    g = bundle.manifest.grid
    extent = (g.x_min_m, g.x_max_m, g.y_min_m, g.y_max_m)
    picks = picked_episodes(frame)
    fig, axes = plt.subplots(1, len(picks), figsize=(4.4 * len(picks), 4.6), constrained_layout=True, squeeze=False)
    colors = ("red", "orange", "magenta", "white")
    rows = frame.set_index("episode")
    for ax, (q, ep) in zip(axes[0], picks, strict=True):
        row = rows.loc[ep]
        im = ax.imshow(bundle.height_rel_m, origin="lower", extent=extent, cmap="viridis")
        ax.contour(bundle.blocked, levels=[0.5], origin="lower", extent=extent, colors="black", linewidths=1.0)
        cells = frame.attrs["paths"][ep]  # [T + 1, K, 2] (iy, ix)
        for k in range(cells.shape[1]):
            px = g.x_min_m + (cells[:, k, 1] + 0.5) * g.spacing_m
            py = g.y_min_m + (cells[:, k, 0] + 0.5) * g.spacing_m
            ax.plot(px, py, color=colors[k % len(colors)], linewidth=1.4, label=f"UAV {k + 1}")
            ax.plot(px[0], py[0], "o", color=colors[k % len(colors)], markeredgecolor="black")
        for u in (int(v) for v in str(row["user"]).split("-")):
            user = bundle.users.iloc[u]
            ax.plot(user["x_m"], user["y_m"], "*", color="cyan", markersize=13, markeredgecolor="black")
        outcome = f"{int(row['steps'])} steps" if row["success"] else f"not all served in {config.t_max} steps"
        ax.set_title(
            f"{q}th percentile: episode {ep}, users {row['user']}\n{outcome} (oracle {int(row['oracle_steps'])})", fontsize=9
        )
        ax.tick_params(labelsize=7)
        fig.colorbar(im, ax=ax, shrink=0.8).set_label("building height - altitude [m]", fontsize=7)
    axes[0][0].legend(fontsize=7, loc="upper left")
    fig.suptitle(f"{method} in {bundle.city}: {config.uavs} UAVs, {config.users} users", fontsize=10)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return (
        f"{method} in {bundle.city}: the episodes at the {', '.join(str(q) for q in PERCENTILES)}th percentiles of "
        "its steps (chosen by rule, failures counted beyond t_max), on the building heights (black: the edges of "
        "blocked cells). Lines: each UAV's path from its circle; stars: the users."
    )


def table_rows(table: pd.DataFrame, t_max: int) -> list[list[str]]:
    """The results table as text cells (header first), the genie's columns named for the oracle."""
    names = [STATS[s].replace("genie", "oracle") for s in STATS]
    rows = [["method", *names]]
    for r in table.to_dict("records"):
        rows.append([r["method"], *(format_stat(s, r[s], r[f"{s}_lo"], r[f"{s}_hi"], t_max) for s in STATS)])
    return rows


#: The summary's title: what each cell holds.
SUMMARY_TITLE = (
    "success / median steps (median of per-episode steps / the oracle's) per method and city; then each "
    "method minus the reference, paired"
)


def summary_rows(table: pd.DataFrame, diff: pd.DataFrame, t_max: int) -> list[list[str]]:
    """Header then one row per method: in each city, ``success / median steps (steps / oracle)``, then its paired
    difference from the city's reference (``reference``: success, median steps), with 95 % intervals."""
    cities = list(dict.fromkeys(table["city"]))
    refs = {c: str(diff[(diff["city"] == c) & (diff["against"] != ORACLE)]["against"].iloc[0]) for c in cities}
    header = ["method", *(f"{c}: success / median steps (x oracle)" for c in cities), *(f"{c}: minus {refs[c]}" for c in cities)]
    rows = [header]
    for method in dict.fromkeys(table["method"]):
        cells = [str(method)]
        for c in cities:
            r = table[(table["city"] == c) & (table["method"] == method)].iloc[0]
            shown = [format_stat(s, r[s], r[f"{s}_lo"], r[f"{s}_hi"], t_max) for s in ("success", "median_steps")]
            cells.append(f"{shown[0]} / {shown[1]} ({format_stat('steps_over_genie', r['steps_over_genie'], t_max=t_max)})")
        for c in cities:
            d = diff[(diff["city"] == c) & (diff["method"] == method) & (diff["against"] == refs[c])]
            cells.append(
                "-" if d.empty else " / ".join(difference_cell(s, d[d["stat"] == s].iloc[0]) for s in ("success", "median_steps"))
            )
        rows.append(cells)
    return rows


def make_fleet_report(
    config: FleetReportConfig,
    out: Path,
    root: Path,
    command: str = "",
    on_progress: Callable[[str], None] | None = None,
    parallel: bool = False,
) -> tuple[pd.DataFrame, pd.DataFrame, Path]:
    """Play every city, tabulate, and write ``out`` (see the module's docstring). Returns (results table, paired
    differences, the Markdown file), every city in each. ``parallel``: the rollouts on Ray (``fleet_results``)."""
    check_replaceable(out, FLEET_JSON, "fleet report")
    tables, diffs, frames, sections, versions, shown_episodes, found = [], [], [], [], {}, {}, []
    pages: dict[str, dict] = {}  # per city: what its section of fleet.html shows
    for number, city in enumerate(config.datasets, 1):
        bundle = load_bundle(city, root=root)
        where = f"city {number} of {len(config.datasets)}: "
        told = on_progress and (lambda what, where=where: on_progress(where + what))
        results = fleet_results(config, bundle, root, told, parallel)
        shown = next(m for m in results if m != ORACLE)
        shown_episodes[city] = (bundle, results[shown], shown)
        table = bootstrap_table(results, n_boot=config.n_boot, seed=config.seed)
        diff = difference_table(results, [ORACLE, reference(results)], n_boot=config.n_boot, seed=config.seed)
        tables.append(table.assign(city=city))
        diffs.append(diff.assign(city=city))
        frames += [df.assign(method=m, city_name=city) for m, df in results.items()]
        versions[city] = bundle.version
        head = (
            f"**{city}** ({config.episodes} episodes, {config.task.uavs} UAVs and {config.task.users} users, "
            f"t_max {config.task.t_max}, P_T {config.task.p_t_db:g} dB; 95 % intervals over user sets, then episodes)"
        )
        rows, diff_rows = table_rows(table, config.task.t_max), difference_rows(diff, config.task.t_max)
        sections += [
            head,
            markdown_table(rows),
            f"Paired differences in {city}, method minus reference (95 % intervals):",
            markdown_table(diff_rows),
        ]
        pages[city] = {"bundle": bundle.version, "rows": rows, "differences": diff_rows}
        said = city_findings(table, diff, config.task.t_max, bound=ORACLE, succeed="serve every user")
        found += [f"In {city}: {f}" for f in said]
    sections.insert(0, markdown_list(found))
    table, diff = pd.concat(tables, ignore_index=True), pd.concat(diffs, ignore_index=True)
    summary = summary_rows(table, diff, config.task.t_max) if len(config.datasets) > 1 else None
    if summary:
        sections += [f"Every city: {SUMMARY_TITLE} (95 % intervals).", markdown_table(summary)]
    with atomic_directory(out, marker=FLEET_JSON, what="fleet report") as tmp:
        for number, (city, (bundle, frame, method)) in enumerate(shown_episodes.items(), start=1):
            path = tmp / f"{city}-episodes.png"
            caption = plot_fleet_episodes(bundle, frame, method, config.task, path)
            sections.append(f"![{caption}]({city}-episodes.png)\n\n{caption}")
            pages[city]["figure"] = _figure(Figure(path, caption), number, f"episodes in {city}")
        (tmp / "fleet.md").write_text("\n\n".join(sections) + "\n", encoding="utf-8")
        table.to_csv(tmp / "results.csv", index=False)
        diff.to_csv(tmp / "differences.csv", index=False)
        pd.concat(frames, ignore_index=True).to_parquet(tmp / "episodes.parquet", index=False)
        doc = {
            "config": config.model_dump(mode="json"),
            "bundles": versions,
            "command": command,
            "uavplace_version": uavplace_version(),
            "created_utc": dt.datetime.now(dt.UTC).isoformat(),
        }
        (tmp / FLEET_JSON).write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        (tmp / "fleet.html").write_text(fleet_page(config, pages, summary, doc, found), encoding="utf-8")
    return table, diff, out / "fleet.md"


def fleet_page(
    config: FleetReportConfig, pages: dict[str, dict], summary: list[list[str]] | None, doc: dict, findings: list[str]
) -> str:
    """``fleet.html``: self-contained, the placement and tracking reports' style: what it found (``findings``), the
    summary of every city (with more than one), then per city its table, its paired differences and its figure
    (``pages``), then ``fleet.json``."""
    import markupsafe

    task = config.task
    sections = [
        _templates()
        .get_template("fleet_section.html.j2")
        .render(city=city, episodes=config.episodes, users=task.users, uavs=task.uavs, n_boot=config.n_boot, **page)
        for city, page in pages.items()
    ]
    return (
        _templates()
        .get_template("fleet.html.j2")
        .render(
            css=markupsafe.Markup(_CSS),
            cities=", ".join(pages),
            uavs=task.uavs,
            users=task.users,
            p_t=f"{task.p_t_db:g}",
            t_max=task.t_max,
            made=doc["created_utc"],
            command=doc["command"],
            summary=summary,
            summary_title=SUMMARY_TITLE,
            findings=findings,
            sections=[markupsafe.Markup(s) for s in sections],
            raw=json.dumps(doc, indent=2),
        )
    )

"""`uavrl report`: the paper's evaluation protocol on a test city, and a self-contained HTML report.

The recipe (``make_report``):

1. load the test city's bundle and every agent (a run folder or a shipped agent folder);
2. draw the episodes once (seeded): a uniformly random user, then a uniformly random valid start;
3. play them with every method (the learned agents, the genie, the steered random walk, greedy
   hill-climbing), batched, the same episodes for all;
4. tabulate success rate and steps to P_T with paired bootstrap 95 % intervals, beside the paper's;
5. draw the CDF of steps to P_T, the performance profiles, the training curves, a few trajectories;
   say what it found (``eval.findings``: the leader, by how much, whether the map matters) above the tables;
6. write ``report.html`` (figures embedded), the PNGs, the tables (CSV and Parquet), every
   episode (Parquet) and ``report.json`` (config and provenance) into a temporary folder that is
   renamed into place.
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import torch

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import (
    ReportConfig,
    ablation_table,
    blanked_agents,
    blanked_results,
    check_unseen,
    default_baselines,
    evaluate,
    groups_of,
    references,
    report_agent,
    results_table,
    shown_method,
    stages,
    training_bounds,
    unlike_training,
)
from uavplace.eval.figures import Figure, pick_trajectories, plot_cdf, plot_profiles, plot_training, plot_trajectories
from uavplace.eval.metrics import difference_table, group_tables, profiles
from uavplace.eval.render import (
    Report,
    city_top,
    difference_rows,
    group_rows,
    render_page,
    render_section,
    table_rows,
)
from uavplace.infra.files import atomic_directory, check_replaceable
from uavplace.schemas.base import repeated, uavplace_version

#: A report folder's marker: only a folder holding it is ever replaced.
REPORT_JSON = "report.json"


def make_report(
    config: ReportConfig,
    out: str | Path,
    *,
    root: str | Path = "data/processed",
    command: str = "",
    on_progress: Callable[[str, int, int], None] | None = None,
    on_plan: Callable[[list[str]], None] | None = None,
    on_status: Callable[[str], None] | None = None,
    parallel: bool = False,
) -> Report:
    """Evaluate every method on ``config.dataset`` and write the report folder ``out`` (atomically).

    Everything that can fail is checked before the first episode: the output
    folder (replaced only if it is a report, ``report.json``), the test bundle,
    every agent (weights only), and that no agent was trained in the test city.
    A training city whose bundle is not built here only loses its upper bound.
    ``on_plan`` is told every stage (``evaluate.stages``) before the first; ``on_progress`` each stage's
    ``(stage, done, total)`` as it goes; ``on_status`` what is being loaded before the first stage. ``parallel``:
    the methods as Ray tasks (``eval.parallel``), the same numbers.
    """
    out = Path(out)
    check_replaceable(out, REPORT_JSON, "report")
    status = on_status or (lambda _: None)
    status(f"loading the bundle of {config.dataset}")
    bundle = load_bundle(config.dataset, root=root)
    status(f"loading {len(config.runs)} agents")
    agents = [report_agent(r, config) for r in config.runs]
    check_unseen(agents, bundle)
    twice = set(repeated([a.name for a in agents]))
    for a in agents:  # same agent and preset twice: tell them apart by folder
        if a.name in twice:
            a.name = a.policy.name = f"{a.name} [{a.folder.name}]"
    # what the command warned of, said on the page too: agents played outside their training settings
    cautions = unlike_training([Path(r) for r in config.runs], [config.dataset], root, config.p_t_db)
    status("reading the agents' training cities (their upper bounds)")
    bounds, bound_notes = training_bounds(agents, root, config.p_t_db)
    status("setting up the baselines and the map searcher")
    baselines = default_baselines(config, bundle)
    blanked = blanked_agents(config, agents) if config.ablate else []
    if on_plan is not None:
        played = [(m.name, m.policy) for m in agents] + [(p.name, p) for p in baselines]
        on_plan(stages(played) + stages([(m.name, m.policy) for m in blanked]))
    results = evaluate(config, bundle, agents, on_progress, baselines=baselines, parallel=parallel)
    results |= blanked_results(config, bundle, blanked, on_progress, parallel)
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
        bands = profiles(results, n_boot=config.n_boot, seed=config.seed)
        figures["profile"] = plot_profiles(bands, bundle.city, tmp / "profile.png")
        figures["training"] = plot_training(agents, bounds, tmp / "training.png", bound_notes)
        shown = shown_method(agents, results)
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
            "test_bundle_cells": bundle.cell_sources(),
            "upper_bounds_db": bounds,
            "upper_bounds_notes": bound_notes,
            "cautions": cautions,
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
        top = city_top(table, differences, config, bundle.city, cautions)
        (tmp / "report.html").write_text(render_page([section], [provenance], top), encoding="utf-8")
        (tmp / REPORT_JSON).write_text(json.dumps(provenance, indent=2) + "\n", encoding="utf-8")
    figures = {k: None if v is None else Figure(out / v.path.name, v.caption) for k, v in figures.items()}
    return Report(out, table, differences, episodes, config, rows, diff_rows, figures, provenance, top, grows)


def _plain(df: pd.DataFrame) -> pd.DataFrame:
    df.attrs = {}  # the recorded paths stay with the per-method frames
    return df

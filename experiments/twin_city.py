"""The shipped agents in a city whose every cell comes from exact paths, against its radio-map twin (issue 32).

Two simulations of one crop with the same users, the same grid and the same settings but the solver:
``--solver paths`` (Sionna's PathSolver at every open cell: every path found, as Wireless InSite computes
them, nothing filled) and the radio map with its gap fill, as every embedded city is made. Both are ingested
and built as any city. The episodes are drawn on the exact-path city (the report's draw: ``--seed``) and kept
where they can start in the twin too (a legal, live cell below P_T from which a target is reachable in both),
so that every method plays the same users from the same cells in both cities (``eval.evaluate.evaluate``: t_max
500, test epsilon 0.096; the test-epsilon moves are drawn per episode and city).

Prints, for every agent and the genie: success and median steps in each city with 95 % intervals that resample
users, then episodes, and the paired difference exact paths - radio map with its interval; then the cities'
dead/live agreement and the SINR error of the radio map against the exact paths over the open cells. Targets
(issue 32): success within 3 points and median steps within 20 %. ``--csv`` writes the table.

    uavdata simulate sionna:florence --crop=364,-88,492,40 --name florence-twin-map --users 4 --seed 8 --samples 1.6e7
    uavdata simulate sionna:florence --crop=364,-88,492,40 --name florence-twin-paths --users 4 --seed 8 \\
        --solver paths --samples 2e6
    uavdata ingest data/raw/florence-twin-map/ && uavdata ingest data/raw/florence-twin-paths/
    uavdata build --city florence-twin-map --city florence-twin-paths --grid 4m --alt 10
    python experiments/twin_city.py --paths florence-twin-paths --radio-map florence-twin-map --p-t-db 20
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from uavplace.dataset.bundle import Bundle, load_bundle
from uavplace.eval.cities import development_cities
from uavplace.eval.evaluate import ReportConfig, default_agents, evaluate, load_agent
from uavplace.eval.metrics import bootstrap_table, difference_table
from uavplace.infra.console import markdown_table
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.stats import format_stat

#: The two cities' labels in the table.
PATHS, RADIO = "exact paths", "radio map"


def same_episodes(paths: Bundle, radio: Bundle, config: ReportConfig) -> tuple[np.ndarray, int]:
    """``config.episodes`` specs drawn on ``paths`` (the report's draw, then as many more as needed) that start in
    ``radio`` too, and how many of the draws were dropped for not starting there."""
    base = EnvConfig(t_max=config.t_max, p_t_db=config.p_t_db, split=config.split, rotate=False)
    maps_p, maps_r = MapSet([paths], base), MapSet([radio], base)
    rng = np.random.default_rng(config.seed)
    kept, dropped = [], 0
    while sum(len(k) for k in kept) < config.episodes:
        if dropped > 100 * config.episodes:
            raise SystemExit(f"{radio.manifest.city}: almost no start of {paths.manifest.city} starts there; not twins?")
        draw = maps_p.sample_episodes(config.episodes, rng)
        ok = maps_r.can_start(draw)  # the same users in the same order, the same canvas: the same specs
        kept.append(draw[ok])
        dropped += int((~ok).sum())
    return np.concatenate(kept)[: config.episodes], dropped


def stat_cell(row: pd.Series, stat: str) -> str:
    """A statistic of a ``bootstrap_table`` row with its interval, as the report writes it (t_max 500)."""
    return format_stat(stat, row[stat], row[f"{stat}_lo"], row[f"{stat}_hi"], t_max=500)


def difference_cell(difference: float, lo: float, hi: float, scale: float = 1, unit: str = "") -> str:
    """A paired difference with its interval, times ``scale`` (100: points), or "undefined" (a median beyond t_max)."""
    if not np.isfinite(difference):
        return "undefined"
    return f"{scale * difference:+.1f} [{scale * lo:+.1f}, {scale * hi:+.1f}]{unit}"


def summary(csvs: list[Path], first: str, second: str) -> None:
    """Print several cities' ``--csv`` tables as one (the city: each file's stem): success and median steps in the
    ``first`` and the ``second`` (``--labels``), their paired difference (first - second) and the maps' dead/live agreement."""
    print(f"| city | method | success: {first} / {second} | difference [points] | median steps: {first} / {second} | "
          "difference [steps] | dead/live agreement |\n|---|---|---|---|---|---|---|")  # fmt: skip
    for csv in csvs:
        for r in pd.read_csv(csv).itertuples():
            steps = " / ".join(format_stat("median_steps", v, t_max=500) for v in (r.median_steps_paths, r.median_steps_radio))
            print(f"| {csv.stem} | {r.method} | {100 * r.success_paths:.1f} / {100 * r.success_radio:.1f} % | "
                  f"{difference_cell(r.success_difference, r.success_difference_lo, r.success_difference_hi, 100)} | "
                  f"{steps} | {difference_cell(r.median_steps_difference, r.median_steps_difference_lo, r.median_steps_difference_hi)} | "
                  f"{100 * r.agreement:.1f} % |")  # fmt: skip


def map_agreement(paths: Bundle, radio: Bundle) -> dict[str, float]:
    """Over the open cells of every user: the share where both call a cell dead or both live, and the radio map's
    SINR error against the exact paths where both are live (median and 90th percentile of |error|, dB)."""
    open_ = np.broadcast_to(~paths.blocked, paths.dead.shape)
    live_p, live_r = ~paths.dead & open_, ~radio.dead & open_
    both = live_p & live_r
    err = np.abs(radio.sinr_db[both] - paths.sinr_db[both])
    return {
        "agreement": float((live_p == live_r)[open_].mean()),
        "live_exact": float(live_p[open_].mean()),
        "live_radio": float(live_r[open_].mean()),
        "median_abs_db": float(np.median(err)),
        "p90_abs_db": float(np.quantile(err, 0.9)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", help="The city traced with --solver paths (required unless --summary)")
    ap.add_argument("--radio-map", help="Its twin traced with the radio map (required unless --summary)")
    ap.add_argument("--summary", type=Path, nargs="+", metavar="CSV",
                    help="Print the --csv tables of earlier runs as one (a city each: the file's stem) and exit")  # fmt: skip
    ap.add_argument("--agent", type=Path, action="append", default=None, help="A run folder (default: data/agents/*)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--p-t-db", type=float, default=5.0, help="SINR target P_T [dB] in both cities (the report's: 5)")
    ap.add_argument("--n-boot", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", default="data/processed")
    ap.add_argument("--csv", type=Path, help="Write the table to this CSV file")
    ap.add_argument("--labels", default=f"{PATHS},{RADIO}", help="What the two cities are, for the table: FIRST,SECOND "
                    "(e.g. '4-neighbour walk,euclidean walk' for two fills of one trace)")  # fmt: skip
    args = ap.parse_args()
    first, second = args.labels.split(",")
    if args.summary:
        summary(args.summary, first, second)
        return
    if not (args.paths and args.radio_map):
        ap.error("--paths and --radio-map are required (or --summary)")
    development_cities([args.paths, args.radio_map], args.root)  # never a test city
    paths, radio = load_bundle(args.paths, root=args.root), load_bundle(args.radio_map, root=args.root)
    if paths.shape != radio.shape or not np.allclose(paths.users[["x_m", "y_m"]], radio.users[["x_m", "y_m"]]):
        raise SystemExit(f"{args.paths} and {args.radio_map} are not twins: other grids or other users")
    config = ReportConfig(dataset=args.paths, episodes=args.episodes, t_max=500, p_t_db=args.p_t_db, seed=args.seed,
                          trajectories=0)  # fmt: skip
    episodes, dropped = same_episodes(paths, radio, config)
    folders = args.agent or default_agents()
    results: dict[str, pd.DataFrame] = {}
    for label, bundle in ((first, paths), (second, radio)):
        agents = [load_agent(f, 0.096, args.seed) for f in folders]
        for name, df in evaluate(config, bundle, agents, baselines=[GeniePolicy()], episodes=episodes).items():
            results[f"{name} @ {label}"] = df
    table = bootstrap_table(results, n_boot=args.n_boot, seed=args.seed).set_index("method")
    methods = [k.removesuffix(f" @ {first}") for k in results if k.endswith(f" @ {first}")]
    diffs = difference_table(results, [f"{m} @ {second}" for m in methods], n_boot=args.n_boot, seed=args.seed)
    rows, out = [], []
    for m in methods:
        p, r = table.loc[f"{m} @ {first}"], table.loc[f"{m} @ {second}"]
        d = diffs[(diffs.method == f"{m} @ {first}") & (diffs.against == f"{m} @ {second}")].set_index("stat")
        cell = {}
        for stat, unit in (("success", "points"), ("median_steps", "steps")):
            row = d.loc[stat]
            cell[stat] = difference_cell(row.difference, row.lo, row.hi, 100 if stat == "success" else 1, f" {unit}")
        rows.append([m, stat_cell(p, "success"), stat_cell(r, "success"), cell["success"],
                     stat_cell(p, "median_steps"), stat_cell(r, "median_steps"), cell["median_steps"]])  # fmt: skip
        out.append({"method": m, **{f"{k}_{lab}": t[k] for lab, t in (("paths", p), ("radio", r))
                                    for k in ("success", "success_lo", "success_hi", "median_steps", "median_steps_lo", "median_steps_hi")},
                    **{f"{s}_difference{suffix}": d.loc[s][col] for s in ("success", "median_steps")
                       for suffix, col in (("", "difference"), ("_lo", "lo"), ("_hi", "hi"))}})  # fmt: skip
    users = int(table.iloc[0]["users"])
    shares = {
        label: float((b.sinr_db >= args.p_t_db)[~b.dead & ~b.blocked[None]].mean())
        for label, b in ((first, paths), (second, radio))
    }
    print(f"{args.paths} ({first}) against {args.radio_map} ({second}) at P_T {args.p_t_db:g} dB (targets: "
          f"{100 * shares[first]:.1f} % and {100 * shares[second]:.1f} % of the live open cells): {len(episodes)} episodes of "
          f"{users} users, the same in both ({dropped} draws dropped: no start in the twin); 95 % intervals over users, "
          "then episodes\n")  # fmt: skip
    header = ["method", f"success, {first}", f"success, {second}", "first - second",
              f"median steps, {first}", f"median steps, {second}", "first - second"]  # fmt: skip
    print(markdown_table([header, *rows]))
    agree = map_agreement(paths, radio)
    print(f"\nmaps over the open cells of every user: dead/live agreement {100 * agree['agreement']:.1f} % (live: {first} "
          f"{100 * agree['live_exact']:.1f} %, {second} {100 * agree['live_radio']:.1f} %); where both are live, the second's "
          f"|SINR error| median {agree['median_abs_db']:.2f} dB, p90 {agree['p90_abs_db']:.2f} dB")  # fmt: skip
    if args.csv is not None:
        pd.DataFrame(out).assign(**{k: v for k, v in agree.items()}).to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()

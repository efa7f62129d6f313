"""Does the height map help? The paper's claim (map beats blind), tested on one preset's seeds, and swapped maps.

Plays the same episodes of each city (``eval.evaluate.evaluate``: t_max 500, test epsilon 0.096, the episodes
``uavrl report --seed`` draws) with:

- the map agents (``--map RUN``, repeatable: the seeds of a preset) seeing their city's buildings;
- the blind agents (``--blind RUN``: the same preset with ``--agent blind``, its seeds);
- the map agents seeing no building at all (``MapSet.show_buildings(None)``), and seeing the buildings of
  another city of the same grid shape (``--donor CITY=DONOR``; by default the first built city of that shape by
  name that is neither a test city nor the city itself). Moves, SINR and the genie stay the city's: only what
  the agent sees changes, so success that holds means the agent does not use the map.

Prints, per city and for all cities pooled, each condition's success and median steps (the mean over its
seeds, an interval that resamples seeds, then users, then episodes, and the seeds' range), then the paired
differences against the map agents seeing their own city (``eval.metrics.group_tables``). Validation cities
by default; test cities only with ``--release``. ``--csv`` writes both tables.

    python experiments/map_claim.py --map runs/agents-v6/best-s{0,1,2} --blind runs/agents-v6/best-blind-s{0,1,2}
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from uavplace.dataset.bundle import load_bundle, read_manifest, resolve
from uavplace.dataset.catalog import list_cities
from uavplace.eval.cities import development_cities
from uavplace.eval.evaluate import ReportConfig, evaluate, load_agent
from uavplace.eval.metrics import group_tables
from uavplace.eval.render import group_rows
from uavplace.infra.console import markdown_table
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.schemas import InputError

#: The conditions, in the table's order; the first is the reference of the differences.
CONDITIONS = ("map", "blind", "no buildings", "swapped map")


def donor_for(city: str, root: str, given: dict[str, str]) -> str | None:
    """The city whose buildings the map agents see in the swapped-map condition (same grid shape, not a test city),
    found from the latest bundles' manifests (no map is read)."""
    if city in given:
        return given[city]
    shape = load_bundle(city, root=root).shape
    for entry in list_cities(root):
        try:
            manifest = read_manifest(resolve(entry.name, root=root))
        except InputError:  # an unbuilt or damaged city is simply not a donor
            continue
        if entry.name != city and manifest.grid.shape == shape and manifest.config.role != "test":
            return entry.name
    return None


def play(city: str, args: argparse.Namespace, donor: str | None) -> dict[str, pd.DataFrame]:
    """Every condition's episodes in ``city``: ``{"<condition>/<run>": frame}`` (the genie under ``genie``)."""
    bundle = load_bundle(city, root=args.root)
    config = ReportConfig(dataset=city, episodes=args.episodes, t_max=500, seed=args.seed, trajectories=0)

    def agents(folders: list[Path], condition: str) -> list:
        out = [load_agent(f, 0.096, args.seed) for f in folders]
        for a in out:
            a.name = a.policy.name = f"{condition}/{a.folder.name}"
        return out

    results = evaluate(config, bundle, agents(args.map, "map") + agents(args.blind, "blind"), baselines=[GeniePolicy()])
    results["genie"] = results.pop(GeniePolicy.name)
    results |= evaluate(config, bundle, agents(args.map, "no buildings"), baselines=[], seen=lambda m: m.show_buildings(None))
    if donor is not None:
        other = load_bundle(donor, root=args.root)
        results |= evaluate(config, bundle, agents(args.map, "swapped map"), baselines=[],
                            seen=lambda m: m.show_buildings(other))  # fmt: skip
    return results


def tables(results: dict[str, pd.DataFrame], args: argparse.Namespace) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    groups = {c: [k for k in results if k.startswith(f"{c}/")] for c in CONDITIONS}
    groups = {c: runs for c, runs in groups.items() if runs} | {"genie": ["genie"]}
    return *group_tables(results, groups, against=["map"], n_boot=args.n_boot, seed=args.seed), groups


def show(where: str, table: pd.DataFrame, diffs: pd.DataFrame, groups: dict[str, list[str]]) -> None:
    print(f"\n{where}: mean over seeds [95 % interval over seeds, users, episodes] (seeds' range); differences paired "
          "in users and episodes\n")  # fmt: skip
    print(markdown_table(group_rows(table, diffs, groups, references_too=True)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--map", type=Path, action="append", required=True, help="A map agent's run (repeatable: its seeds)")
    ap.add_argument("--blind", type=Path, action="append", default=[], help="A blind agent's run (repeatable)")
    ap.add_argument("--city", action="append", default=None, help="City to play (repeatable; default: the validation cities)")
    ap.add_argument("--release", action="store_true", help="Allow test cities (release numbers only, never to choose)")
    ap.add_argument("--donor", action="append", default=[], metavar="CITY=DONOR", help="The swapped map's city for CITY")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--n-boot", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", default="data/processed")
    ap.add_argument("--csv", type=Path, help="Write the tables to CSV_table.csv and CSV_differences.csv")
    args = ap.parse_args()
    cities = development_cities(args.city, args.root, release=args.release)
    given = dict(d.split("=", 1) for d in args.donor)
    pooled: dict[str, list[pd.DataFrame]] = {}
    out_tables, out_diffs = [], []
    for city in cities:
        donor = donor_for(city, args.root, given)
        results = play(city, args, donor)
        for name, df in results.items():
            pooled.setdefault(name, []).append(df)
        table, diffs, groups = tables(results, args)
        show(f"{city} (swapped map: {donor or 'none of its shape'})", table, diffs, groups)
        out_tables.append(table.assign(city=city, donor=donor))
        out_diffs.append(diffs.assign(city=city, donor=donor))
    if len(cities) > 1:
        common = {k: v for k, v in pooled.items() if len(v) == len(cities)}  # swapped maps only where every city has one
        table, diffs, groups = tables({k: pd.concat(v, ignore_index=True) for k, v in common.items()}, args)
        show(f"all {len(cities)} cities pooled ({', '.join(cities)})", table, diffs, groups)
        out_tables.append(table.assign(city="pooled"))
        out_diffs.append(diffs.assign(city="pooled"))
    if args.csv is not None:
        pd.concat(out_tables).to_csv(f"{args.csv}_table.csv", index=False)
        pd.concat(out_diffs).to_csv(f"{args.csv}_differences.csv", index=False)


if __name__ == "__main__":
    main()

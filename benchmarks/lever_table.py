"""The lever table: each training run's validation score and its success in unseen cities.

For every run folder: the settings that differ from the ``best`` preset, the evaluation that chose
``best.pt`` (on the validation cities), then ``best.pt`` on ``--episodes`` episodes of each test
city (t_max 500, epsilon 0.096, the episodes ``uavrl report --seed`` draws; ``eval.report.evaluate``
with the genie as the only baseline): success, median steps
and their ratio to the genie's median on the same episodes, and the wall time: the run's own
(``wall_s`` of its last evaluation, over its starts and resumes), or for a run trained before the
trainer kept time, what the lever script logged (``wall.txt`` beside the runs; a resumed run's
parts added up, a part that was killed is not there). Test cities are only reported here, never used to choose.
Each agent is loaded once; its random moves are drawn per episode (``rl/randomness.py``), so every city plays
as ``uavrl report`` plays it, whatever was played before.

    python benchmarks/lever_table.py runs/levers/R* [--city test --city etoile] [--episodes 1000]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.cities import development_cities
from uavplace.eval.report import ReportConfig, evaluate, load_agent
from uavplace.rl.agent.dqn import preset_config
from uavplace.rl.policies import GeniePolicy
from uavplace.rl.rollout import summarise


def changed_settings(config) -> str:
    """The fields of ``config`` (and its env) that differ from its preset, as ``--set`` would write them."""
    base = preset_config(config.preset, agent=config.agent, seed=config.seed).model_dump()
    mine = config.model_dump()
    out = [f"{k}={v}" for k, v in mine.items() if k not in ("env", "total_steps", "eval_every", "seed") and v != base[k]]
    out += [f"env.{k}={v}" for k, v in mine["env"].items() if v != base["env"][k]]
    return ", ".join(out) or "(preset)"


def wall_times(folders: list[Path]) -> dict[str, str]:
    """Each run's wall time from its OUT/wall.txt: the sum of its lines, one per start or resume (``one_run.sh``)."""
    seconds: dict[str, int] = {}
    for log in {f.parent / "wall.txt" for f in folders}:
        if log.is_file():
            for line in log.read_text().splitlines():
                name, _, text = line.partition(": ")
                seconds[name] = seconds.get(name, 0) + int(text.removesuffix(" s"))
    return {name: f"{s} s" for name, s in seconds.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--city", action="append", default=None, help="City to play (repeatable; default: every validation city)")
    ap.add_argument("--release", action="store_true", help="Allow test cities (release numbers only, never to choose)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    cities = development_cities(args.city, args.root, release=args.release)
    walls = wall_times(args.runs)
    agents = [load_agent(folder, 0.096, args.seed) for folder in args.runs]
    for a in agents:  # the runs' folder names tell agents of one preset apart
        a.name = a.policy.name = a.folder.name
    tests: dict[str, dict[str, dict[str, float]]] = {}
    for city in cities:
        config = ReportConfig(dataset=city, episodes=args.episodes, t_max=500, seed=args.seed, trajectories=0)
        results = evaluate(config, load_bundle(city, root=args.root), agents, baselines=[GeniePolicy()])
        tests[city] = {name: summarise(df) for name, df in results.items()}
    head = ["run", "settings", "steps", "val success", "val median"]
    head += [f"{c} {x}" for c in cities for x in ("success", "median", "x genie")] + ["wall"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for a in agents:
        evals = pd.read_parquet(a.folder / "eval.parquet")
        chosen = evals[evals["best"]].iloc[-1]
        last = evals.step.max()  # an ensemble's one evaluation has no step: its members' schedule, times their number
        steps = f"{int(last):,}" if pd.notna(last) else f"{a.config.ensemble} x {a.config.total_steps:,}"
        row = [a.name, changed_settings(a.config), steps]
        row += [f"{100 * chosen.success:.1f} %", f"{chosen.median_steps:g}"]
        for summaries in tests.values():
            s, genie = summaries[a.name], summaries[GeniePolicy.name]["median_steps"]
            row += [f"{100 * s['success']:.1f} %", f"{s['median_steps']:g}", f"{s['median_steps'] / genie:.2f}"]
        own = evals["wall_s"].iloc[-1] if "wall_s" in evals else float("nan")
        row.append(f"{own:.0f} s" if pd.notna(own) else walls.get(a.name, "-"))
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()

"""The report's slow methods played by this tree and by an earlier commit, in turn, in one run: times, ratios, and
whether every episode came out the same.

A change made for speed must not move a number (issue 63). For each city and method this plays the report's
episodes with the code of ``--base`` (a git worktree of that commit, made under ``runs/versus/``) and with the
code of this tree, one child process each, alternating for ``--rounds`` rounds; each child warms up on a few
episodes first (the predicted maps read or made before its clock starts). It prints each version's best time, the
ratio and whether the two versions' episodes are equal (``DataFrame.equals`` of every column, the paths too).

    python benchmarks/versus.py --base e1c6e54 [--city etoile-val --city florence-val] [--method searcher ...]
        [--episodes 300] [--rounds 2]

Methods: ``searcher`` and ``hybrid`` (``data/agents/hybrid``), each also ``-blank`` (shown no building, the
report's ablation). Validation cities by default; run it with the bundles built and nothing else running.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
#: The package's subfolders (pyproject.toml's package-dir): a worktree of another commit imported as ``uavplace``.
SUBPACKAGES = ("schemas", "infra", "cli", "ingest", "simulate", "dataset", "rl", "eval")
METHODS = ("searcher", "searcher-blank", "hybrid", "hybrid-blank")


def play(city: str, method: str, episodes: int, out: Path) -> None:
    """One child: ``method`` on ``city``'s report episodes with whatever ``uavplace`` imports; prints its seconds.
    It runs with an earlier commit's code too, so it reads only what those have (not ``evaluate.agent_env``)."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.eval.evaluate import NO_BUILDINGS, ReportConfig, baseline_policies, load_agent, report_env
    from uavplace.rl.tasks.placement import rollout
    from uavplace.rl.tasks.placement.searcher import SEARCHER
    from uavplace.rl.world.maps import MapSet

    bundle = load_bundle(city, root=str(REPO / "data" / "processed"))
    config = ReportConfig(dataset=city, episodes=episodes)
    env = report_env(config)
    chosen = MapSet([bundle], env).episode_list(config.episodes, config.seed)
    if method.startswith("searcher"):
        policies = {p.name: p for p in baseline_policies(config, env, REPO / "data" / "processed" / ".predictions")}
        policy = policies[SEARCHER if method == "searcher" else SEARCHER + NO_BUILDINGS]
    else:
        agent = load_agent(str(REPO / "data" / "agents" / "hybrid"), config.test_epsilon, config.seed)
        policy = agent.policy
        env = agent.config.env_config(evaluation=True).model_copy(update={"t_max": config.t_max, "p_t_db": config.p_t_db})
    maps = MapSet([bundle], env)
    if method.endswith("-blank"):
        maps.show_buildings(None)
    rollout.run_episodes(maps, policy, chosen[:4])
    t0 = time.perf_counter()
    df = rollout.run_episodes(maps, policy, chosen, record=np.arange(len(chosen)))
    seconds = time.perf_counter() - t0
    df.assign(path=[np.asarray(p).tobytes() for p in df.attrs.pop("paths")]).to_parquet(out)
    print(json.dumps({"seconds": seconds}))


def shim(base: str) -> Path:
    """A folder whose ``uavplace`` package is the code of commit ``base`` (a worktree under runs/versus/)."""
    sha = subprocess.run(["git", "rev-parse", base], cwd=REPO, capture_output=True, text=True, check=True).stdout.strip()
    tree = REPO / "runs" / "versus" / sha[:12]
    if not tree.exists():
        subprocess.run(["git", "worktree", "add", "--detach", str(tree), sha], cwd=REPO, check=True, capture_output=True)
    package = tree.parent / f"{sha[:12]}-shim" / "uavplace"
    package.mkdir(parents=True, exist_ok=True)
    (package / "__init__.py").touch()
    for name in SUBPACKAGES:
        link = package / name
        if not link.is_symlink():
            link.symlink_to(tree / name)
    return package.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="HEAD~1", help="the earlier commit (default: HEAD~1)")
    ap.add_argument("--city", action="append", default=None, help="city (repeatable; default: etoile-val, florence-val)")
    ap.add_argument("--method", action="append", choices=METHODS, default=None, help="method (repeatable; default: all)")
    ap.add_argument("--episodes", type=int, default=300, help="the report's first episodes of each city")
    ap.add_argument("--rounds", type=int, default=2, help="times each version plays each method, in turn")
    ap.add_argument("--child", nargs=4, metavar=("CITY", "METHOD", "EPISODES", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        city, method, episodes, out = args.child
        play(city, method, int(episodes), Path(out))
        return
    versions = {args.base: str(shim(args.base)), "this tree": ""}
    print(f"| city | method | {args.base}: s | this tree: s | ratio | episodes the same |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for city in args.city or ["etoile-val", "florence-val"]:
            for method in args.method or METHODS:
                best = {v: float("inf") for v in versions}
                for k in range(args.rounds):
                    for version, path in versions.items():
                        out = Path(tmp) / f"{len(path) > 0}-{k}.parquet"
                        env = os.environ | {"PYTHONPATH": path} if path else os.environ
                        child = [sys.executable, __file__, "--child", city, method, str(args.episodes), str(out)]
                        done = subprocess.run(child, env=env, capture_output=True, text=True, check=False)
                        if done.returncode:
                            sys.exit(f"{version}, {city}, {method}: exit {done.returncode}\n{done.stderr[-2000:]}")
                        best[version] = min(best[version], json.loads(done.stdout.strip().splitlines()[-1])["seconds"])
                frames = [pd.read_parquet(Path(tmp) / f"{flag}-0.parquet") for flag in (True, False)]
                same = "yes" if frames[0].equals(frames[1]) else "NO"
                before, after = best[args.base], best["this tree"]
                print(f"| {city} | {method} | {before:.1f} | {after:.1f} | {before / after:.2f} x | {same} |", flush=True)


if __name__ == "__main__":
    main()

"""Time of the hybrid's rollouts: its belief channel as painted now against the whole canvases, in the same run.

The hybrid (``data/agents/hybrid``: ``best`` reading the map searcher's belief, ``EnvConfig.belief_channel``) is the
main job's slowest method (docs/benchmarks.md, "The main job, part by part"). Its channel is painted only in the
window the next observation reads, and only for the rows still playing (``rl.belief.BeliefTracker``). For each city,
with its buildings shown and blanked (the report's ablation), this plays the report's episodes twice, one after the
other in this process: with the channel painted as before (every row's whole canvas at every step, the played-out
rows of the queue too), then as it is now; it prints both times, the speed-up and whether every episode came out the
same (steps, success, return: the numbers must not move).

    python benchmarks/bench_belief.py [--city etoile-val --city florence-val] [--episodes 300]

Run it with the bundles built (README, first command) on a machine with nothing else running.
"""

from __future__ import annotations

import argparse
import time
from unittest import mock

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import ReportConfig, agent_env, load_agent, report_env
from uavplace.rl.tasks.placement import rollout
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.world.maps import MapSet


class WholeCanvases(BatchedEnv):
    """The belief channel as it was painted before: every row's whole canvas after every measurement, the rows whose
    queue is played out included."""

    def __init__(self, *args, **kwargs) -> None:  # noqa: ANN002, ANN003 - BatchedEnv's
        super().__init__(*args, **kwargs)
        tracker = self.belief
        tracker.window = None
        start, measure = tracker.start, tracker.measure
        tracker.start = lambda rows, canvases, y, x, first, unread=None: start(rows, canvases, y, x, first)
        tracker.measure = lambda rows, y, x, values, unread=None: measure(rows, y, x, values)


def play(maps: MapSet, agent, episodes: np.ndarray, env: type[BatchedEnv]) -> tuple[float, object]:  # noqa: ANN001
    with mock.patch.object(rollout, "BatchedEnv", env):
        t0 = time.perf_counter()
        df = rollout.run_episodes(maps, agent.policy, episodes)
        return time.perf_counter() - t0, df


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", default=None, help="City (repeatable; default: etoile-val, florence-val)")
    ap.add_argument("--episodes", type=int, default=300)
    ap.add_argument("--agent", default="data/agents/hybrid", help="An agent whose env has the belief channel")
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    print("| city | buildings | whole canvases s | windows s | speed-up | episodes the same |")
    print("|---|---|---|---|---|---|")
    for city in args.city or ["etoile-val", "florence-val"]:
        bundle = load_bundle(city, root=args.root)
        config = ReportConfig(dataset=city, episodes=args.episodes, predictor=None)
        episodes = MapSet([bundle], report_env(config)).episode_list(config.episodes, config.seed)
        for shown in (True, False):
            agent = load_agent(args.agent, config.test_epsilon, config.seed)
            env = agent_env(config, agent)
            if not env.belief_channel:
                ap.error(f"{args.agent} has no belief channel")
            maps = MapSet([bundle], env)
            if not shown:
                maps.show_buildings(None)
            play(maps, agent, episodes[:8], BatchedEnv)  # the predicted maps made or read before the clocks start
            before, old = play(maps, agent, episodes, WholeCanvases)
            after, new = play(maps, agent, episodes, BatchedEnv)
            same = old[["steps", "success", "return_"]].equals(new[["steps", "success", "return_"]])
            print(f"| {city} | {'shown' if shown else 'blanked'} | {before:.1f} | {after:.1f} | {before / after:.2f} x | "
                  f"{'yes' if same else 'NO'} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()

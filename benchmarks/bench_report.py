"""Time of the main job's evaluation: each method's rollouts as a ratio to the genie's on the same episodes.

For each test city (default: the main job's test, etoile and florence) it draws the report's episodes
once (``uavrl report``'s seed) and plays them with every shipped agent and baseline through
``eval.evaluate.evaluate``, one method at a time, timing each. It prints seconds per method and their
ratio to the genie's rollout (the cheapest possible player of the same episodes: a table lookup per
move), then the totals. ``--legacy`` also times each agent the way reports acted before this
benchmark (every slot of a 256-episode batch through the network, batch norm unfolded), in the same
run, for the speed-up.

    python benchmarks/bench_report.py [--city test --city etoile --city florence] [--episodes 1000] [--legacy]

Run it after the main job's ingest and build (README, first command). The main job's wall time is
measured separately (README: `time` around its three commands).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import ReportConfig, baseline_policies, default_agents, evaluate, load_agent
from uavplace.infra.tensors import load_tensors
from uavplace.rl.agent.dqn import DQNPolicy, make_network, masked_argmax, to_tensor
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.policies import random_legal
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.world.maps import MapSet


class LegacyPolicy(DQNPolicy):
    """How agents acted before: every slot through the unfolded network, under ``no_grad``."""

    def __init__(self, policy: DQNPolicy, net: torch.nn.Module) -> None:
        super().__init__(net, policy.epsilon, 0, policy.name)
        self.net = net.eval()

    def act(self, obs, mask, env):  # noqa: ANN001, ANN201 - DQNPolicy.act
        with torch.no_grad():
            q = self.net(to_tensor(obs, self.device))
            greedy = masked_argmax(q, torch.from_numpy(mask).to(self.device)).cpu().numpy()
        return np.where(self.rng.random(len(mask)) < self.epsilon, random_legal(mask, self.rng), greedy)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", action="append", default=None, help="Test city (repeatable; default: test, etoile, florence)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--root", default="data/processed")
    ap.add_argument("--legacy", action="store_true", help="Also time the agents as they acted before (256 slots, unfolded)")
    args = ap.parse_args()
    cities = args.city or ["test", "etoile", "florence"]
    totals: dict[str, float] = {}
    print(f"| city | method | seconds | / genie |{' legacy seconds | speed-up |' if args.legacy else ''}")
    print(f"|---|---|---|---|{'---|---|' if args.legacy else ''}")
    for city in cities:
        bundle = load_bundle(city, root=args.root)
        config = ReportConfig(dataset=city, episodes=args.episodes, trajectories=0)
        agents = [load_agent(folder, config.test_epsilon, config.seed) for folder in default_agents()]
        base = EnvConfig(t_max=config.t_max, p_t_db=config.p_t_db, rotate=False)
        times: dict[str, float] = {}
        for policy in baseline_policies(config, base):
            t0 = time.perf_counter()
            evaluate(config, bundle, [], baselines=[policy])
            times[policy.name] = time.perf_counter() - t0
        legacy: dict[str, float] = {}
        for agent in agents:
            t0 = time.perf_counter()
            evaluate(config, bundle, [agent], baselines=[])
            times[agent.name] = time.perf_counter() - t0
            if args.legacy:
                env = agent.config.env_config(evaluation=True).model_copy(update={"t_max": config.t_max, "split": None})
                maps = MapSet([bundle], env)
                episodes = MapSet([bundle], base).episode_list(config.episodes, config.seed)
                net = make_network(agent.config, env.num_channels, env.window)
                net.load_state_dict(load_tensors(agent.folder / "checkpoints" / "best.pt")["online"])
                t0 = time.perf_counter()
                run_episodes(maps, LegacyPolicy(agent.policy, net), episodes, num_envs=256)
                legacy[agent.name] = time.perf_counter() - t0
        genie = times["genie"]
        for name, seconds in times.items():
            totals[name] = totals.get(name, 0.0) + seconds
            extra = (
                f" {legacy[name]:.1f} | {legacy[name] / seconds:.2f} x |" if name in legacy else (" | |" if args.legacy else "")
            )
            print(f"| {city} | {name} | {seconds:.1f} | {seconds / genie:.1f} x |{extra}")
    print(f"\nall cities: {sum(totals.values()):.1f} s of rollouts; " + ", ".join(f"{k} {v:.1f} s" for k, v in totals.items()))


if __name__ == "__main__":
    main()

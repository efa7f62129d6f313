"""Several seeds of one recurrent preset acting as one agent (the mean of their Q values), against each seed alone.

Every seed keeps its own GRU state; the ensemble's greedy move maximises the mean of the seeds' Q values minus the
test rule's revisit penalty (the first run's), with the report's epsilon 0.096. Each city is played by
``eval.report.evaluate`` on the episodes ``uavrl report --seed`` draws (1000 by default), the genie beside. Measure it
on validation cities only: it is a candidate lever, not a way to look at test cities.

    python benchmarks/ensemble.py runs/levers-v5/GRU-R32-s0 runs/levers-v5/GRU-R32-s1 runs/levers-v5/GRU-R32-s2 \\
        --city corpus-016 --city corpus-017 --city oldtown-005
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from torch import nn

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.report import Agent, ReportConfig, evaluate, load_agent
from uavplace.rl.agent.dqn import DQNPolicy
from uavplace.rl.policies import GeniePolicy
from uavplace.rl.rollout import summarise


class MeanQ(nn.Module):
    """Recurrent networks side by side: the state is theirs concatenated, the Q values their mean."""

    recurrent = True

    def __init__(self, nets: list[nn.Module]) -> None:
        super().__init__()
        if not all(getattr(n, "recurrent", False) for n in nets):
            raise ValueError("every member must be a recurrent network (trained with recurrent=true)")
        self.nets = nn.ModuleList(nets)
        self.width = nets[0].core.hidden_size

    def initial_state(self, n: int) -> torch.Tensor:
        return torch.zeros(n, self.width * len(self.nets), device=next(self.parameters()).device)

    def encode(self, obs: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        return torch.cat([net.encode(obs, part) for net, part in zip(self.nets, h.split(self.width, dim=1), strict=True)], 1)

    def head(self, z: torch.Tensor) -> torch.Tensor:
        return torch.stack([net.head(part) for net, part in zip(self.nets, z.split(self.width, dim=1), strict=True)]).mean(0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="Run folders of one preset (their checkpoints/best.pt)")
    ap.add_argument("--city", action="append", required=True, help="Validation city (repeatable)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    agents = [load_agent(folder, 0.096, args.seed) for folder in args.runs]
    for a in agents:
        a.name = a.policy.name = a.folder.name
    first = agents[0]
    policy = DQNPolicy(MeanQ([a.policy.net for a in agents]), 0.096, args.seed, "ensemble", first.config.test_revisit_penalty)
    ensemble = Agent("ensemble", first.folder, first.config, first.run, policy, None, None)
    print("| city | " + " | ".join(["ensemble", *(a.name for a in agents), "genie"]) + " |")
    print("|" + "---|" * (len(agents) + 3))
    for city in args.city:
        config = ReportConfig(dataset=city, episodes=args.episodes, t_max=500, seed=args.seed, trajectories=0)
        results = evaluate(config, load_bundle(city, root=args.root), [ensemble, *agents], baselines=[GeniePolicy()])
        cells = [f"{100 * s['success']:.1f} % / {s['median_steps']:g}" for s in map(summarise, results.values())]
        print(f"| {city} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()

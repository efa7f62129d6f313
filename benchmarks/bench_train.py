"""Training speed: our trainer against Tianshou's DQN on the same problem, network and learning per step.

Both train a double DQN with a dueling head and legal-move masking (in the greedy move and in the
double-Q target), n-step returns, the same Q-network and the same replay ratio (``batch_size``
samples every ``train_every`` env steps), on the embedded train city:

* ours: ``rl.agent.train.Trainer`` over the batched environment (one array step for all envs,
  uint8 replay);
* Tianshou 2.x: ``DQN`` + ``Collector`` over a ``DummyVectorEnv`` of our Gymnasium env
  (``uavplace/UavPlacement-v0``), the legal moves passed as ``obs.mask``.

It prints env steps/s and gradient updates/s of each, measured in the same run after the same
warm-up, and the ratio. ``--memory`` instead fills a paper-preset replay buffer (5e5 transitions)
and reports the run's peak RSS.

    pip install -e '.[bench]'      # adds tianshou
    uavdata ingest data/raw/train/ && uavdata build --grid 4m --alt 10 --noise-dbm -68 --split train=train
    python benchmarks/bench_train.py [--steps 20000] [--preset best]
    python benchmarks/bench_train.py --memory
    python benchmarks/bench_train.py --corpus corpus      # the train city alone against the corpus and it
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from uavplace.dataset.catalog import expand_datasets
from uavplace.rl.agent.dqn import DQNConfig, make_network, preset_config
from uavplace.rl.agent.train import Trainer
from uavplace.rl.config import EnvConfig


def bench_ours(config: DQNConfig, dataset: str | list[str], root: str, steps: int, warmup: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(config, [dataset] if isinstance(dataset, str) else dataset, root, Path(tmp) / "run")
        marks: dict[str, float] = {}

        def on_progress(p) -> None:
            if "t0" not in marks and p.step >= warmup:
                marks["t0"], marks["s0"], marks["u0"] = time.perf_counter(), p.step, trainer.agent.updates

        trainer.run(on_progress=on_progress, stop_at=steps)
        dt = time.perf_counter() - marks["t0"]
        return {
            "env_steps_per_s": (trainer.state.step - marks["s0"]) / dt,
            "updates_per_s": (trainer.agent.updates - marks["u0"]) / dt,
            "updates": trainer.agent.updates,
        }


def bench_tianshou(config: DQNConfig, dataset: str, root: str, steps: int, warmup: int) -> dict:
    import gymnasium as gym
    from tianshou.algorithm import DQN
    from tianshou.algorithm.modelfree.dqn import DiscreteQLearningPolicy
    from tianshou.algorithm.optim import AdamOptimizerFactory
    from tianshou.data import Collector, VectorReplayBuffer
    from tianshou.env import DummyVectorEnv
    from tianshou.utils.torch_utils import policy_within_training_step

    import uavplace.rl  # noqa: F401  (registers the environments)

    env_cfg = config.env_config()

    class MaskedObs(gym.ObservationWrapper):
        """Our env with the legal moves in the observation, where Tianshou looks for them (``obs.mask``)."""

        def __init__(self, env: gym.Env) -> None:
            super().__init__(env)
            self.observation_space = gym.spaces.Dict({"obs": env.observation_space, "mask": gym.spaces.MultiBinary(4)})

        def observation(self, obs: np.ndarray) -> dict:
            return {"obs": obs, "mask": self.env.unwrapped.action_mask().astype(bool)}

    class Net(torch.nn.Module):
        """The same Q-network, with Tianshou's model signature."""

        def __init__(self) -> None:
            super().__init__()
            self.net = make_network(config, env_cfg.num_channels, env_cfg.window)

        def forward(self, obs, state=None, info=None):
            return self.net(torch.as_tensor(obs, dtype=torch.float32)), state

    def make_env() -> gym.Env:
        return MaskedObs(gym.make("uavplace/UavPlacement-v0", dataset=dataset, root=root, config=env_cfg))

    n = config.num_envs
    envs = DummyVectorEnv([make_env for _ in range(n)])
    envs.seed(config.seed)
    probe = make_env()
    policy = DiscreteQLearningPolicy(model=Net(), action_space=probe.action_space, observation_space=probe.observation_space)
    algo = DQN(
        policy=policy,
        optim=AdamOptimizerFactory(lr=config.lr_start),
        gamma=config.gamma,
        n_step_return_horizon=config.n_step,
        target_update_freq=max(1, config.target_update // config.train_every),
        is_double=True,
        huber_loss_delta=1.0,
    )
    buffer = VectorReplayBuffer(config.buffer_size, n)
    collector = Collector(algo, envs, buffer, exploration_noise=True)
    collector.reset()
    policy.set_eps_training(0.1)
    updates_per_collect = max(1, n // config.train_every)
    done = updates = 0
    t0 = s0 = u0 = None
    with policy_within_training_step(policy):
        while done < steps:
            collector.collect(n_step=n)
            done += n
            if done >= config.learning_starts:
                for _ in range(updates_per_collect):
                    algo.update(buffer, config.batch_size)
                    updates += 1
            if t0 is None and done >= warmup:
                t0, s0, u0 = time.perf_counter(), done, updates
    dt = time.perf_counter() - t0
    return {"env_steps_per_s": (done - s0) / dt, "updates_per_s": (updates - u0) / dt, "updates": updates}


def bench_memory(dataset: str, root: str, extra_steps: int) -> None:
    """A paper-preset run whose replay fills up (5e5 transitions), then ``extra_steps`` with updates."""
    base = preset_config("paper")
    cfg = base.model_copy(
        update={
            "num_envs": 256,
            "learning_starts": base.buffer_size,
            "total_steps": base.buffer_size + extra_steps,
            "eval_every": base.buffer_size + extra_steps,
            "eval_episodes": 50,
        }
    )
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(cfg, [dataset], root, Path(tmp) / "run")
        trainer.run()
        filled = trainer.replay.size
        nbytes = sum(getattr(trainer.replay, k).nbytes for k in trainer.replay._ARRAYS)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB -> GiB
    print(f"paper preset, replay {filled:,}/{cfg.buffer_size:,} transitions ({nbytes / 2**30:.2f} GiB of arrays), "
          f"{cfg.total_steps:,} steps in {time.perf_counter() - t0:.0f} s")  # fmt: skip
    print(f"peak RSS {peak:.2f} GiB (target <= 6 GiB): {'OK' if peak <= 6 else 'OVER'}")


def bench_corpus(args: argparse.Namespace) -> None:
    """Our trainer (the preset, its levers on) on one city and on the corpus plus that city, in one run:
    env steps/s and updates/s, and their ratio (many cities must not slow training down)."""
    config = preset_config(
        args.preset, total_steps=10 * args.steps, buffer_size=args.steps, learning_starts=min(2_000, args.warmup),
        eval_every=10 * args.steps, eval_episodes=50,
    )  # fmt: skip
    cities = [*expand_datasets([args.corpus], args.root), args.dataset]
    one = bench_ours(config, args.dataset, args.root, args.steps, args.warmup)
    many = bench_ours(config, cities, args.root, args.steps, args.warmup)
    for label, r in ((args.dataset, one), (f"{len(cities)} cities", many)):
        print(f"  {label:>10}: {r['env_steps_per_s']:8.0f} env steps/s  {r['updates_per_s']:6.1f} updates/s")
    ratio = many["env_steps_per_s"] / one["env_steps_per_s"]
    print(f"  ratio (corpus / one city), env steps/s: {ratio:.2f}x (target: >= 0.9)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dataset", default="train", help="built city (default: the embedded train city)")
    ap.add_argument("--root", default="data/processed")
    ap.add_argument("--preset", default="best", choices=["paper", "fast", "best"], help="network and learning rates")
    ap.add_argument("--steps", type=int, default=20_000, help="env steps per trainer (after which the clock stops)")
    ap.add_argument("--warmup", type=int, default=4_000, help="env steps before the clock starts (updates already on)")
    ap.add_argument("--memory", action="store_true", help="peak RSS of a paper-preset run with a full replay instead")
    ap.add_argument("--corpus", default=None, help="instead: ours on --dataset alone against the corpus NAME-NNN and it")
    args = ap.parse_args()
    if args.memory:
        bench_memory(args.dataset, args.root, extra_steps=3_000)
        return
    if args.corpus:
        bench_corpus(args)
        return
    # Both loops stop at --steps, before total_steps: no evaluation or checkpoint is timed.
    config = preset_config(
        args.preset,
        total_steps=10 * args.steps,
        buffer_size=args.steps,
        learning_starts=min(2_000, args.warmup),
        eval_every=10 * args.steps,
    )
    env = EnvConfig()
    print(f"preset {args.preset}: {config.num_envs} envs, batch {config.batch_size} every {config.train_every} env steps, "
          f"{config.n_step}-step returns, network {config.network}, {torch.get_num_threads()} torch threads, "
          f"window {env.window}")  # fmt: skip
    # Acting and storing only (no gradient step), then training at the preset's replay ratio.
    collect = config.model_copy(update={"learning_starts": 10 * args.steps})
    for label, cfg in (("acting + replay only", collect), ("training (same updates per env step)", config)):
        ours = bench_ours(cfg, args.dataset, args.root, args.steps, args.warmup)
        theirs = bench_tianshou(cfg, args.dataset, args.root, args.steps, args.warmup)
        print(label)
        for name, r in (("uavplace", ours), ("tianshou", theirs)):
            print(
                f"  {name:>9}: {r['env_steps_per_s']:8.0f} env steps/s  {r['updates_per_s']:6.1f} updates/s  ({r['updates']} updates)"
            )
        print(f"  ratio (ours / tianshou), env steps/s: {ours['env_steps_per_s'] / theirs['env_steps_per_s']:.2f}x")


if __name__ == "__main__":
    main()

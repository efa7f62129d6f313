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
and reports the run's peak RSS. ``--to-target`` trains both to a validation success (the
preset's schedule of epsilon and learning rate, both evaluated every ``--eval-every`` env steps
by the same function on the same episodes) and prints the wall time each took to reach it,
evaluations included.

    pip install -e '.[bench]'      # adds tianshou
    uavdata ingest data/raw/train/ && uavdata build --city train --grid 4m --alt 10 --split train=train --val-users 3
    python benchmarks/bench_train.py [--steps 20000] [--preset best-dqn]
    python benchmarks/bench_train.py --memory
    python benchmarks/bench_train.py --corpus corpus      # the train city alone against the corpus and it
    python benchmarks/bench_train.py --learners --corpus corpus   # replay DQN, PQN and PQN + GRU on the corpus
    python benchmarks/bench_train.py --paper-speed --steps 8000 --warmup 3000   # the paper network, fast against plain
    python benchmarks/bench_train.py --to-target 0.9 [--budget 300000] [--eval-every 10000]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from uavplace.dataset.bundle import load_bundle
from uavplace.dataset.catalog import expand_datasets
from uavplace.rl.agent.config import DQNConfig, preset_config
from uavplace.rl.agent.dqn import DQN, make_network
from uavplace.rl.agent.train import Trainer, linear
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.learner import validation_set
from uavplace.rl.world.cities import plan_cities


def bench_ours(config: DQNConfig, dataset: str | list[str], root: str, steps: int, warmup: int, fast: bool = True) -> dict:
    """Env steps/s and updates/s of our trainer from step ``warmup`` to ``steps`` (the clock stops at the last step's
    progress report, before the checkpoint ``stop_at`` writes); ``fast``: the trainer's (False: the plain arrangement)."""
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(config, [dataset] if isinstance(dataset, str) else dataset, root, Path(tmp) / "run", fast=fast)
        marks: dict[str, float] = {}

        def on_progress(p) -> None:
            if "t0" not in marks and p.step >= warmup:
                marks["t0"], marks["s0"], marks["u0"] = time.perf_counter(), p.step, trainer.agent.updates
            marks["t1"], marks["s1"], marks["u1"] = time.perf_counter(), p.step, trainer.agent.updates

        trainer.run(on_progress=on_progress, stop_at=steps)
        dt = marks["t1"] - marks["t0"]
        return {
            "env_steps_per_s": (marks["s1"] - marks["s0"]) / dt,
            "updates_per_s": (marks["u1"] - marks["u0"]) / dt,
            "updates": trainer.agent.updates,
        }


def bench_paper_speed(args: argparse.Namespace) -> None:
    """The paper network's training, fast (``DQN(fast=True)``, what runs train with) against the plain arrangement
    of the same computation (``fast=False``: NCHW tensors, eval-mode modules, per-parameter Adam and clipping), in one
    run: the milliseconds of one gradient step and of acting for the preset's envs, interleaved in rounds on the same
    batches of one trainer's replay, then the whole training loop's env steps/s of each (``--rounds`` each, alternating)."""
    config = preset_config(
        "paper", total_steps=10 * args.steps, buffer_size=args.steps, learning_starts=min(2_000, args.warmup),
        eval_every=10 * args.steps,
    )  # fmt: skip
    print(f"paper preset: {config.num_envs} envs, batch {config.batch_size} every {config.train_every} env steps, "
          f"{torch.get_num_threads()} torch threads; median over {args.rounds} rounds")  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(config, [args.dataset], args.root, Path(tmp) / "run")
        trainer.run(stop_at=args.warmup)
        rng = np.random.default_rng(0)
        batches = [trainer.replay.sample(config.batch_size, rng) for _ in range(20)]
        c, w = trainer.env.maps.config.num_channels, trainer.env.maps.config.window
        agents = {}
        for fast in (False, True):
            torch.manual_seed(0)
            agents[fast] = DQN(config, c, w, fast=fast)
        obs, mask = trainer.env.observe(), trainer.env.action_mask()
        last = np.full(config.num_envs, -1, np.int64)
        times: dict[tuple[str, bool], list[float]] = {}
        for _ in range(args.rounds):
            for fast, agent in agents.items():
                t0 = time.perf_counter()
                for b in batches:
                    agent.update(b, config.lr_start)
                t1 = time.perf_counter()
                for _ in range(len(batches)):
                    agent.act(obs, mask, 0.0, last, rng)
                t2 = time.perf_counter()
                times.setdefault(("update", fast), []).append(1e3 * (t1 - t0) / len(batches))
                times.setdefault(("act", fast), []).append(1e3 * (t2 - t1) / len(batches))
    for what in ("update", "act"):
        plain, fast = (float(np.median(times[(what, f)])) for f in (False, True))
        print(f"  {what:>6}: plain {plain:6.2f} ms  fast {fast:6.2f} ms  speed-up {plain / fast:.2f}x")
    loops: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(args.rounds):
        for fast in (False, True):
            loops[fast].append(bench_ours(config, args.dataset, args.root, args.steps, args.warmup, fast=fast)["env_steps_per_s"])
    plain, fast = (float(np.median(loops[f])) for f in (False, True))
    print(
        f"  training loop: plain {plain:6.1f} env steps/s  fast {fast:6.1f} env steps/s  speed-up {fast / plain:.2f}x (aim: 2x)"
    )


def tianshou_dqn(config: DQNConfig, dataset: str, root: str):  # noqa: ANN201 - (algorithm, policy, collector, our network)
    """Tianshou's double DQN over a ``DummyVectorEnv`` of our Gymnasium env, on our Q-network, with the
    preset's learning rate annealed linearly over the updates of ``config.total_steps``."""
    import gymnasium as gym
    from tianshou.algorithm import DQN
    from tianshou.algorithm.modelfree.dqn import DiscreteQLearningPolicy
    from tianshou.algorithm.optim import AdamOptimizerFactory, LRSchedulerFactory
    from tianshou.data import Collector, VectorReplayBuffer
    from tianshou.env import DummyVectorEnv

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

    class LinearLR(LRSchedulerFactory):
        """lr_start -> lr_end over the run's updates, as our trainer anneals it over its env steps."""

        def create_scheduler(self, optim: torch.optim.Optimizer) -> torch.optim.lr_scheduler.LRScheduler:
            total = max(1, (config.total_steps - config.learning_starts) // config.train_every)
            return torch.optim.lr_scheduler.LambdaLR(optim, lambda u: linear(1.0, config.lr_end / config.lr_start, u / total))

    def make_env() -> gym.Env:
        return MaskedObs(gym.make("uavplace/UavPlacement-v0", dataset=dataset, root=root, config=env_cfg))

    n = config.num_envs
    envs = DummyVectorEnv([make_env for _ in range(n)])
    envs.seed(config.seed)
    probe = make_env()
    model = Net()
    policy = DiscreteQLearningPolicy(model=model, action_space=probe.action_space, observation_space=probe.observation_space)
    algo = DQN(
        policy=policy,
        optim=AdamOptimizerFactory(lr=config.lr_start).with_lr_scheduler_factory(LinearLR()),
        gamma=config.gamma,
        n_step_return_horizon=config.n_step,
        target_update_freq=max(1, config.target_update // config.train_every),
        is_double=True,
        huber_loss_delta=1.0,
    )
    collector = Collector(algo, envs, VectorReplayBuffer(config.buffer_size, n), exploration_noise=True)
    collector.reset()
    return algo, policy, collector, model.net


def tianshou_training(config: DQNConfig, algo, policy, collector, epsilon: Callable[[int], float]):  # noqa: ANN001, ANN201
    """Tianshou's training loop at our replay ratio: collect ``num_envs`` env steps at ``epsilon(done)``, then (once
    ``learning_starts`` is past) ``num_envs // train_every`` updates; yields ``(env steps, updates)`` after each round."""
    from tianshou.utils.torch_utils import policy_within_training_step

    n = config.num_envs
    updates_per_collect = max(1, n // config.train_every)
    done = updates = 0
    with policy_within_training_step(policy):
        while True:
            policy.set_eps_training(epsilon(done))
            collector.collect(n_step=n)
            done += n
            if done >= config.learning_starts:
                for _ in range(updates_per_collect):
                    algo.update(collector.buffer, config.batch_size)
                    updates += 1
            yield done, updates


def bench_tianshou(config: DQNConfig, dataset: str, root: str, steps: int, warmup: int) -> dict:
    algo, policy, collector, _ = tianshou_dqn(config, dataset, root)
    t0 = s0 = u0 = None
    for done, updates in tianshou_training(config, algo, policy, collector, lambda _: 0.1):
        if t0 is None and done >= warmup:
            t0, s0, u0 = time.perf_counter(), done, updates
        if done >= steps:
            break
    dt = time.perf_counter() - t0
    return {"env_steps_per_s": (done - s0) / dt, "updates_per_s": (updates - u0) / dt, "updates": updates}


class _Reached(Exception):
    """Raised from the progress callback to stop our trainer once an evaluation reached the target."""


def time_to_target(args: argparse.Namespace) -> None:
    """Ours and Tianshou's DQN, the preset's schedules on ``--budget`` env steps, each evaluated every
    ``--eval-every`` steps on the same validation episodes with the same acting rule (``DQNPolicy``:
    the preset's test epsilon and revisit penalty): the wall time to the first evaluation at or above
    ``--to-target``, evaluations (and our checkpoints) included."""
    from uavplace.rl.agent.dqn import DQNPolicy
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.world.stats import summarise

    config = preset_config(
        args.preset, total_steps=args.budget, eval_every=args.eval_every, seed=args.seed, buffer_size=args.buffer
    )
    rows: dict[str, list[tuple[int, float, float]]] = {"uavplace": [], "tianshou": []}  # (step, seconds, success)
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(config, [args.dataset], args.root, Path(tmp) / "run")
        t0 = time.perf_counter()

        def on_progress(p) -> None:
            ev = trainer.state.evals
            if ev and (not rows["uavplace"] or rows["uavplace"][-1][0] != ev[-1]["step"]):
                rows["uavplace"].append((ev[-1]["step"], time.perf_counter() - t0, ev[-1]["success"]))
                print(
                    f"  uavplace  {ev[-1]['step']:>7,} steps  {rows['uavplace'][-1][1]:6.0f} s  {100 * ev[-1]['success']:.1f} %"
                )
                if ev[-1]["success"] >= args.to_target:
                    raise _Reached

        try:
            trainer.run(on_progress=on_progress)
        except _Reached:
            pass
        # the run's own validation episodes (``validation_set`` draws them from the config's seed)
        cities = plan_cities([load_bundle(args.dataset, root=args.root)], [], config.eval_split)
        eval_maps, episodes = validation_set(config, cities)
    algo, policy, collector, net = tianshou_dqn(config, args.dataset, args.root)
    span = config.eps_fraction * config.total_steps
    next_eval, t0 = config.eval_every, time.perf_counter()
    for done, _ in tianshou_training(
        config, algo, policy, collector, lambda d: linear(config.eps_start, config.eps_end, d / span)
    ):
        if done >= next_eval:
            next_eval += config.eval_every
            acting = DQNPolicy.from_config(net, config)
            success = summarise(run_episodes(eval_maps, acting, episodes, num_envs=min(256, len(episodes))))["success"]
            net.train()
            rows["tianshou"].append((done, time.perf_counter() - t0, success))
            print(f"  tianshou  {done:>7,} steps  {rows['tianshou'][-1][1]:6.0f} s  {100 * success:.1f} %")
            if success >= args.to_target:
                break
        if done >= config.total_steps:
            break
    print(f"time to {100 * args.to_target:g} % validation success ({args.preset} preset, {args.dataset}, replay "
          f"{config.buffer_size:,}, {len(episodes)} episodes per evaluation, every {config.eval_every:,} env steps, "
          f"budget {config.total_steps:,}):")  # fmt: skip
    reached = {}
    for name, r in rows.items():
        hit = next(((step, sec) for step, sec, success in r if success >= args.to_target), None)
        best = max((success for _, _, success in r), default=float("nan"))
        reached[name] = hit
        text = f"{hit[1]:.0f} s at {hit[0]:,} env steps" if hit else f"not reached (best {100 * best:.1f} %)"
        print(f"  {name:>9}: {text}")
    if reached["uavplace"] and reached["tianshou"]:
        print(f"  ratio (tianshou / ours), wall time: {reached['tianshou'][1] / reached['uavplace'][1]:.2f}x")


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


def bench_learners(args: argparse.Namespace) -> None:
    """Our presets' three learners on the same cities, one after the other in one run: best-dqn (replay DQN),
    best-pqn (PQN) and best (PQN with the recurrent core). Env steps/s (acting and learning together) and each
    one's ratio to best-dqn's; updates/s counts each learner's own gradient steps (not the same batch)."""
    cities = [*expand_datasets([args.corpus], args.root), args.dataset] if args.corpus else [args.dataset]
    base = None
    for name in ("best-dqn", "best-pqn", "best"):
        config = preset_config(
            name, total_steps=10 * args.steps, buffer_size=args.steps, learning_starts=min(2_000, args.warmup),
            eval_every=10 * args.steps, eval_episodes=50,
        )  # fmt: skip
        r = bench_ours(config, cities, args.root, args.steps, args.warmup)
        base = base or r["env_steps_per_s"]
        label = f"{name} ({config.learner}{', recurrent' if config.recurrent else ''})"
        print(
            f"  {label:>24}: {r['env_steps_per_s']:6.0f} env steps/s  {r['updates_per_s']:6.1f} updates/s  "
            f"ratio to best-dqn {r['env_steps_per_s'] / base:.2f}x"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dataset", default="train", help="built city (default: the embedded train city)")
    ap.add_argument("--root", default="data/processed")
    ap.add_argument(
        "--preset", default="best-dqn", choices=["paper", "fast", "best-dqn"], help="network and learning rates (a replay DQN)"
    )
    ap.add_argument("--steps", type=int, default=20_000, help="env steps per trainer (after which the clock stops)")
    ap.add_argument("--warmup", type=int, default=4_000, help="env steps before the clock starts (updates already on)")
    ap.add_argument("--memory", action="store_true", help="peak RSS of a paper-preset run with a full replay instead")
    ap.add_argument(
        "--paper-speed", action="store_true", help="instead: the paper network's training, fast against plain (try --steps 8000)"
    )
    ap.add_argument("--rounds", type=int, default=3, help="--paper-speed: alternating rounds of each")
    ap.add_argument("--corpus", default=None, help="instead: ours on --dataset alone against the corpus NAME-NNN and it")
    ap.add_argument("--to-target", type=float, default=None, help="instead: wall time of both to this validation success")
    ap.add_argument(
        "--learners", action="store_true", help="instead: env steps/s of best-dqn, best-pqn and best (with --corpus: on it)"
    )
    ap.add_argument("--budget", type=int, default=300_000, help="--to-target: env steps at most (the preset's schedule)")
    ap.add_argument("--eval-every", type=int, default=10_000, help="--to-target: env steps between evaluations")
    ap.add_argument("--seed", type=int, default=0, help="--to-target: seed of both runs")
    ap.add_argument(
        "--buffer",
        type=int,
        default=50_000,
        help="--to-target: replay capacity of both (Tianshou keeps float32 observations and next observations, "
        "88 KB a transition: the best preset's 2e5 took 19.6 GB and was killed for memory)",
    )
    args = ap.parse_args()
    if args.memory:
        bench_memory(args.dataset, args.root, extra_steps=3_000)
        return
    if args.learners:
        bench_learners(args)
        return
    if args.paper_speed:
        bench_paper_speed(args)
        return
    if args.corpus:
        bench_corpus(args)
        return
    if args.to_target is not None:
        time_to_target(args)
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

"""The tracking task's baselines and upper bound on the same episodes of one or more cities with routes.

The oracle (the most covered steps possible), the re-planning genie, the steered random walk and greedy
hill-climbing (``rl.tracking``) play the same episodes (routes, start times and start cells drawn with
``--seed``); one Markdown table of the per-episode metrics (``rl.tracking.episode_metrics``): the median
steps to first reach P_T, the mean coverage after it, the median longest outage and the mean share of
the horizon covered, with the seconds each method took.

    python benchmarks/tracking_baselines.py tinyr --episodes 200 [--horizon 300] [--root data/processed]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.rl.policies import GreedyPolicy, RandomWalkPolicy
from uavplace.rl.tracking import MovesOnly, OraclePolicy, ReplanningGenie, RouteSet, TrackingConfig, run_tracking


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cities", nargs="+")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--horizon", type=int, default=300)
    ap.add_argument("--p-t-db", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", default="data/processed")
    args = ap.parse_args()
    config = TrackingConfig(horizon=args.horizon, p_t_db=args.p_t_db)
    routes = RouteSet([load_bundle(c, root=args.root) for c in args.cities], config)
    episodes = routes.sample_episodes(args.episodes, np.random.default_rng(args.seed))
    policies = [OraclePolicy(), ReplanningGenie(), MovesOnly(RandomWalkPolicy(seed=args.seed)),
                MovesOnly(GreedyPolicy(config.p_h_db, seed=args.seed))]  # fmt: skip
    print(f"{', '.join(args.cities)}: {args.episodes} episodes, horizon {args.horizon}, P_T {args.p_t_db:g} dB, seed {args.seed}")
    print(
        "| method | median steps to first reach | coverage after it | median longest outage | share of the horizon covered | seconds |"
    )
    print("|---|---|---|---|---|---|")
    for policy in policies:
        t0 = time.perf_counter()
        d = run_tracking(routes, policy, episodes).table
        print(
            f"| {policy.name} | {np.median(d.first_reach):g} | {d.coverage.mean():.3f} | {np.median(d.longest_outage):g} | "
            f"{d.covered_share.mean():.3f} | {time.perf_counter() - t0:.1f} |"
        )


if __name__ == "__main__":
    main()

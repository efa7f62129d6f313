"""The tracking task's methods on the same episodes of one or more cities with routes (validation cities).

The report's methods (``eval.reports.tracking.page.tracking_methods``): the oracle (the most covered steps possible), any
``--agent``, the re-planning genie, the steered random walk and greedy hill-climbing, those without a stay action
also holding their cell while covered (``rl.tasks.tracking.Holding``; ``--no-hold`` leaves them out). They play the same
episodes (routes, start times and start cells drawn with ``--seed``); one Markdown table of the per-episode
metrics (``rl.tasks.tracking.episode_metrics``): the median steps to first reach P_T, the mean coverage after it, the
median longest outage and the mean share of the horizon covered, with the seconds each method took.

    python experiments/tracking_baselines.py trk-val --episodes 300 [--agent data/agents/best] [--horizon 300] [--searcher]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.cities import development_cities
from uavplace.eval.evaluate import check_unseen, load_agent
from uavplace.eval.reports.tracking.page import tracking_methods
from uavplace.rl.belief import PREDICTIONS, PredictionCache
from uavplace.rl.config import DEFAULT_PREDICTOR
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.tasks.tracking import RouteSet, TrackingConfig, TrackingSearchPolicy, fit_motion, run_tracking, tracking_search


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cities", nargs="*", help="Cities with routes (default: every validation city built)")
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--horizon", type=int, default=300)
    ap.add_argument("--p-t-db", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--root", default="data/processed")
    ap.add_argument("--agent", action="append", default=[], help="An agent's run folder (repeatable)")
    ap.add_argument("--no-hold", action="store_true", help="Leave out the methods holding their cell while covered")
    ap.add_argument("--release", action="store_true", help="Allow test cities (release numbers only, never to choose)")
    ap.add_argument(
        "--searcher",
        action="store_true",
        help="Also the tracking searcher (rl/tasks/tracking/searcher.py): the shipped predictor, the motion fitted on --motion-from",
    )
    ap.add_argument("--motion-from", nargs="+", default=[f"trk-00{i}" for i in range(4)],
                    help="Training cities with routes whose speeds the tracking searcher's motion is fitted on")  # fmt: skip
    args = ap.parse_args()
    config = TrackingConfig(horizon=args.horizon, p_t_db=args.p_t_db)
    cities = development_cities(args.cities, args.root, release=args.release)
    bundles = [load_bundle(c, root=args.root) for c in cities]
    if not args.cities:  # the validation cities that have routes
        bundles = [b for b in bundles if b.routes is not None]
    agents = [load_agent(a, 0.096, args.seed, task=None) for a in args.agent]
    for b in bundles:
        check_unseen(agents, b)
    routes = RouteSet(bundles, config)
    episodes = routes.sample_episodes(args.episodes, np.random.default_rng(args.seed))
    policies = tracking_methods(config, args.seed, agents, hold=not args.no_hold)
    if args.searcher:
        motion = fit_motion([load_bundle(c, root=args.root) for c in args.motion_from])
        print(f"motion fitted on {', '.join(args.motion_from)}: {motion}")
        cache = PredictionCache(f"{args.root}/{PREDICTIONS}")
        searcher = MapSearchPolicy(load_predictor(DEFAULT_PREDICTOR), tracking_search(), cache)
        policies.append(TrackingSearchPolicy(searcher, motion))
    print(
        f"{', '.join(b.city for b in bundles)}: {args.episodes} episodes, horizon {args.horizon}, P_T {args.p_t_db:g} dB, seed {args.seed}"
    )
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

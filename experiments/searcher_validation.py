"""The map searcher on validation cities: the report's methods that matter to it, paired on the same episodes.

Per validation city (never a test city: this is where the searcher's settings are chosen): the genie, the shipped
``best`` (or the agents of ``--agent``, the first the reference), the map searcher (rl/tasks/placement/searcher.py)
and its ablation shown open ground, on the episodes ``uavrl report`` draws; success, median steps, ratio to the genie's median and SPL
with 95 % intervals over users then episodes, and every method's paired differences against the first agent and
against the searcher. Settings of the searcher as ``--set name=value`` (``SearchConfig`` fields).

    python experiments/searcher_validation.py [--city oldtown-005] [--episodes 300] [--set temper=0.3] [--quick]
        [--predictor data/agents/searcher/unet] [--agent data/agents/best --agent runs/hybrid/h-s0]
        [--variant planner=info,info_weight=0.2] [--versus runs/predictor/v2] [--measure sigma_db=4]
"""

from __future__ import annotations

import time
from pathlib import Path

import click
from common import VALIDATION, trace_with_workers, validation_parser

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import ReportConfig, evaluate, load_agent
from uavplace.eval.metrics import bootstrap_table, difference_table
from uavplace.infra.console import markdown_table
from uavplace.infra.options import with_pairs
from uavplace.rl.belief import PREDICTIONS, PredictionCache
from uavplace.rl.config import DEFAULT_PREDICTOR, MeasurementSettings, SearchConfig
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.tasks.placement.searcher import SEARCHER, MapSearchPolicy


def _settings(ap, base, pairs: list[str], option: str):  # noqa: ANN001, ANN202 - its parser, a model and the same model
    """``base`` with ``pairs`` (``name=value``, JSON values) set, as ``uavrl report --search`` sets them; a bad one ends
    the script with the parser's usage error."""
    try:
        return with_pairs(base, pairs, option)
    except click.BadParameter as exc:
        ap.error(exc.format_message())


def main() -> None:
    ap = validation_parser(__doc__, episodes=300)
    ap.add_argument(
        "--agent",
        type=Path,
        action="append",
        default=None,
        help="Agent folder (repeatable; default: data/agents/best); the first is the reference of the differences",
    )
    ap.add_argument("--set", action="append", default=[], help="A SearchConfig field, name=value (JSON value)")
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        help="Another searcher played beside it on the same episodes, its fields changed: name=value[,name=value] "
        "(repeatable; named 'map searcher [name=value,...]'; paired against the searcher)",
    )
    ap.add_argument("--root", type=Path, default=Path("data/processed"))
    ap.add_argument("--predictor", type=Path, default=DEFAULT_PREDICTOR, help="Constants' JSON or a tier's folder")
    ap.add_argument(
        "--versus",
        type=Path,
        action="append",
        default=[],
        help="Another predictor (a tier's folder or constants' JSON) whose searcher plays beside it on the same "
        "episodes, named 'map searcher [FOLDER]' (repeatable; paired against the searcher)",
    )
    ap.add_argument(
        "--measure",
        action="append",
        default=[],
        help="What the UAVs read (a MeasurementSettings field, name=value, as uavrl report --measure; repeatable)",
    )
    ap.add_argument("--quick", action="store_true", help="The genie and the searcher only (no best, no ablation)")
    ap.add_argument(
        "--workers",
        type=int,
        default=1,
        help="Ray tasks a ray-traced tier traces its candidates in (a local Ray of that many CPUs; the maps are the "
        "same whatever the number)",
    )
    args = ap.parse_args()
    search = _settings(ap, SearchConfig(), args.set, "--set")
    measurement = _settings(ap, MeasurementSettings(), args.measure, "--measure")
    predictor, cache = load_predictor(args.predictor), PredictionCache(args.root / PREDICTIONS)
    versus = [(other, load_predictor(other)) for other in args.versus]
    trace_with_workers([predictor] + [t for _, t in versus], args.workers)
    folders = args.agent or [Path("data/agents/best")]
    agents = [] if args.quick else [load_agent(f, epsilon=0.096, seed=args.seed) for f in folders]
    if len({a.name for a in agents}) != len(agents):  # two runs of one preset: named by their folders
        for a, f in zip(agents, folders, strict=True):
            a.name = a.policy.name = f"{a.name} [{f.name}]"
    print(f"searcher settings: {search.model_dump()}; measurement: {measurement.model_dump()}")
    for city in args.city or VALIDATION:
        bundle = load_bundle(city, root=args.root)
        if bundle.manifest.config.role == "test":
            ap.error(f"{city} is a test city: release numbers come from `uavrl report`, never a choice")
        config = ReportConfig(dataset=city, episodes=args.episodes, seed=args.seed, predictor=None, measurement=measurement)
        policies = [GeniePolicy()] + [
            MapSearchPolicy(predictor, search.model_copy(update={"buildings": b}), cache)
            for b in ((True,) if args.quick else (True, False))
        ]
        for text in args.variant:
            changed = _settings(ap, search, text.split(","), "--variant")
            policies.append(MapSearchPolicy(predictor, changed, cache, name=f"{SEARCHER} [{text}]"))
        for other, tier in versus:
            policies.append(MapSearchPolicy(tier, search, cache, name=f"{SEARCHER} [{other.name}]"))
        t0 = time.perf_counter()
        results = evaluate(config, bundle, agents, baselines=policies)
        wall = time.perf_counter() - t0
        table = bootstrap_table(results, n_boot=1000, seed=args.seed)
        rows = [["method", "success", "median steps", "median / genie's", "SPL"]]
        for r in table.to_dict("records"):
            rows.append([r["method"], f"{100 * r['success']:.1f} % [{100 * r['success_lo']:.1f}, {100 * r['success_hi']:.1f}]",
                         f"{r['median_steps']:g} [{r['median_steps_lo']:g}, {r['median_steps_hi']:g}]",
                         f"{r['medians_ratio']:.2f}", f"{r['spl']:.3f}"])  # fmt: skip
        print(f"\n{city} ({args.episodes} episodes, {wall:.0f} s)\n" + markdown_table(rows), flush=True)
        diffs = difference_table(results, [a.name for a in agents[:1]] + [SEARCHER], n_boot=1000, seed=args.seed)
        for d in diffs.to_dict("records"):
            if d["method"] != GeniePolicy.name:
                scale = 100 if d["stat"] == "success" else 1
                print(f"  {d['method']} - {d['against']}, {d['stat']}: {scale * d['difference']:+.1f} "
                      f"[{scale * d['lo']:+.1f}, {scale * d['hi']:+.1f}]")  # fmt: skip


if __name__ == "__main__":
    main()

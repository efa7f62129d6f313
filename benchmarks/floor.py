"""The main job's arithmetic: how fast its report could be on this machine with every number the same.

It reads the episodes a report played (``reports/<city>/episodes.parquet``, the main job's) and counts the two
kinds of arithmetic its rollouts cannot skip without changing a number:

- the agents' networks: one forward pass per row and step (FLOPs per sample counted by
  ``torch.utils.flop_counter``), and the best rate of each network on this machine, a full batch of 256 rows;
- the belief product of the map searcher and of the hybrid's belief channel: at every step of a row, its belief
  times every candidate's cover, ``2 C M`` FLOPs for ``C`` candidates and ``M`` legal cells of the row's canvas
  (the canvases' shapes from the predicted maps, with the buildings shown and blanked); the hybrid's in the precision
  its channel is played in (``EnvConfig.belief_precision`` of ``data/agents/hybrid``: bfloat16 since issue 90), at
  the rate of torch's bfloat16 product at the same shape.

With the cache cold the report also predicts every candidate's map of every canvas it plays (with the buildings shown
and blanked): it counts them, times the predictor on one canvas with no cache and counts its FLOPs there, for the
seconds they take at that rate (the predictor's measured time, not a floor) and at the product's peak.

Then it times numpy's float32 matrix product (the same OpenBLAS the product runs on) at the largest of those shapes
with 256 rows, on every core torch and BLAS are given, and prints each part's seconds at its own best rate and at
that peak. Their sum is a floor under the report's rollouts, below which no change that keeps the tables the same can
go on this machine: it leaves out the environment's steps, the statistics and the figures, and counts every FLOP at
the rate of a full, square product.

    python benchmarks/floor.py [--reports reports] [--city test --city etoile --city florence]

Run it after the main job (README, first command): the predicted maps are read from its cache.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from torch.utils.flop_counter import FlopCounterMode

from uavplace.dataset.bundle import load_bundle
from uavplace.eval.evaluate import (
    NO_BUILDINGS,
    SHIPPED_AGENTS,
    ReportConfig,
    default_agents,
    default_baselines,
    load_agent,
    report_env,
)
from uavplace.rl.belief import PredictionCache
from uavplace.rl.predictor import load_predictor
from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
from uavplace.rl.world.maps import MapSet
from uavplace.rl.world.view import PublicMaps

#: The rows of a batch the rates are measured at: the report's ``num_envs``.
BATCH = 256
#: The methods whose every step multiplies a belief by the candidates' cover maps: the searcher's own, and the hybrid's
#: channel (the same candidates: ``rl.belief.BeliefTracker`` predicts with the buildings as its maps show them).
PRODUCT_METHODS = ("map searcher", "PQN + GRU (hybrid)")


def rate(fn, flops: float, seconds: float) -> float:  # noqa: ANN001 - a call without arguments
    """FLOP/s of ``fn``, which does ``flops``, called for ``seconds`` after one warm-up call."""
    fn()
    t0, n = time.perf_counter(), 0
    while time.perf_counter() - t0 < seconds:
        fn()
        n += 1
    return n * flops / (time.perf_counter() - t0)


def product_shapes(city: str, root: str) -> tuple[dict[tuple[str, int], tuple[int, int]], MapSet]:
    """``{(method, canvas): (C, M)}`` for the product methods, shown and blanked (each canvas's candidates: the maps a
    cold cache predicts for a canvas played on), and the report's maps."""
    bundle = load_bundle(city, root=root)
    config = ReportConfig(dataset=city)
    shapes: dict[tuple[str, int], tuple[int, int]] = {}
    maps = MapSet([bundle], report_env(config))
    public = PublicMaps.of(maps)
    policies = {p.name: p for p in default_baselines(config, bundle)}
    for suffix in ("", NO_BUILDINGS):  # the searcher given the buildings, then its ablation (a policy of its own)
        searcher = policies[PRODUCT_METHODS[0] + suffix]
        for canvas in np.unique(maps.view_map):
            cover = searcher.canvas_maps(public, int(canvas)).cover
            for method in PRODUCT_METHODS:
                shapes[method + suffix, int(canvas)] = cover.shape
    return shapes, maps


def predictor_rate(city: str, root: str) -> tuple[float, float]:
    """(seconds, FLOPs) the map searcher spends predicting one candidate's map: canvas 0 of ``city`` with no cache,
    predicted twice, once timed and once counted (the counter slows every call)."""
    bundle = load_bundle(city, root=root)
    config = ReportConfig(dataset=city)
    public = PublicMaps.of(MapSet([bundle], report_env(config)))
    predictor = load_predictor(config.predictor)
    t0 = time.perf_counter()
    made = MapSearchPolicy(predictor, config.search, PredictionCache(None)).canvas_maps(public, 0)
    seconds = (time.perf_counter() - t0) / len(made.cells)
    with FlopCounterMode(display=False) as counter:
        MapSearchPolicy(predictor, config.search, PredictionCache(None)).canvas_maps(public, 0)
    return seconds, counter.get_total_flops() / len(made.cells)


def network_rates(seconds: float) -> dict[str, tuple[float, float]]:
    """``{agent name: (FLOPs a sample, FLOP/s at a full batch)}`` of each shipped agent, acting as the report acts."""
    out = {}
    for folder in default_agents():
        agent = load_agent(folder, 0.0, 0)
        net, env = agent.policy.net, agent.config.env_config(evaluation=True)
        x = torch.rand(BATCH, env.num_channels, env.window, env.window).mul(255).contiguous(memory_format=torch.channels_last)
        h = net.initial_state(BATCH) if agent.policy.recurrent else None

        def forward(net=net, x=x, h=h) -> torch.Tensor:  # noqa: ANN001 - bound at definition
            with torch.inference_mode():
                return net(x) if h is None else net.head(net.encode(x, h))

        with FlopCounterMode(display=False) as counter:
            forward()
        flops = counter.get_total_flops()
        out[agent.name] = (flops / BATCH, rate(forward, flops, seconds))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reports", default="reports", help="the report's folder: <city>/episodes.parquet (default: reports)")
    ap.add_argument("--city", action="append", default=None, help="a city of the report (repeatable; default: its three)")
    ap.add_argument("--root", default="data/processed", help="the bundles (default: data/processed)")
    ap.add_argument("--predict-city", default="florence", help="where the predictor is timed (default: florence)")
    ap.add_argument("--seconds", type=float, default=4.0, help="how long each rate is timed (default: 4)")
    args = ap.parse_args()
    cities = args.city or ["test", "etoile", "florence"]
    rows = []  # (part, TFLOP, FLOP/s at its own best)
    largest = (0, 0)
    steps: dict[str, int] = {}
    predicted = 0  # candidates' maps a cold cache makes: every canvas, buildings shown and blanked
    for city in cities:
        played = pd.read_parquet(Path(args.reports) / city / "episodes.parquet")
        shapes, maps = product_shapes(city, args.root)
        largest = max([largest, *shapes.values()], key=lambda s: s[0] * s[1])
        flown = {int(c) for c in np.unique(maps.view_map[played.view.to_numpy()])}  # the canvases its episodes play on
        predicted += sum(c for (m, canvas), (c, _) in shapes.items() if m.startswith(PRODUCT_METHODS[0]) and canvas in flown)
        for method, frame in played.groupby("method"):
            steps[method] = steps.get(method, 0) + int(frame.steps.sum())
            canvases = maps.view_map[frame.view.to_numpy()]
            if (method, int(canvases[0])) in shapes:
                cm = np.array([np.prod(shapes[method, int(c)]) for c in canvases], np.float64)
                rows.append((f"{city}: {method}, belief product", float(2 * cm @ frame.steps.to_numpy()), None))
    a = np.random.default_rng(0).random((BATCH, largest[0]), np.float32)
    b = np.random.default_rng(1).random(largest, np.float32)
    peak = rate(lambda: a @ b, 2.0 * BATCH * largest[0] * largest[1], args.seconds)
    low_a, low_b = torch.from_numpy(a).bfloat16(), torch.from_numpy(b).bfloat16()
    low = rate(lambda: low_a @ low_b, 2.0 * BATCH * largest[0] * largest[1], args.seconds)
    hybrid = load_agent(SHIPPED_AGENTS / "hybrid", 0.0, 0).config.env_config(evaluation=True).belief_precision
    low_rows = {part for part, _, _ in rows if hybrid == "bfloat16" and PRODUCT_METHODS[1] in part}
    rows = [(part + " (bfloat16)", flops, low) if part in low_rows else (part, flops, peak) for part, flops, _ in rows]
    for name, (per_sample, best) in network_rates(args.seconds).items():
        samples = sum(n for method, n in steps.items() if method == name or method == name + NO_BUILDINGS)
        rows.append((f"{name}: networks ({samples} samples, {per_sample / 1e6:.2f} MFLOP each)", samples * per_sample, best))
    print(
        f"float32 product of {BATCH} x {largest[0]} by {largest[0]} x {largest[1]}: {peak / 1e9:.1f} GFLOP/s, in "
        f"bfloat16 (torch) {low / 1e9:.1f} GFLOP/s (torch threads {torch.get_num_threads()})\n"
    )
    print("| part | TFLOP | its best rate, GFLOP/s | s at its best rate | s at the product's peak |")
    print("|---|---|---|---|---|")
    for part, flops, best in rows:
        print(f"| {part} | {flops / 1e12:.2f} | {best / 1e9:.1f} | {flops / best:.1f} | {flops / peak:.1f} |")
    flops = sum(r[1] for r in rows)
    own, at_peak = sum(r[1] / r[2] for r in rows), flops / peak
    print(f"| all | {flops / 1e12:.2f} | | {own:.1f} | {at_peak:.1f} |")
    per_map, map_flops = predictor_rate(args.predict_city, args.root)
    print(
        f"\nWith the cache cold: {predicted} predicted maps, {map_flops / 1e6:.0f} MFLOP each in torch (the learned "
        f"tier), at {per_map * 1e3:.1f} ms a map ({args.predict_city}, canvas 0, no cache): {predicted * per_map:.0f} s "
        f"more, {predicted * map_flops / peak:.0f} s of it at the product's peak."
    )


if __name__ == "__main__":
    main()

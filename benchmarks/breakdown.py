"""Where the main job's time goes: `uavrl report` as the README runs it, in this process, its parts timed.

For each city and method: the wall and CPU seconds of its predicted maps (a searcher's, cold or warm cache as it
finds it) and of its rollouts; per city the statistics (the tables, the paired differences, the performance
profiles' bands) and the figures; then the page of every city (its aggregate and pooled profiles) and what is left
(loading, writing, the imports). One table, each part's share of the whole wall time. CPU seconds are this process's
(every thread: torch's, Ray's driver; not the Ray workers'), so above the wall time when both cores work in it. With
Ray (``--workers`` above 1) the methods' rollouts run at once in the workers: the table then has one row a city,
"rollouts (every method, on Ray)", its wall time the city's.

    python benchmarks/breakdown.py [--out runs/breakdown] [REPORT OPTIONS ...]   # e.g. --workers 1 --quiet --dataset test

The timers wrap the report's functions from outside (the package is unchanged); run it from the repository root with
the bundles built, on a machine with nothing else running, for docs/benchmarks.md's numbers.
"""

from __future__ import annotations

import argparse
import functools
import time
from collections import defaultdict
from pathlib import Path

#: The statistics and the figures, by the names the report (``uavplace.eval.report``) calls them through.
STATISTICS = ("results_table", "difference_table", "ablation_table", "group_tables", "profiles")
FIGURES = ("plot_cdf", "plot_profiles", "plot_training", "plot_trajectories")


class Stopwatch:
    """Wall and CPU seconds by (city, part), summed over calls; the city is the one being reported."""

    def __init__(self) -> None:
        self.city = "-"
        self.depth = 0  # a part called inside another (a searcher's maps inside a rollout) counts as the outer one
        self.wall: dict[tuple[str, str], float] = defaultdict(float)
        self.cpu: dict[tuple[str, str], float] = defaultdict(float)

    def wrap(self, fn, part):  # noqa: ANN001, ANN201 - any function, the same signature
        @functools.wraps(fn)
        def timed(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            if self.depth:
                return fn(*args, **kwargs)
            wall, cpu = time.perf_counter(), time.process_time()
            self.depth += 1
            try:
                return fn(*args, **kwargs)
            finally:
                self.depth -= 1
                key = (self.city, part(*args, **kwargs) if callable(part) else part)
                self.wall[key] += time.perf_counter() - wall
                self.cpu[key] += time.process_time() - cpu

        return timed


def instrument(watch: Stopwatch) -> None:
    """Wrap the report's parts in ``watch`` (module attributes, as the report looks them up)."""
    import uavplace.eval.evaluate as evaluate
    import uavplace.eval.parallel as parallel
    import uavplace.eval.render as render
    import uavplace.eval.report as report
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

    load_bundle = report.load_bundle

    def city_of(name, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        watch.city = name.split("@")[0]
        return load_bundle(name, *args, **kwargs)

    report.load_bundle = city_of
    evaluate.run_episodes = watch.wrap(evaluate.run_episodes, lambda mapset, policy, *a, **k: f"{policy.name}: rollouts")
    parallel.play_on_ray = watch.wrap(parallel.play_on_ray, "rollouts (every method, on Ray)")
    MapSearchPolicy.canvas_maps = watch.wrap(
        MapSearchPolicy.canvas_maps, lambda policy, *a, **k: f"{policy.name}: predicted maps"
    )
    for names, kind in ((STATISTICS, "statistics"), (FIGURES, "figures")):
        for name in names:
            setattr(report, name, watch.wrap(getattr(report, name), kind))
    for name in ("write_summary_page", "markdown_tables"):  # imported by the command when it calls them
        setattr(render, name, watch.wrap(getattr(render, name), "the page of every city (aggregate, pooled profiles)"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog="Other options go to uavrl report.")
    ap.add_argument("--out", type=Path, default=Path("runs/breakdown"), help="the report's folder (not reports/)")
    args, rest = ap.parse_known_args()
    watch = Stopwatch()
    wall, cpu = time.perf_counter(), time.process_time()
    from uavplace.cli import uavrl  # the imports count in the total

    instrument(watch)
    uavrl.main(["report", "--out", str(args.out), "--markdown", str(args.out / "tables.md"), *rest], standalone_mode=False)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    rows = sorted(watch.wall, key=lambda k: -watch.wall[k])
    print("| city | part | wall s | CPU s | share of the wall time |\n|---|---|---|---|---|")
    for key in rows:
        print(f"| {key[0]} | {key[1]} | {watch.wall[key]:.1f} | {watch.cpu[key]:.1f} | {100 * watch.wall[key] / wall:.1f} % |")
    rest_wall, rest_cpu = wall - sum(watch.wall.values()), cpu - sum(watch.cpu.values())
    print(f"| - | the rest (imports, loading, writing) | {rest_wall:.1f} | {rest_cpu:.1f} | {100 * rest_wall / wall:.1f} % |")
    print(f"| all | the report | {wall:.1f} | {cpu:.1f} | 100 % |")
    by_part: dict[str, float] = defaultdict(float)
    for (_, part), seconds in watch.wall.items():
        by_part[part.split(": ")[-1]] += seconds
    print("\nBy kind of work: " + ", ".join(f"{k} {v:.0f} s ({100 * v / wall:.0f} %)" for k, v in
                                              sorted(by_part.items(), key=lambda kv: -kv[1])))  # fmt: skip


if __name__ == "__main__":
    main()

"""Where a report's time goes: `uavrl report` as the README runs it (the main job), or its tracking or fleet report
(``--task tracking``, ``--task fleet``), in this process, its parts timed.

For each city and method: the wall and CPU seconds of its predicted maps (a searcher's, cold or warm cache as it
finds it) and of its rollouts; per city the statistics (the tables, the paired differences, the performance
profiles' bands) and the figures; then the page of every city (its aggregate and pooled profiles) and what is left
(loading, writing, the imports). One table, each part's share of the whole wall time. A part called inside another
(a searcher's maps predicted inside its rollouts) is its own row, and the outer part's seconds are those left
without it. CPU seconds are this process's (every thread: torch's, Ray's driver; not the Ray workers'), so above the
wall time when both cores work in it. With Ray (``--workers`` above 1) the methods' rollouts run at once in the
workers: the table then has one row a city, "rollouts (every method, on Ray)", its wall time the city's.

    python benchmarks/breakdown.py [--out runs/breakdown] [REPORT OPTIONS ...]   # e.g. --workers 1 --quiet --dataset test
    python benchmarks/breakdown.py --task tracking --dataset trk-val --episodes 100 --quiet

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
    """Wall and CPU seconds by (city, part), summed over calls, each part's own (less the parts it called); the city
    is the one being reported."""

    def __init__(self) -> None:
        self.city = "-"
        self.inner: list[list[float]] = []  # per open part: the wall and CPU seconds of the parts it called
        self.wall: dict[tuple[str, str], float] = defaultdict(float)
        self.cpu: dict[tuple[str, str], float] = defaultdict(float)

    def wrap(self, fn, part):  # noqa: ANN001, ANN201 - any function, the same signature
        @functools.wraps(fn)
        def timed(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            key = (self.city, part(*args, **kwargs) if callable(part) else part)
            wall, cpu = time.perf_counter(), time.process_time()
            self.inner.append([0.0, 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                inner_wall, inner_cpu = self.inner.pop()
                wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
                self.wall[key] += wall - inner_wall
                self.cpu[key] += cpu - inner_cpu
                if self.inner:
                    self.inner[-1][0] += wall
                    self.inner[-1][1] += cpu

        return timed

    def in_city(self, fn, city):  # noqa: ANN001, ANN201 - any function; ``city(*args)`` names the city it works on
        @functools.wraps(fn)
        def named(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            self.city = city(*args, **kwargs)
            return fn(*args, **kwargs)

        return named


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


def instrument_tracking(watch: Stopwatch) -> None:
    """The tracking report's parts: each method's rollouts (``run_tracking``) in its route set's city, the searchers'
    maps, the tables' statistics, the figures."""
    import uavplace.eval.reports.tracking.page as page
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

    rollouts = watch.wrap(page.run_tracking, lambda routes, policy, *a, **k: f"{policy.name}: rollouts")
    page.run_tracking = watch.in_city(rollouts, lambda routes, *a, **k: routes.bundles[0].city)
    MapSearchPolicy.canvas_maps = watch.wrap(MapSearchPolicy.canvas_maps, "the searchers' predicted maps")
    page.tracking_table = watch.wrap(page.tracking_table, "statistics")
    for name, city in (("plot_coverage", 3), ("plot_episodes", 4)):  # the city's place among their arguments
        figure = watch.wrap(getattr(page, name), "figures")
        setattr(page, name, watch.in_city(figure, lambda *a, at=city, **k: a[at]))


def instrument_fleet(watch: Stopwatch) -> None:
    """The fleet report's parts: each city's methods' rollouts (``run_fleet``), the searcher's maps, the statistics,
    the figures."""
    import uavplace.eval.reports.fleet.page as page
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

    page.fleet_results = watch.in_city(page.fleet_results, lambda config, bundle, *a, **k: bundle.city)
    page.run_fleet = watch.wrap(page.run_fleet, lambda maps, policy, *a, **k: f"{policy.name}: rollouts")
    MapSearchPolicy.canvas_maps = watch.wrap(MapSearchPolicy.canvas_maps, "the searcher's predicted maps")
    for name in ("bootstrap_table", "difference_table"):
        setattr(page, name, watch.wrap(getattr(page, name), "statistics"))
    page.plot_fleet_episodes = watch.in_city(watch.wrap(page.plot_fleet_episodes, "figures"), lambda bundle, *a, **k: bundle.city)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog="Other options go to uavrl report.")
    ap.add_argument("--out", type=Path, default=Path("runs/breakdown"), help="the report's folder (not reports/)")
    ap.add_argument("--task", choices=("placement", "tracking", "fleet"), default="placement", help="which report")
    args, rest = ap.parse_known_args()
    watch = Stopwatch()
    wall, cpu = time.perf_counter(), time.process_time()
    from uavplace.cli import uavrl  # the imports count in the total

    {"placement": instrument, "tracking": instrument_tracking, "fleet": instrument_fleet}[args.task](watch)
    task = [] if args.task == "placement" else ["--task", args.task]
    uavrl.main(["report", *task, "--out", str(args.out), "--markdown", str(args.out / "tables.md"), *rest], standalone_mode=False)
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

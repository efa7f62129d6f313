"""``uavdata simulate``: ray-trace procedural or open cities into Wireless InSite exports (registered in ``uavplace.cli``)."""

from __future__ import annotations

import math
from pathlib import Path

import click
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from uavplace.infra.console import Bounds, Finite, command_line, console, fail, path_option, ray_address_option, say, stdout
from uavplace.infra.options import model_options, settings
from uavplace.simulate.config import OPTION_NAMES, Simulation


class Point(click.ParamType):
    """``X,Y`` in metres."""

    name = "x,y"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201 - click's signature
        if isinstance(value, tuple):
            return value
        try:
            x, y = (float(v) for v in str(value).split(","))
        except ValueError:
            self.fail(f"{value!r}: expected X,Y in metres", param, ctx)
        if not (math.isfinite(x) and math.isfinite(y)):
            self.fail(f"{value!r}: X and Y must be finite", param, ctx)
        return (x, y)


@click.command()
@click.argument("sources", metavar="SOURCE...", nargs=-1, required=True)
@model_options(Simulation, "name", "count")
@ray_address_option("a corpus")
@click.option(
    "--cpus-per-city",
    type=Finite(min=0.5),
    default=2.0,
    show_default=True,
    help="CPUs each city's Ray task reserves (the ray tracer uses all it is given).",
)
@path_option("--out", "out_root", folder=True, default="data/raw", help="Folder of raw city exports.")
@model_options(
    Simulation,
    *(f for f in Simulation.model_fields if f not in ("name", "count", "seed")),
    names=OPTION_NAMES,
    users_m={"type": Point(), "multiple": True},
    extent_m={"type": Bounds()},
    crop_m={"type": Bounds()},
)
@path_option(
    "--trace-cache",
    folder=True,
    help="Keep each city's traced maps in this folder (CITY.npz, arrays only) and reuse them when the spec and the "
    "ray-trace settings match: changing only --gap-fill-reach, --gap-fill-decay or --gap-fill-walk then re-fills "
    "without tracing.",
)
@model_options(Simulation, "seed")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def simulate(
    sources: tuple[str, ...],
    ray_address: str | None,
    cpus_per_city: float,
    out_root: Path,
    trace_cache: Path | None,
    quiet: bool,
    **values: object,
) -> None:
    """Ray-trace cities with Sionna RT and write each as Wireless InSite exports in OUT/<name>/.

    \b
    SOURCE is one of:
      procedural:train|test|tiny   the original generator (552 x 500, 400 x 500, 96 x 80 m)
      procedural:STYLE[:WxH]       generator v2: grid, rotated, perimeter, towers, organic,
                                   plazas, oldtown (narrow lanes), tiered (large blocks of
                                   many roof tiers), or mixed (the first six styles in turn
                                   by seed); 400 x 400 m
      an InSite .city, a GeoJSON of footprints (OpenStreetMap heights and levels understood),
      a CityJSON .json (0.2 to 2.0, LoD1/LoD2: roof surfaces as tiers; data/geometry/ has two)
      a Mitsuba .xml scene with its PLY/OBJ meshes, or sionna:etoile, sionna:florence (the
      scenes Sionna RT ships): a building per connected body, no ground, roofs in height tiers
    Several SOURCEs, or --count N, make a corpus (OUT/<name>-000/, ...), traced as Ray
    tasks on a local Ray (or --ray-address); cities already done with the same settings
    are skipped, so running the command again resumes it.
    Each city gets <name>.txrx (users and the receiver grid), <name>.setup, <name>.city,
    one <name>.power.tNNN_01.r002.p2m.gz per user, <name>.provenance.csv.gz (where each
    receiver's value came from: ray-traced, walked, ...; schemas/provenance.py) and simulation.json (every parameter,
    package versions, materials, wall time); the settings are simulate/config.py's Simulation. Then: uavdata ingest
    OUT/<name>/ && uavdata build. Needs the raytrace extra: pip install -e '.[raytrace]' (CPU: libllvm19).
    """
    from uavplace.schemas import InputError
    from uavplace.simulate.corpus import city_config, corpus_specs, is_done
    from uavplace.simulate.sources import check_simulation

    call = settings(Simulation, values, OPTION_NAMES)
    try:
        base, rt = call.city(sources[0]), call.raytrace()
    except ValueError as err:  # --device cuda where Dr.Jit finds no GPU
        fail(InputError("--device", str(err)))
    try:
        check_simulation(base, rt, call.count)  # every setting, before any list of cities is made or any work starts
        specs = corpus_specs(list(sources), call.name, call.count, base, call.first)
    except InputError as err:
        fail(err)
    if len(specs) > 1 or ray_address is not None:
        _simulate_corpus(specs, rt, out_root, ray_address, cpus_per_city, quiet, trace_cache)
    elif is_done(specs[0], city_config(rt, specs[0]), out_root):
        stdout().print(
            f"{call.name}: already done with the same settings in {out_root / call.name}", highlight=False, soft_wrap=True
        )
    else:
        _simulate_one(specs[0], city_config(rt, specs[0]), out_root, ray_address, cpus_per_city, quiet, trace_cache)


def _simulate_one(
    spec,
    rt,
    out_root: Path,
    address: str | None,
    cpus: float,
    quiet: bool,  # noqa: ANN001
    trace_cache: Path | None,
) -> None:
    """One city in this process, a progress bar (a line per step when not on a terminal), then its summary line."""
    from uavplace.simulate.pipeline import simulate_city

    name = spec.name
    lines = not quiet and not console.is_terminal  # a log: a line per step instead of a bar
    try:
        with Progress(
            TextColumn("[bold]simulate[/] {task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=console,
            disable=quiet or lines,
            transient=True,
        ) as progress:
            task = progress.add_task(name, total=None)

            def on_progress(stage: str, done: int, total: int) -> None:
                progress.update(task, description=f"{name}: {stage}", completed=done, total=total)
                if lines and done:
                    console.print(f"simulate {name}: {stage} {done}/{total}", highlight=False, markup=False)

            where = {"command": command_line(), "trace_cache": trace_cache, "ray_address": address, "cpus_per_user": cpus}
            folder, record = simulate_city(spec, rt, out_root, on_progress=on_progress, **where)
    except RuntimeError as err:  # Sionna RT missing or its child process failed
        fail(err)
    g = record["grid"]
    say(
        f"simulated {name}: {record['geometry']}, {len(record['users_m'])} users, "
        f"grid {g['num_x']} x {g['num_y']} at {g['spacing_m']:g} m and {g['altitude_m']:g} m, "
        + (
            f"{record['routes']['count']} routes ({record['routes']['points']} points, "
            f"{record['routes']['seconds_per_point']:g} s a point), "
            if record["routes"]["count"]
            else ""
        )
        + f"{100 * record['unreached_cell_share']:.1f} % of user-cells unreached "
        f"({100 * record['gap_filled_cell_share']:.1f} % filled: no ray hit them), ray tracing {record['raytrace_seconds']:.1f} s "
        f"(wall {record['wall_seconds']:.1f} s) -> {folder}",
    )


def _simulate_corpus(
    specs,
    rt,
    out_root: Path,
    address: str | None,
    cpus_per_city: float,
    quiet: bool,  # noqa: ANN001
    trace_cache: Path | None = None,
) -> None:
    """Several cities as Ray tasks, one progress bar (a line per city when not on a terminal), resumable."""
    from uavplace.simulate.corpus import simulate_corpus

    out = stdout()
    lines = quiet or not console.is_terminal
    columns = (
        TextColumn("[bold]simulate[/] corpus"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=console, disable=lines, transient=True) as progress:
        bar = progress.add_task("corpus", total=len(specs))

        def on_city(summary: dict, done: int, total: int) -> None:
            progress.update(bar, completed=len(specs) - total + done)
            if lines and not quiet:
                out.print(
                    f"[{done}/{total}] simulated {summary['name']}: {summary['geometry']} ({summary['seconds']:.0f} s) "
                    f"-> {summary['folder']}",
                    highlight=False,
                    soft_wrap=True,
                    markup=False,
                )

        try:
            done, skipped = simulate_corpus(
                specs,
                rt,
                out_root,
                command=command_line(),
                address=address,
                cpus_per_city=cpus_per_city,
                on_city=on_city,
                trace_cache=trace_cache,
            )
        except RuntimeError as err:
            fail(err)
    out.print(
        f"simulated {len(done)} of {len(specs)} cities into {out_root}"
        + (f"; {len(skipped)} already done with the same settings: {', '.join(skipped)}" if skipped else ""),
        highlight=False,
        soft_wrap=True,
    )

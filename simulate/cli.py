"""``uavdata simulate``: ray-trace procedural or open cities into Wireless InSite exports (registered in ``uavplace.cli``)."""

from __future__ import annotations

import math
from pathlib import Path

import click
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from uavplace.infra.console import SEED, Bounds, Finite, Metres, command_line, console, fail, ray_address_option, stdout
from uavplace.infra.files import check_name


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
@click.option(
    "--name",
    required=True,
    help="City name: the exports go to OUT/<name>/; with several cities, OUT/<name>-000/, OUT/<name>-001/, ...",
)
@click.option(
    "--count",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Cities to draw from one procedural SOURCE, seeds SEED, SEED+1, ... (a corpus).",
)
@ray_address_option("a corpus")
@click.option(
    "--cpus-per-city",
    type=Finite(min=0.5),
    default=2.0,
    show_default=True,
    help="CPUs each city's Ray task reserves (the ray tracer uses all it is given).",
)
@click.option(
    "--out",
    "out_root",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("data/raw"),
    show_default=True,
    help="Folder of raw city exports.",
)
@click.option(
    "--users",
    "num_users",
    type=click.IntRange(min=1),
    default=27,
    show_default=True,
    help="Users (ground transmitters at 1.5 m) sampled uniformly over open ground.",
)
@click.option(
    "--user",
    "users_m",
    type=Point(),
    multiple=True,
    help="Place a user at X,Y instead of sampling (repeatable; overrides --users).",
)
@click.option(
    "--routes",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="User routes for the tracking task: paths along open ground (clear of every building by 0.25 m or more), sampled "
    "every <= 2 m, every point traced as a user; written as the .txrx points set 'Route' and <name>.routes.csv "
    "(simulate/routes.py).",
)
@click.option("--route-length", "route_length_m", type=Metres(), default="120m", show_default=True, help="Length of each route.")
@click.option(
    "--route-kinds",
    default="pedestrian,vehicle",
    show_default=True,
    help="Kinds of the routes, in turn: pedestrian (1.4 m/s) and vehicle (10 m/s); a kind sets the user's speed.",
)
@click.option("--grid", "grid_m", type=Metres(), default="4m", show_default=True, help="Receiver grid spacing.")
@click.option(
    "--alt", "altitude_m", type=Metres(), default="10m", show_default=True, help="Receiver grid height (the UAV altitude)."
)
@click.option("--extent", type=Bounds(), default=None, help="Grid extent XMIN,YMIN,XMAX,YMAX [m] (default: the city's bounds).")
@click.option(
    "--crop",
    type=Bounds(),
    default=None,
    help="Real geometry only: keep the buildings inside XMIN,YMIN,XMAX,YMAX [m] (clipped; counted) and make that the city.",
)
@click.option("--freq", "frequency_hz", type=Finite(), default=800e6, show_default=True, help="Carrier frequency [Hz].")
@click.option("--tx-dbm", type=Finite(), default=20.0, show_default=True, help="User transmit power [dBm].")
@click.option("--samples", type=Finite(), default=1e6, show_default=True, help="Rays per user (Sionna samples_per_tx).")
@click.option("--depth", type=click.IntRange(min=0), default=5, show_default=True, help="Maximum interactions per path.")
@click.option(
    "--solver",
    type=click.Choice(["radio-map", "paths"]),
    default="radio-map",
    show_default=True,
    help="radio-map: Sionna's radio map of every cell, the gaps filled by --gap-fill-method. paths: exact paths "
    "(Sionna's PathSolver, every path found, as InSite computes them) at every open cell, nothing filled, --samples "
    "rays per user for each cell (2e6 is the fidelity reference's): about a second a cell and user on 2 cores, so "
    "for small cities (simulate/raytrace.py, exact_path_maps; docs/fidelity.md, the exact-path twin).",
)
@click.option("--no-diffraction", is_flag=True, help="Switch edge diffraction off (faster, more dead cells).")
@click.option(
    "--gap-fill",
    default="none",
    show_default=True,
    help="Coarser maps (cell x factor, same samples, e.g. 4,16) traced as well, which the smooth and parent "
    "methods take their levels from; 'none' for the geodesic method.",
)
@click.option(
    "--gap-fill-method",
    type=click.Choice(["geodesic", "smooth", "parent"]),
    default="geodesic",
    show_default=True,
    help="How cells no ray hit are filled. geodesic: the exact straight path from the user through the walls it "
    "crosses (simulate/transmission.py; none beyond --depth walls), then a walk of --gap-fill-reach metres from "
    "the hit cells through open ground, losing --gap-fill-decay dB per metre; the rest stays unreached. The "
    "earlier fills from --gap-fill's coarse maps, which leave the coarse cells' lattice in the maps: smooth (the "
    "coarse level, the variation of the nearest hit cells) and parent (the coarse cell's mean, copied).",
)
@click.option(
    "--gap-fill-reach",
    "gap_fill_reach_m",
    type=Finite(min=0, max=400),
    default=24.0,
    show_default=True,
    help="geodesic: how far [m] from a hit cell the walk goes (0: direct paths only).",
)
@click.option(
    "--gap-fill-decay",
    "gap_fill_decay_db_per_m",
    type=Finite(min=0, max=100),
    default=3.0,
    show_default=True,
    help="geodesic: loss of the walk [dB per metre].",
)
@click.option(
    "--gap-fill-walk",
    type=click.Choice(["euclidean", "4-neighbour"]),
    default="euclidean",
    show_default=True,
    help="geodesic: how the walk measures its reach. euclidean: the shortest way through open ground in steps of 1, "
    "sqrt 2 and sqrt 5 cells (within 3 % of a straight line), so what it lights follows the streets; 4-neighbour: steps "
    "along the axes only (an isolated lit patch is a diamond; the fill of the cities simulated before this option).",
)
@click.option(
    "--complete-missed",
    is_flag=True,
    help="Trace exact paths (Sionna's PathSolver, every path found) at every open cell the radio map missed, instead of "
    "filling them: each user's missed cells a Ray task (--ray-address; --cpus-per-city CPUs each; on a GPU where "
    "Mitsuba finds one), each user's result kept in --trace-cache so that a stopped run resumes per user. About 0.4 s a "
    "cell and user at 2e6 rays on 2 cores (docs/fidelity.md, 'Exact paths for the missed cells').",
)
@click.option(
    "--complete-samples",
    type=Finite(min=1),
    default=2e6,
    show_default=True,
    help="--complete-missed: PathSolver's rays per user for each missed cell (2e6: the exact-path reference's).",
)
@click.option(
    "--trace-cache",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Keep each city's traced maps in this folder (CITY.npz, arrays only) and reuse them when the spec and the "
    "ray-trace settings match: changing only --gap-fill-reach, --gap-fill-decay or --gap-fill-walk then re-fills "
    "without tracing.",
)
@click.option(
    "--seed", type=SEED, default=0, show_default=True, help="Seed of the city generator, the users and the ray sampler."
)
@click.option("--quiet", is_flag=True, help="No progress bar.")
def simulate(
    sources: tuple[str, ...],
    name: str,
    count: int,
    ray_address: str | None,
    cpus_per_city: float,
    out_root: Path,
    num_users: int,
    users_m: tuple,
    routes: int,
    route_length_m: float,
    route_kinds: str,
    grid_m: float,
    altitude_m: float,
    extent,
    crop,
    frequency_hz: float,
    tx_dbm: float,
    samples: float,
    depth: int,
    solver: str,
    no_diffraction: bool,
    gap_fill: str,
    gap_fill_method: str,
    gap_fill_reach_m: float,
    gap_fill_decay_db_per_m: float,
    gap_fill_walk: str,
    complete_missed: bool,
    complete_samples: float,
    trace_cache: Path | None,
    seed: int,
    quiet: bool,
) -> None:
    """Ray-trace cities with Sionna RT and write each as Wireless InSite exports in OUT/<name>/.

    \b
    SOURCE is one of:
      procedural:train|test|tiny   the original generator (552 x 500, 400 x 500, 96 x 80 m)
      procedural:STYLE[:WxH]       generator v2: grid, rotated, perimeter, towers, organic,
                                   plazas, oldtown (narrow lanes), or mixed (the first six
                                   styles in turn by seed); 400 x 400 m
      an InSite .city, a GeoJSON of footprints (OpenStreetMap heights and levels understood)
      a Mitsuba .xml scene with its PLY/OBJ meshes, or sionna:etoile, sionna:florence (the
      scenes Sionna RT ships): a building per connected body, no ground, roofs in height tiers
    Several SOURCEs, or --count N, make a corpus (OUT/<name>-000/, ...), traced as Ray
    tasks on a local Ray (or --ray-address); cities already done with the same settings
    are skipped, so running the command again resumes it.
    Each city gets <name>.txrx (users and the receiver grid), <name>.setup, <name>.city,
    one <name>.power.tNNN_01.r002.p2m.gz per user, <name>.provenance.csv.gz (where each
    receiver's value came from: ray-traced, walked, ...; schemas/provenance.py) and simulation.json (every parameter,
    package versions, materials, wall time). Then: uavdata ingest OUT/<name>/ && uavdata build.
    Needs the raytrace extra: pip install -e '.[raytrace]' (CPU: libllvm19).
    """
    from uavplace.schemas import InputError
    from uavplace.simulate.corpus import city_config, corpus_specs, is_done
    from uavplace.simulate.pipeline import SimulationSpec, check_simulation, simulate_city
    from uavplace.simulate.raytrace import RayTraceConfig

    check_name(name, "city name")
    for value, hint in ((extent, "--extent"), (crop, "--crop")):
        if isinstance(value, str):
            raise click.BadParameter("expected XMIN,YMIN,XMAX,YMAX", param_hint=hint)
    base = SimulationSpec(source=sources[0], name=name, num_users=len(users_m) or num_users, grid_m=grid_m, altitude_m=altitude_m,
                          tx_dbm=tx_dbm, seed=seed, extent_m=extent, users_m=tuple(users_m), crop_m=crop, routes=routes,
                        route_length_m=route_length_m, route_kinds=tuple(k.strip() for k in route_kinds.split(",")))  # fmt: skip
    try:
        factors = () if gap_fill == "none" else tuple(int(f) for f in gap_fill.split(","))
    except ValueError:
        raise click.BadParameter(f"{gap_fill!r}: expected factors like 4,16, or none", param_hint="--gap-fill") from None
    if any(f < 2 for f in factors):
        raise click.BadParameter("factors must be >= 2", param_hint="--gap-fill")
    if gap_fill_method != "geodesic" and not factors:
        raise click.BadParameter(f"the {gap_fill_method} method takes its levels from coarse maps: add --gap-fill 4,16",
                                 param_hint="--gap-fill")  # fmt: skip
    rt = RayTraceConfig(
        frequency_hz=frequency_hz,
        samples_per_tx=int(samples) if math.isfinite(samples) else samples,  # check_simulation refuses nan and inf
        max_depth=depth,
        diffraction=not no_diffraction,
        seed=seed,
        gap_fill_factors=factors,
        gap_fill_method=gap_fill_method,
        gap_fill_reach_m=gap_fill_reach_m,
        gap_fill_decay_db_per_m=gap_fill_decay_db_per_m,
        gap_fill_walk=gap_fill_walk,
        complete_missed_samples=(int(complete_samples) if math.isfinite(complete_samples) else complete_samples)
        if complete_missed
        else 0,
        solver=solver,
    )
    try:
        check_simulation(base, rt, count)  # every option, before any list of cities is made or any work starts
    except InputError as err:
        fail(err)
    specs = corpus_specs(list(sources), name, count, base)
    if len(specs) > 1 or ray_address is not None:
        _simulate_corpus(specs, rt, out_root, ray_address, cpus_per_city, quiet, trace_cache)
        return
    if is_done(specs[0], city_config(rt, specs[0]), out_root):
        stdout().print(f"{name}: already done with the same settings in {out_root / name}", highlight=False, soft_wrap=True)
        return
    lines = not quiet and not console.is_terminal  # a log: a line per step instead of a bar
    try:
        with Progress(TextColumn("[bold]simulate[/] {task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=console, disable=quiet or lines, transient=True) as progress:  # fmt: skip
            task = progress.add_task(name, total=None)

            def on_progress(stage: str, done: int, total: int) -> None:
                progress.update(task, description=f"{name}: {stage}", completed=done, total=total)
                if lines and done:
                    console.print(f"simulate {name}: {stage} {done}/{total}", highlight=False, markup=False)

            folder, record = simulate_city(specs[0], rt, out_root, command=command_line(), on_progress=on_progress,
                                           trace_cache=trace_cache, ray_address=ray_address,
                                           cpus_per_user=cpus_per_city)  # fmt: skip
    except RuntimeError as err:  # Sionna RT missing or its child process failed
        fail(err)
    g = record["grid"]
    stdout().print(
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
        highlight=False,
        soft_wrap=True,
    )


def _simulate_corpus(specs, rt, out_root: Path, address: str | None, cpus_per_city: float, quiet: bool,  # noqa: ANN001
                     trace_cache: Path | None = None) -> None:  # fmt: skip
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
                out.print(f"[{done}/{total}] simulated {summary['name']}: {summary['geometry']} ({summary['seconds']:.0f} s) "
                          f"-> {summary['folder']}", highlight=False, soft_wrap=True, markup=False)  # fmt: skip

        try:
            done, skipped = simulate_corpus(specs, rt, out_root, command=command_line(), address=address,
                                            cpus_per_city=cpus_per_city, on_city=on_city, trace_cache=trace_cache)  # fmt: skip
        except RuntimeError as err:
            fail(err)
    out.print(
        f"simulated {len(done)} of {len(specs)} cities into {out_root}"
        + (f"; {len(skipped)} already done with the same settings: {', '.join(skipped)}" if skipped else ""),
        highlight=False,
        soft_wrap=True,
    )

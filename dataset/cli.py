"""``uavdata``: ingest raw ray-tracer exports, build versioned map bundles, list and show them."""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import sys
from pathlib import Path
from typing import NoReturn

import click
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table
from rich.text import Text

from dataset.catalog import DEFAULT_ROOT, list_cities
from schemas import InputError
from schemas.bundle import BuildConfig
from schemas.export import SCHEMA_MODELS, json_schemas
from schemas.files import check_name, describe_os_error

console = Console(stderr=True)


def stdout() -> Console:
    """Console for results: the terminal's width, or 160 columns when piped (names stay whole)."""
    return Console(width=None if sys.stdout.isatty() else 160)


def command_line() -> str:
    return " ".join(shlex.quote(a) for a in [Path(sys.argv[0]).name, *sys.argv[1:]])


#: ``--root``: where ingested cities and bundles live (shared by uavdata and uavrl commands).
root_option = click.option(
    "--root",
    type=click.Path(file_okay=False, path_type=Path),
    default=DEFAULT_ROOT,
    show_default=True,
    help="Root of processed data.",
)


def fail(err: Exception | str) -> NoReturn:
    """Print one error line and exit with status 2."""
    text = describe_os_error(err) if isinstance(err, OSError) and not isinstance(err, InputError) else str(err)
    text = " ".join(text.split()) or type(err).__name__  # one line, whatever the message held
    console.print(f"[bold red]error:[/] {escape(text)}", highlight=False, soft_wrap=True)
    sys.exit(2)


class UavGroup(click.Group):
    """A click group whose every failure is one ``error: ...`` line and exit status 2, never a traceback.

    Bad input (``InputError``), usage errors, operating-system errors (a full
    disk, a permission) and, as a last resort, any other exception are caught
    here. ``UAVPLACE_DEBUG=1`` lets an unexpected exception through with its
    traceback, for bug reports.
    """

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):  # noqa: ANN001, ANN201
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.exceptions.Abort:
            fail("aborted")
        except click.UsageError as err:
            hint = f" (see '{err.ctx.command_path} --help')" if err.ctx is not None else ""
            fail(f"{err.format_message()}{hint}")
        except click.ClickException as err:
            fail(err.format_message())
        except InputError as err:
            fail(err)
        except OSError as err:
            fail(describe_os_error(err))
        except Exception as err:
            if os.environ.get("UAVPLACE_DEBUG"):
                raise
            fail(f"internal error ({type(err).__name__}: {err}); run again with UAVPLACE_DEBUG=1 for the traceback")
        if not standalone_mode:
            return rv
        sys.exit(rv if isinstance(rv, int) else 0)


def plain_table(*headers: str, **kwargs) -> Table:  # noqa: ANN003 - rich.table.Table's options
    """A rich table whose headers are text, not markup: units such as ``[m]`` stay visible."""
    table = Table(**kwargs)
    for header in headers:
        table.add_column(Text(header))
    return table


@click.group(cls=UavGroup, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="uavplace", prog_name="uavdata")
def main() -> None:
    """uavplace data pipeline: raw ray-tracer exports -> validated tables -> map bundles.

    \b
    Typical use on a new city:
      uavdata ingest data/raw/cityA/
      uavdata build --grid 4m --alt 10 --noise-dbm -68
    (-68 dBm of noise plus interference is the level the embedded cities and
    the shipped agents are calibrated at; see the README.)
    """


@main.command()
@click.argument("folders", nargs=-1, required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--out",
    "out_root",
    type=click.Path(file_okay=False, path_type=Path),
    default=DEFAULT_ROOT,
    show_default=True,
    help="Root of processed data; tables go to OUT/<city>/ingested/.",
)
@click.option("--name", default=None, help="City name (default: the folder's name; only with one FOLDER).")
@click.option("--quiet", is_flag=True, help="No progress bar and no per-file table; only the summary line.")
def ingest(folders: tuple[Path, ...], out_root: Path, name: str | None, quiet: bool) -> None:
    """Read every export in each city FOLDER, validate it and write tables (e.g. `uavdata ingest data/raw/*/`).

    Understands Wireless InSite receiver outputs (.p2m, .p2m.gz: power, pl,
    pg, txloss, spread, noise), .txrx, .setup, .city, .ter, GeoJSON footprints
    (.geojson) and meshes (.obj .ply .stl .glb .gltf). Per-path outputs
    (paths, doa, dod, cir, ...) are recognised and skipped; unknown files are
    listed as warnings. On any error nothing is written for that city and the exit status is 2.
    """
    if name is not None and len(folders) > 1:
        raise click.BadParameter("--name names one city: give one FOLDER", param_hint="--name")
    if name is not None:
        check_name(name, "city name")
    for folder in folders:
        _ingest_one(folder, out_root, name, quiet)


def _ingest_one(folder: Path, out_root: Path, name: str | None, quiet: bool) -> None:
    from ingest.pipeline import ingest_city

    with Progress(
        TextColumn("[bold]ingest[/] {task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        disable=quiet,
        transient=True,
    ) as progress:
        task = progress.add_task(str(folder), total=None)

        def on_file(rel: str, total: int) -> None:
            progress.update(task, description=rel, total=total, advance=1)

        out_dir, manifest, report = ingest_city(folder, out_root, name=name, command=command_line(), on_file=on_file)
    out = stdout()
    if not quiet:
        table = plain_table("file", "kind", "status", "rows", "rejected", "note", title=f"{manifest.name}: files")
        for f in report.files:  # file names and notes are the user's text, not markup
            table.add_row(*map(Text, (f.path, f.kind, f.status, str(f.rows_read), str(f.rows_rejected), f.message or "")))
        out.print(table)
        for w in report.warnings:
            console.print(f"[yellow]warning:[/] {w}", highlight=False, soft_wrap=True)
    c = manifest.counts
    out.print(
        f"ingested {manifest.name}: {c['files']} files ({c['files_parsed']} parsed, {c['files_skipped']} skipped, "
        f"{c['files_unknown']} unknown), {c['transmitters']} users, {c['receiver_rows']} receiver rows "
        f"({c['receiver_rows_reached']} reached), {c['buildings']} buildings, {c['rows_rejected']} rows rejected "
        f"-> {out_dir}",
        highlight=False,
        soft_wrap=True,
    )


@main.command()
@click.argument("model", required=False, type=click.Choice(sorted(SCHEMA_MODELS)))
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Write one <name>.schema.json per contract into this folder instead of printing.",
)
def schema(model: str | None, out_dir: Path | None) -> None:
    """Print the JSON schema of the contracts (all, or MODEL), so other tools can validate our outputs.

    Table contracts (receivers, transmitters, buildings, building_parts) come
    as the JSON schema of one row, with units and descriptions per column.
    """
    out = stdout()
    schemas = json_schemas()
    if model:
        schemas = {model: schemas[model]}
    if out_dir is None:
        out.print_json(json.dumps(schemas if not model else schemas[model]))
        return
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, s in schemas.items():
        (out_dir / f"{name}.schema.json").write_text(json.dumps(s, indent=2) + "\n", encoding="utf-8")
    out.print(f"wrote {len(schemas)} schema(s) to {out_dir}")


class Metres(click.ParamType):
    """A length in metres: ``4``, ``4m`` or ``2.5 m``."""

    name = "metres"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201 - click's signature
        if isinstance(value, float | int):
            return float(value)
        text = str(value).strip().lower().removesuffix("m").strip()
        try:
            return float(text)
        except ValueError:
            self.fail(f"{value!r} is not a length in metres (e.g. 4m, 2.5)", param, ctx)


class Bounds(click.ParamType):
    """``auto``, ``receivers``, ``buildings`` or ``XMIN,YMIN,XMAX,YMAX`` in metres."""

    name = "bounds"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201 - click's signature
        if value in ("auto", "receivers", "buildings") or isinstance(value, tuple):
            return value
        try:
            box = tuple(float(v) for v in str(value).split(","))
        except ValueError:
            box = ()
        if len(box) != 4:
            self.fail(f"{value!r}: expected auto, receivers, buildings or XMIN,YMIN,XMAX,YMAX", param, ctx)
        return box


def _splits(values: tuple[str, ...]) -> dict[str, str]:
    out = {}
    for v in values:
        city, sep, role = v.partition("=")
        if not sep or role not in ("train", "val", "test"):
            raise click.BadParameter(f"{v!r}: expected CITY=train, CITY=val or CITY=test", param_hint="--split")
        out[city] = role
    return out


@main.command()
@click.option("--grid", "grid_m", type=Metres(), default="4m", show_default=True, help="Grid spacing of the maps (e.g. 4m).")
@click.option(
    "--alt",
    "altitude_m",
    type=Metres(),
    default="10m",
    show_default=True,
    help="UAV altitude above ground; the receivers at this height (terrain taken into account) make the SINR maps.",
)
@click.option(
    "--alt-tol",
    "altitude_tol_m",
    type=Metres(),
    default="0.5m",
    show_default=True,
    help="Receivers within this distance of the altitude are used.",
)
@click.option("--city", "cities", multiple=True, help="Build only this ingested city (repeatable; default: all).")
@click.option(
    "--noise-dbm",
    type=float,
    default=-104.0,
    show_default=True,
    help="Noise plus background interference power [dBm] (the paper's combined -104 dBm; the embedded "
    "cities are calibrated at -68 dBm, see the README).",
)
@click.option(
    "--interference-std-db",
    type=float,
    default=0.0,
    show_default=True,
    help="Std [dB] of a Gaussian per-cell offset of the noise+interference level (0: none).",
)
@click.option(
    "--tx-dbm",
    type=float,
    default=None,
    help="User transmit power [dBm]: needed when the export has path loss/gain and no power; "
    "else it overrides the export's (received power shifts with it).",
)
@click.option(
    "--sinr-floor-db",
    type=float,
    default=-40.0,
    show_default=True,
    help="SINR given to dead cells (no ray-traced path) and lowest SINR reported anywhere [dB].",
)
@click.option(
    "--bounds",
    type=Bounds(),
    default="auto",
    show_default=True,
    help="Grid extent: auto (the receiver grid; receivers and buildings when the receivers are points), "
    "receivers, buildings (buildings and receivers), or XMIN,YMIN,XMAX,YMAX [m].",
)
@click.option("--crop", is_flag=True, help="Drop buildings wholly outside the grid (counted in the manifest) instead of failing.")
@click.option(
    "--split",
    "splits",
    multiple=True,
    metavar="CITY=ROLE",
    help="Declare a city's role: train, val (a validation city: all its users select checkpoints) or test "
    "(repeatable). Recorded in the bundle.",
)
@click.option(
    "--val-users",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Users of each train city held out for validation (seeded).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the interference draw and of the user split.")
@click.option(
    "--p-t-db",
    type=float,
    default=5.0,
    show_default=True,
    help="SINR target the manifest's difficulty figures (targets, BFS steps) are computed at [dB].",
)
@click.option("--force", is_flag=True, help="Rebuild even if an identical bundle exists.")
@root_option
@click.option("--quiet", is_flag=True, help="Only the summary lines.")
def build(
    grid_m: float,
    altitude_m: float,
    altitude_tol_m: float,
    cities: tuple[str, ...],
    noise_dbm: float,
    interference_std_db: float,
    tx_dbm: float | None,
    sinr_floor_db: float,
    bounds,
    crop: bool,
    splits: tuple[str, ...],
    val_users: int,
    seed: int,
    p_t_db: float,
    force: bool,
    root: Path,
    quiet: bool,
) -> None:
    """Rasterise ingested cities into versioned map bundles under ROOT/<city>/<version>/.

    \b
    A bundle holds maps.npz (height map, blocked mask, per-user SINR and dead
    masks), cells.parquet (the same as a long table), users.parquet and
    manifest.json (every parameter, counts, sha256 of inputs and files). The
    version is a hash of the inputs and these options: rebuilding unchanged
    inputs does nothing. ROOT/<city>/latest names the newest build.
    SINR = received power - (noise + interference), averaged over receivers in
    the linear domain; the export's own SINR is used when it has one.
    """
    from dataset.build import build_city

    role = _splits(splits)
    for city in cities:
        check_name(city, "city name")
    names = list(cities) or [c.name for c in list_cities(root)]
    if not names:
        fail(InputError(root, "no ingested city: run `uavdata ingest data/raw/<city>/` first"))
    unknown = sorted(set(role) - set(names))
    if unknown:
        raise click.BadParameter(f"cities {unknown} are not being built", param_hint="--split")
    out = stdout()
    errors = 0
    for name in names:
        try:
            config = BuildConfig(
                grid_m=grid_m,
                altitude_m=altitude_m,
                altitude_tol_m=altitude_tol_m,
                noise_dbm=noise_dbm,
                interference_std_db=interference_std_db,
                seed=seed,
                sinr_floor_db=sinr_floor_db,
                tx_dbm=tx_dbm,
                bounds=bounds,
                crop=crop,
                role=role.get(name),
                val_users=val_users if role.get(name) == "train" else 0,
                p_t_db=p_t_db,
            )
        except ValueError as exc:
            raise click.BadParameter(str(exc)) from None
        try:
            with console.status(f"[bold]build[/] {name}", spinner="dots") if not quiet else contextlib.nullcontext() as status:

                def on_stage(stage: str, name: str = name, status=status) -> None:
                    if status is not None:
                        status.update(f"[bold]build[/] {name}: {stage}")

                result = build_city(name, config, root, command=command_line(), force=force, on_stage=on_stage)
        except InputError as err:
            console.print(f"[bold red]error:[/] {escape(name)}: {escape(str(err))}", highlight=False, soft_wrap=True)
            errors += 1
            continue
        m = result.manifest
        if not quiet:
            for w in m.warnings:
                console.print(f"[yellow]warning:[/] {name}: {w}", highlight=False, soft_wrap=True)
        what = "built" if result.built else "up to date (nothing to do)"
        out.print(
            f"{what} {name}@{m.version}: {m.grid.num_x} x {m.grid.num_y} cells of {m.grid.spacing_m:g} m at "
            f"{m.config.altitude_m:g} m, {m.num_users} users, SINR from {m.sinr.source}, "
            f"{m.counts['blocked_cells']} blocked cells, {m.counts['dead_cells']} dead user-cells -> {result.path}",
            highlight=False,
            soft_wrap=True,
        )
        out.print(f"  difficulty: {format_difficulty(m.difficulty)}", highlight=False, soft_wrap=True)
        if result.previous_latest is not None:
            out.print(
                f"  latest: {name} now means {name}@{m.version} (it was {name}@{result.previous_latest}); "
                f"to keep using the other, name it: --dataset {name}@{result.previous_latest}",
                highlight=False,
                soft_wrap=True,
            )
    if errors:
        sys.exit(2)


def format_difficulty(d: dict[str, float | None]) -> str:
    def pct(v: float | None) -> str:
        return "-" if v is None else f"{100 * v:.1f} %"

    def num(v: float | None) -> str:
        return "-" if v is None else f"{v:g}"

    return (
        f"at P_T {d['p_t_db']:g} dB: {pct(d['target_share'])} of legal cells are targets, {pct(d['dead_share'])} dead; "
        f"BFS steps to a target from {int(d['num_starts'] or 0)} starts: median {num(d['bfs_median_steps'])}, "
        f"mean {num(d['bfs_mean_steps'])}; {pct(d.get('excluded_start_share'))} of start cells excluded "
        "(no reachable target)"
    )


def _size(path: Path) -> str:
    total = sum(p.stat().st_size for p in path.iterdir() if p.is_file())
    return f"{total / 1e6:.1f} MB"


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
        return (x, y)


@main.command()
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
@click.option(
    "--ray-address",
    default=None,
    help="Ray cluster to run a corpus on (e.g. ray://head:10001, or auto); default: a local Ray on this machine.",
)
@click.option(
    "--cpus-per-city",
    type=click.FloatRange(min=0.5),
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
@click.option("--freq", "frequency_hz", type=float, default=800e6, show_default=True, help="Carrier frequency [Hz].")
@click.option("--tx-dbm", type=float, default=20.0, show_default=True, help="User transmit power [dBm].")
@click.option("--samples", type=float, default=1e6, show_default=True, help="Rays per user (Sionna samples_per_tx).")
@click.option("--depth", type=click.IntRange(min=0), default=5, show_default=True, help="Maximum interactions per path.")
@click.option("--no-diffraction", is_flag=True, help="Switch edge diffraction off (faster, more dead cells).")
@click.option(
    "--gap-fill",
    default="4,16",
    show_default=True,
    help="Coarser maps (cell x factor, same samples) whose cells fill Monte Carlo gaps of the grid; "
    "'none' to keep gaps as unreached.",
)
@click.option(
    "--gap-fill-method",
    type=click.Choice(["smooth", "parent"]),
    default="smooth",
    show_default=True,
    help="smooth: a gap takes the level of the coarse map and the variation of its nearest hit cells, never across "
    "a building; parent: the coarse cell's mean, copied (the first version: 4 x 4 and 16 x 16 mosaics).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the city generator, the users and the ray sampler.")
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
    grid_m: float,
    altitude_m: float,
    extent,
    crop,
    frequency_hz: float,
    tx_dbm: float,
    samples: float,
    depth: int,
    no_diffraction: bool,
    gap_fill: str,
    gap_fill_method: str,
    seed: int,
    quiet: bool,
) -> None:
    """Ray-trace cities with Sionna RT and write each as Wireless InSite exports in OUT/<name>/.

    \b
    SOURCE is one of:
      procedural:train|test|tiny   the original generator (552 x 500, 400 x 500, 96 x 80 m)
      procedural:STYLE[:WxH]       generator v2: grid, rotated, perimeter, towers, organic,
                                   plazas, or mixed (a style drawn from the seed); 400 x 400 m
      an InSite .city, a GeoJSON of footprints (OpenStreetMap heights and levels understood)
      a Mitsuba .xml scene with its PLY/OBJ meshes, or sionna:etoile, sionna:florence (the
      scenes Sionna RT ships): a building per connected body, no ground, roofs in height tiers
    Several SOURCEs, or --count N, make a corpus (OUT/<name>-000/, ...), traced as Ray
    tasks on a local Ray (or --ray-address); cities already done with the same settings
    are skipped, so running the command again resumes it.
    Each city gets <name>.txrx (users and the receiver grid), <name>.setup, <name>.city,
    one <name>.power.tNNN_01.r002.p2m.gz per user and simulation.json (every parameter,
    package versions, materials, wall time). Then: uavdata ingest OUT/<name>/ && uavdata build.
    Needs the raytrace extra: pip install -e '.[raytrace]' (CPU: libllvm19).
    """
    from simulate.corpus import corpus_specs
    from simulate.pipeline import SimulationSpec, simulate_city
    from simulate.raytrace import RayTraceConfig

    check_name(name, "city name")
    for value, hint in ((extent, "--extent"), (crop, "--crop")):
        if isinstance(value, str):
            raise click.BadParameter("expected XMIN,YMIN,XMAX,YMAX", param_hint=hint)
    base = SimulationSpec(source=sources[0], name=name, num_users=len(users_m) or num_users, grid_m=grid_m, altitude_m=altitude_m,
                          tx_dbm=tx_dbm, seed=seed, extent_m=extent, users_m=tuple(users_m), crop_m=crop)  # fmt: skip
    specs = corpus_specs(list(sources), name, count, base)
    try:
        factors = () if gap_fill == "none" else tuple(int(f) for f in gap_fill.split(","))
    except ValueError:
        raise click.BadParameter(f"{gap_fill!r}: expected factors like 4,16, or none", param_hint="--gap-fill") from None
    if any(f < 2 for f in factors):
        raise click.BadParameter("factors must be >= 2", param_hint="--gap-fill")
    rt = RayTraceConfig(
        frequency_hz=frequency_hz,
        samples_per_tx=int(samples),
        max_depth=depth,
        diffraction=not no_diffraction,
        seed=seed,
        gap_fill_factors=factors,
        gap_fill_method=gap_fill_method,
    )
    if len(specs) > 1 or ray_address is not None:
        _simulate_corpus(specs, rt, out_root, ray_address, cpus_per_city, quiet)
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

            folder, record = simulate_city(specs[0], rt, out_root, command=command_line(), on_progress=on_progress)
    except RuntimeError as err:  # Sionna RT missing or its child process failed
        fail(err)
    g = record["grid"]
    stdout().print(
        f"simulated {name}: {record['geometry']}, {len(record['users_m'])} users, "
        f"grid {g['num_x']} x {g['num_y']} at {g['spacing_m']:g} m and {g['altitude_m']:g} m, "
        f"{100 * record['unreached_cell_share']:.1f} % of user-cells unreached "
        f"({100 * record['gap_filled_cell_share']:.1f} % Monte Carlo gaps filled), ray tracing {record['raytrace_seconds']:.1f} s "
        f"(wall {record['wall_seconds']:.1f} s) -> {folder}",
        highlight=False,
        soft_wrap=True,
    )


def _simulate_corpus(specs, rt, out_root: Path, address: str | None, cpus_per_city: float, quiet: bool) -> None:  # noqa: ANN001
    """Several cities as Ray tasks, one progress bar (a line per city when not on a terminal), resumable."""
    from simulate.corpus import simulate_corpus

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
                                            cpus_per_city=cpus_per_city, on_city=on_city)  # fmt: skip
        except RuntimeError as err:
            fail(err)
    out.print(
        f"simulated {len(done)} of {len(specs)} cities into {out_root}"
        + (f"; {len(skipped)} already done with the same settings: {', '.join(skipped)}" if skipped else ""),
        highlight=False,
        soft_wrap=True,
    )


@main.command(name="list")
@root_option
def list_(root: Path) -> None:
    """List ingested cities and their bundles (versions, grid, altitude, users, size) under ROOT."""
    from dataset.bundle import list_versions, read_latest

    out = stdout()
    cities = list_cities(root)  # bad input: one error line from UavGroup
    if not cities:
        out.print(f"no ingested city under {root} (run `uavdata ingest data/raw/<city>/`)")
        return
    table = plain_table(
        "city", "users", "receiver rows", "reached", "buildings", "frequency [MHz]", "ingested (UTC)", title="ingested"
    )
    bundles = plain_table(
        "city",
        "version",
        "grid [m]",
        "alt [m]",
        "cells",
        "users",
        "split",
        "SINR from",
        "size",
        "built (UTC)",
        title="bundles (* latest)",
    )
    for c in cities:
        k = c.manifest.counts
        f = c.manifest.frequency_hz
        table.add_row(
            c.name,
            str(k["transmitters"]),
            str(k["receiver_rows"]),
            str(k["receiver_rows_reached"]),
            str(k["buildings"]),
            f"{f / 1e6:g}" if f else "-",
            c.manifest.created_utc,
        )
        latest = read_latest(c.name, root)
        for m in list_versions(c.name, root):
            role = m.config.role or "-"
            split = ", ".join(f"{v} {k}" for k, v in m.split.items() if v) if m.config.role else "-"
            bundles.add_row(
                c.name,
                m.version + (" *" if m.version == latest else ""),
                f"{m.grid.spacing_m:g}",
                f"{m.config.altitude_m:g}",
                f"{m.grid.num_x} x {m.grid.num_y}",
                str(m.num_users),
                f"{role} ({split})" if m.config.role else "-",
                m.sinr.source,
                _size(c.path / m.version),
                m.created_utc,
            )
    out.print(table)
    if bundles.row_count:
        out.print(bundles)
    else:
        out.print("no bundle yet: run `uavdata build --grid 4m --alt 10`")


@main.command()
@click.argument("city")
@click.option("--version", default=None, help="Bundle version (default: the city's latest). CITY@VERSION works too.")
@click.option("--user", type=click.IntRange(min=0), default=0, show_default=True, help="User whose SINR map is drawn.")
@click.option(
    "--out",
    "out_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="PNG to write (default: reports/show/<city>-<version>-user<N>.png).",
)
@root_option
def show(city: str, version: str | None, user: int, out_path: Path | None, root: Path) -> None:
    """Render a bundle's height map and one user's SINR map to a PNG."""
    from dataset.bundle import load_bundle
    from dataset.preview import render_bundle

    bundle = load_bundle(city, version, root)
    if user >= bundle.num_users:
        raise click.BadParameter(f"the bundle has {bundle.num_users} users (0..{bundle.num_users - 1})", param_hint="--user")
    out_path = out_path or Path("reports") / "show" / f"{bundle.city}-{bundle.version}-user{user}.png"
    path = render_bundle(bundle, user, out_path)
    stdout().print(f"wrote {path}", highlight=False, soft_wrap=True)


if __name__ == "__main__":
    main()

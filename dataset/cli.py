"""``uavdata build``, ``list``, ``show``, ``pack`` and ``export``: versioned map bundles from ingested cities, their compact training maps, and the radio-map community's formats (registered in ``uavplace.cli``)."""

from __future__ import annotations

import contextlib
import re
import sys
from pathlib import Path

import click
from pydantic import ValidationError
from rich.markup import escape

from uavplace.dataset.catalog import ROLES_FILE, list_cities
from uavplace.infra.console import (
    Bounds,
    command_line,
    console,
    fail,
    folder_option,
    keep_whole,
    path_option,
    plain_table,
    root_option,
    say,
    stdout,
)
from uavplace.infra.files import check_name
from uavplace.infra.options import model_options
from uavplace.schemas import InputError
from uavplace.schemas.base import validation_message
from uavplace.schemas.bundle import BuildConfig, CityRoles


def _splits(values: tuple[str, ...]) -> dict[str, str | None]:
    """``--split`` values as ``{city: role}`` (``none``: no role, None)."""
    out: dict[str, str | None] = {}
    for v in values:
        city, sep, role = v.partition("=")
        if not sep or role not in ("train", "val", "test", "none"):
            raise click.BadParameter(f"{v!r}: expected CITY=train, CITY=val, CITY=test or CITY=none", param_hint="--split")
        out[city] = None if role == "none" else role
    return out


def _say_built(out, name: str, result) -> None:  # noqa: ANN001 - a rich Console and a BuildResult
    """What ``uavdata build`` made of city ``name``: the bundle, its difficulty, and where ``latest`` moved."""
    m = result.manifest
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


@click.command()
@model_options(
    BuildConfig,
    "grid_m",
    names={"grid_m": "--grid"},
    unset={
        "grid_m": "each city's receiver-grid spacing from its .txrx; a city of point receivers, or of grids of "
        "several spacings, needs it given"
    },
)
@model_options(BuildConfig, "altitude_m", "altitude_tol_m", names={"altitude_m": "--alt", "altitude_tol_m": "--alt-tol"})
@click.option("--city", "cities", multiple=True, help="Build only this ingested city (repeatable; default: all).")
@model_options(
    BuildConfig, "noise_dbm", "interference_std_db", "tx_dbm", "sinr_floor_db", "bounds", "crop", bounds={"type": Bounds()}
)
@click.option(
    "--crop-city",
    "crop_cities",
    multiple=True,
    metavar="CITY",
    help="--crop for this city only (repeatable): a city whose receiver grid covers part of its scene by design, as "
    "`uavdata simulate --extent` makes one; the others keep the check.",
)
@click.option(
    "--split",
    "splits",
    multiple=True,
    metavar="CITY=ROLE",
    help="Declare a city's role: train, val (a validation city: all its users select checkpoints), test, or none "
    "(repeatable; overrides --roles). Recorded in the bundle. A city whose latest bundle has a role must be given "
    "one again, here or in --roles (a build without it would drop the role).",
)
@path_option(
    "--roles",
    "roles_file",
    folder=False,
    default=Path("data/raw") / ROLES_FILE,
    help="The cities' roles, declared beside the data (TOML: train, val, test and crop lists of city names, and "
    "val_users; schemas/bundle.py, CityRoles; the embedded cities': data/raw/cities.toml). Applied to the cities "
    "built; --split, --crop-city and --val-users override it. Skipped when the default file is absent.",
)
@model_options(CityRoles, "val_users", unset={"val_users": "the roles file's val_users for the train cities it lists, else 0"})
@model_options(BuildConfig, "seed", "p_t_db")
@click.option("--force", is_flag=True, help="Rebuild even if an identical bundle exists.")
@root_option
@click.option("--quiet", is_flag=True, help="Only the summary lines.")
def build(
    grid_m: float | None,
    cities: tuple[str, ...],
    crop_cities: tuple[str, ...],
    splits: tuple[str, ...],
    roles_file: Path,
    val_users: int | None,
    force: bool,
    root: Path,
    quiet: bool,
    **fields: object,
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
    from uavplace.dataset.build import build_city
    from uavplace.dataset.catalog import export_spacing
    from uavplace.dataset.roles import plan_builds

    default_roles = Path("data/raw") / ROLES_FILE  # skipped when absent
    try:
        plans = plan_builds(
            cities,
            root,
            roles=_splits(splits),
            crop_cities=crop_cities,
            roles_file=None if roles_file == default_roles and not roles_file.exists() else roles_file,
            val_users=val_users,
        )
    except InputError as err:
        fail(err)
    out = stdout()
    errors = 0
    warned: list[tuple[str, str]] = []
    for plan in plans:
        name = plan.city
        try:
            grid = grid_m if grid_m is not None else export_spacing(name, root)
        except InputError as err:
            console.print(f"[bold red]error:[/] {escape(name)}: {escape(str(err))}", highlight=False, soft_wrap=True)
            errors += 1
            continue
        try:
            declared = {"crop": fields["crop"] or plan.crop, "role": plan.role, "val_users": plan.val_users}
            config = BuildConfig(**(fields | declared), grid_m=grid)
        except ValidationError as exc:
            field, message = validation_message(exc)
            raise click.BadParameter(f"{message} (got {exc.errors()[0].get('input')!r})", param_hint=field) from None
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
        warned += [(name, w) for w in result.manifest.warnings]
        _say_built(out, name, result)
    if not quiet:
        for line in warning_lines(warned):
            console.print(f"[yellow]warning:[/] {escape(line)}", highlight=False, soft_wrap=True)
    if errors:
        sys.exit(2)


def warning_lines(warned: list[tuple[str, str]]) -> list[str]:
    """The build's warnings (city, text), one line per kind: a kind is the text less its numbers and the ids it
    lists; a kind met in several cities is one line, its first city's text, then the others with their counts."""

    def kind(text: str) -> str:
        text = re.sub(r"\[[^\]]*\]|\([^)]*building_[^)]*\)", "", text)  # the ids and names it lists
        return re.sub(r"\d+(\.\d+)?", "#", text)

    groups: dict[str, list[tuple[str, str]]] = {}
    for city, text in warned:
        groups.setdefault(kind(text), []).append((city, text))
    lines = []
    for members in groups.values():
        (city, text), others = members[0], members[1:]
        line = f"{city}: {text}"
        if others:
            counts = ", ".join(f"{c} ({_first_number(t)})" for c, t in others)
            line += f"; the same in {len(others)} more {'city' if len(others) == 1 else 'cities'}: {counts}"
        lines.append(line)
    return lines


def _first_number(text: str) -> str:
    found = re.search(r"\d+", text)
    return found.group() if found else "-"


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


def list_tables(cities: list, root: Path) -> tuple:  # noqa: ANN001 - CityEntry rows and two rich Tables
    """``uavdata list``'s two tables, ingested cities and bundles, their names and versions never cut (a version is
    what ``--dataset city@version`` needs): the other columns give way in a narrow terminal."""
    from uavplace.dataset.roles import BUNDLE_COLUMNS, INGESTED_COLUMNS, bundle_rows, ingested_row

    ingested = plain_table(*INGESTED_COLUMNS, rows=[ingested_row(c) for c in cities], title="ingested")
    rows = [row for c in cities for row in bundle_rows(c, root)]
    bundles = plain_table(*BUNDLE_COLUMNS, rows=rows, title="bundles (* latest)")
    return keep_whole(ingested, "city"), keep_whole(bundles, "city", "version")


@click.command(name="list")
@root_option
@click.option(
    "--table",
    is_flag=True,
    help="Instead, one Markdown table of the built cities (each one's latest bundle): source, size, buildings, users, "
    "role, blocked, target and dead shares, the genie's median steps, and how faithful the maps are (constant 4 x 4 "
    "patches, dead/live boundaries and SINR steps on the 64 m and 16 m lines of a coarse gap fill; dataset/corpus.py).",
)
@path_option(
    "--raw",
    folder=True,
    default=Path("data/raw"),
    help="With --table: where each city's raw folder (its simulation.json: source and building tiers) is.",
)
def list_(root: Path, table: bool, raw: Path) -> None:
    """List ingested cities and their bundles (versions, grid, altitude, users, size) under ROOT."""
    out = stdout()
    if table:
        from uavplace.dataset.corpus import corpus_rows
        from uavplace.infra.console import markdown_table

        click.echo(markdown_table(corpus_rows(root, raw)))
        return
    cities = list_cities(root)  # bad input: one error line from UavGroup
    if not cities:
        out.print(f"no ingested city under {root} (run `uavdata ingest data/raw/<city>/`)")
        return
    ingested, bundles = list_tables(cities, root)
    out.print(ingested)
    if bundles.row_count:
        out.print(bundles)
    else:
        out.print("no bundle yet: run `uavdata build --grid 4m --alt 10`")


@click.command()
@click.argument("city")
@click.option("--version", default=None, help="Bundle version (default: the city's latest). CITY@VERSION works too.")
@click.option("--user", type=click.IntRange(min=0), default=0, show_default=True, help="User whose SINR map is drawn.")
@path_option(
    "--out",
    "out_path",
    folder=False,
    help="PNG to write (default: reports/show/<city>-<version>-user<N>.png).",
)
@root_option
def show(city: str, version: str | None, user: int, out_path: Path | None, root: Path) -> None:
    """Render a bundle's height map and one user's SINR map to a PNG.

    The SINR map's estimated cells, whose value was not traced at the cell itself (straight path, walked, coarse map,
    not recorded, nearest receiver: schemas/provenance.py, docs/simulate.md "Provenance"), are hatched, a hatch per kind
    with its share of the open cells in the legend."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.dataset.preview import render_bundle

    bundle = load_bundle(city, version, root)
    if user >= bundle.num_users:
        raise click.BadParameter(f"the bundle has {bundle.num_users} users (0..{bundle.num_users - 1})", param_hint="--user")
    out_path = out_path or Path("reports") / "show" / f"{bundle.city}-{bundle.version}-user{user}.png"
    path = render_bundle(bundle, user, out_path)
    say(f"wrote {path}")


@click.command()
@click.argument("cities", metavar="CITY...", nargs=-1, required=True)
@root_option
@folder_option(
    "--raw", "data/raw", "Where each city's raw folder is: its simulation.json (seed and ray-trace settings) goes into the pack."
)
@folder_option(
    "--out",
    "data/trainmaps",
    "Folder of packs: one <city>.npz each (a regular file or absent; written to a temporary file, then renamed).",
)
def pack(cities: tuple[str, ...], root: Path, raw: Path, out: Path) -> None:
    """Pack built cities' maps into the compact training-maps form the predictor trains on (dataset/trainmaps.py):
    building heights, the users' cells, each user's SINR to 0.5 dB (dead cells apart) and its provenance, about
    3-8 kB a user (6 kB the median of data/trainmaps/). A CITY whose pack holds what packing its bundle now gives, byte for byte (meta included), is left as it is."""
    from uavplace.dataset.bundle import load_bundle
    from uavplace.dataset.trainmaps import TrainingMaps, pack_bytes, simulation_record, write_pack
    from uavplace.infra.limits import limits

    out_ = stdout()
    total_users = total_bytes = 0
    for city in cities:
        check_name(city, "city name")
        bundle = load_bundle(city, root=root)
        path = out / f"{city}.npz"
        maps, simulation = TrainingMaps.of_bundle(bundle), simulation_record(raw / city)
        if path.is_file() and not path.is_symlink() and path.stat().st_size < limits().map_bytes:
            # packed already only when its bytes are the pack this bundle makes (meta included): an edited, damaged
            # or older pack is packed again
            if path.read_bytes() == pack_bytes(maps, simulation)[0]:
                out_.print(f"{city}: packed already from bundle {bundle.version}", highlight=False)
                continue
        meta = write_pack(path, maps, simulation)
        size = path.stat().st_size
        total_users, total_bytes = total_users + meta.num_users, total_bytes + size
        out_.print(
            f"{city}: {meta.num_users} users, {size / 1e3:.0f} kB ({size / meta.num_users / 1e3:.1f} kB a user), "
            f"{meta.clipped_cells} cells clipped -> {path}",
            highlight=False,
            soft_wrap=True,
        )
    out_.print(f"packed {total_users} users into {total_bytes / 1e6:.1f} MB under {out}", highlight=False)


@click.command()
@click.argument("cities", metavar="CITY...", nargs=-1, required=True)
@click.option(
    "--format",
    "formats",
    type=click.Choice(["radiomapseer", "deepmimo"]),
    multiple=True,
    default=("radiomapseer", "deepmimo"),
    show_default=True,
    help="radiomapseer: OUT/<city>/ with the building map and one radio map per user as PNG (a documented dB scale, "
    "scale.json) and the users' positions as CSV; deepmimo: OUT/<city>.deepmimo.npz, per user its position and "
    "each cell's received power, path loss and SINR (dataset/export.py documents both, units and frames).",
)
@root_option
@folder_option("--out", "exports", "Folder of the exports (a RadioMapSeer-style folder is replaced only if it is one).")
def export(cities: tuple[str, ...], formats: tuple[str, ...], root: Path, out: Path) -> None:
    """Write built cities in the formats of the radio-map community: RadioMapSeer-style folders (PNG maps) and
    DeepMIMO-style array files."""
    from uavplace.dataset.bundle import load_bundle, resolve
    from uavplace.dataset.export import write_deepmimo, write_radiomapseer

    for city in cities:  # every city named is built here before the first is written
        resolve(city, root=root)
    for city in dict.fromkeys(cities):
        bundle = load_bundle(city, root=root)
        for fmt in dict.fromkeys(formats):
            path = write_radiomapseer(bundle, out) if fmt == "radiomapseer" else write_deepmimo(bundle, out)
            say(f"{city}: {fmt} -> {path}")

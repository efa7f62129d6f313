"""``uavdata ingest``: read, validate and tabulate a city's raw exports (registered in ``uavplace.cli``)."""

from __future__ import annotations

from pathlib import Path

import click
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.text import Text

from uavplace.infra.console import command_line, console, plain_table, stdout
from uavplace.infra.files import DEFAULT_ROOT, check_name


@click.command()
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
@click.option("--verbose", is_flag=True, help="Also a table of every file: kind, status, rows read and rejected, notes.")
@click.option("--quiet", is_flag=True, help="No progress bar; only the summary line per city (and any warning).")
def ingest(folders: tuple[Path, ...], out_root: Path, name: str | None, verbose: bool, quiet: bool) -> None:
    """Read every export in each city FOLDER, validate it and write tables: `uavdata ingest data/raw/*/` takes them all.

    Understands Wireless InSite receiver outputs (.p2m, .p2m.gz: power, pl,
    pg, txloss, spread, noise), .txrx, .setup, .city, .ter, GeoJSON footprints
    (.geojson) and meshes (.obj .ply .stl .glb .gltf). Per-path outputs
    (paths, doa, dod, cir, ...) are recognised and skipped; unknown files are
    listed as warnings. A RadioMapSeer-style folder (what `uavdata export`
    writes: scale.json, PNG maps, users.csv; ingest/radiomapseer.py) is read
    as a city too. On any error nothing is written for that city and the exit status is 2.
    """
    if name is not None and len(folders) > 1:
        raise click.BadParameter("--name names one city: give one FOLDER", param_hint="--name")
    if name is not None:
        check_name(name, "city name")
    seen: dict[str, Path] = {}
    for folder in folders:  # one city a name: the second folder of a name would replace the first's tables
        city = folder.resolve().name
        if city in seen:
            same = folder.resolve() == seen[city].resolve()
            raise click.UsageError(
                f"{folder} is given twice"
                if same
                else f"{seen[city]} and {folder} are both city '{city}': ingest them in two commands, one with --name"
            )
        seen[city] = folder
    for folder in folders:
        _ingest_one(folder, out_root, name, verbose, quiet)


def _ingest_one(folder: Path, out_root: Path, name: str | None, verbose: bool, quiet: bool) -> None:
    from uavplace.ingest.pipeline import ingest_city

    with Progress(
        TextColumn("[bold]ingest[/] {task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        disable=quiet or not console.is_terminal,  # a log gets the summary line only (no blank line per city)
        transient=True,
    ) as progress:
        task = progress.add_task(str(folder), total=None)

        def on_file(rel: str, total: int) -> None:
            progress.update(task, description=rel, total=total, advance=1)

        out_dir, manifest, report = ingest_city(folder, out_root, name=name, command=command_line(), on_file=on_file)
    out = stdout()
    if verbose:
        table = plain_table("file", "kind", "status", "rows", "rejected", "note", title=f"{manifest.name}: files")
        for f in report.files:  # file names and notes are the user's text, not markup
            table.add_row(*map(Text, (f.path, f.kind, f.status, str(f.rows_read), str(f.rows_rejected), f.message or "")))
        out.print(table)
    for w in report.warnings:  # never hidden: a warning is something the user has to see
        console.print(Text.assemble(("warning:", "yellow"), f" {w}"), highlight=False, soft_wrap=True)  # w: the user's text
    c = manifest.counts
    out.print(
        f"ingested {manifest.name}: {c['files']} files ({c['files_parsed']} parsed, {c['files_skipped']} skipped, "
        f"{c['files_unknown']} unknown), {c['transmitters'] - c.get('route_points', 0)} users, "
        + (f"{c['route_points']} route points, " if c.get("route_points") else "")
        + f"{c['receiver_rows']} receiver rows "
        f"({c['receiver_rows_reached']} reached), {c['buildings']} buildings, {c['rows_rejected']} rows rejected "
        f"-> {out_dir}",
        highlight=False,
        soft_wrap=True,
    )

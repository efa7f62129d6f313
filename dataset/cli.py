"""``uavdata``: ingest raw ray-tracer exports (and, later stages, build map bundles)."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import click
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from dataset.catalog import DEFAULT_ROOT, list_cities
from ingest.pipeline import ingest_city
from schemas import InputError
from schemas.export import SCHEMA_MODELS, json_schemas

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


def fail(err: InputError) -> None:
    console.print(f"[bold red]error:[/] {err}", highlight=False, soft_wrap=True)
    sys.exit(2)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
def main() -> None:
    """uavplace data pipeline: raw ray-tracer exports -> validated tables -> map bundles.

    \b
    Typical use on a new city:
      uavdata ingest data/raw/cityA/
    """


@main.command()
@click.argument("folder", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--out",
    "out_root",
    type=click.Path(file_okay=False, path_type=Path),
    default=DEFAULT_ROOT,
    show_default=True,
    help="Root of processed data; tables go to OUT/<city>/ingested/.",
)
@click.option("--name", default=None, help="City name (default: the folder's name).")
@click.option("--quiet", is_flag=True, help="No progress bar and no per-file table; only the summary line.")
def ingest(folder: Path, out_root: Path, name: str | None, quiet: bool) -> None:
    """Read every export in FOLDER, validate it and write tables.

    Understands Wireless InSite receiver outputs (.p2m, .p2m.gz: power, pl,
    pg, txloss, spread, noise), .txrx, .setup, .city, .ter, GeoJSON footprints
    (.geojson) and meshes (.obj .ply .stl .glb .gltf). Per-path outputs
    (paths, doa, dod, cir, ...) are recognised and skipped; unknown files are
    listed as warnings. On any error nothing is written and the exit status is 2.
    """
    try:
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
    except InputError as err:
        fail(err)
        return
    out = stdout()
    if not quiet:
        table = Table("file", "kind", "status", "rows", "rejected", "note", title=f"{manifest.name}: files")
        for f in report.files:
            table.add_row(f.path, f.kind, f.status, str(f.rows_read), str(f.rows_rejected), f.message or "")
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


@main.command(name="list")
@root_option
def list_(root: Path) -> None:
    """List the ingested cities under ROOT with their users, receivers and buildings."""
    out = stdout()
    try:
        cities = list_cities(root)
    except InputError as err:
        fail(err)
        return
    if not cities:
        out.print(f"no ingested city under {root} (run `uavdata ingest data/raw/<city>/`)")
        return
    table = Table("city", "users", "receiver rows", "reached", "buildings", "frequency [MHz]", "ingested (UTC)")
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
    out.print(table)

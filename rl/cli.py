"""``uavrl``: train and evaluate UAV placement agents on map bundles built by ``uavdata``."""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Table

from dataset.bundle import list_versions, read_latest
from dataset.catalog import list_cities
from dataset.cli import root_option, stdout
from schemas import InputError


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
def main() -> None:
    """UAV placement agents: the datasets they can use, training and reports."""


@main.command()
@root_option
def datasets(root: Path) -> None:
    """List the built cities under ROOT that agents can be given (`--dataset NAME`), from their latest bundle."""
    out = stdout()
    try:
        cities = list_cities(root)
    except InputError as err:
        raise click.ClickException(str(err)) from None
    table = Table("dataset", "version", "grid [m]", "alt [m]", "cells", "users", "role", "train / val / test users")
    unbuilt = []
    for c in cities:
        latest = read_latest(c.name, root)
        m = next((m for m in list_versions(c.name, root) if m.version == latest), None)
        if m is None:
            unbuilt.append(c.name)
            continue
        s = m.split
        table.add_row(
            c.name, m.version, f"{m.grid.spacing_m:g}", f"{m.config.altitude_m:g}", f"{m.grid.num_x} x {m.grid.num_y}",
            str(m.num_users), m.config.role or "-", f"{s['train']} / {s['val']} / {s['test']}" if m.config.role else "-",
        )  # fmt: skip
    if table.row_count:
        out.print(table)
    else:
        out.print(f"no built city under {root}: run `uavdata ingest data/raw/<city>/` then `uavdata build`")
    if unbuilt:
        out.print(f"ingested but not built (run `uavdata build`): {', '.join(unbuilt)}")

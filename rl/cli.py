"""``uavrl``: train and evaluate UAV placement agents on cities prepared by ``uavdata``."""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Table

from dataset.catalog import list_cities
from dataset.cli import root_option, stdout
from schemas import InputError


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
def main() -> None:
    """UAV placement agents: the cities they can use, training and reports."""


@main.command()
@root_option
def datasets(root: Path) -> None:
    """List the cities under ROOT that agents can be given (`--dataset NAME`), with their users."""
    out = stdout()
    try:
        cities = list_cities(root)
    except InputError as err:
        raise click.ClickException(str(err)) from None
    if not cities:
        out.print(f"no city under {root}: run `uavdata ingest data/raw/<city>/` first")
        return
    table = Table("dataset", "users", "users with receiver data")
    for c in cities:
        users = {(r.tx_set_id, r.tx_point) for r in c.manifest.receiver_sets}
        table.add_row(c.name, str(c.manifest.counts["transmitters"]), str(len(users)))
    out.print(table)

"""What a build of ingested cities declares beside its settings: each city's role (train, val, test or none), crop and
held-out validation users, from the command line over the roles file beside the data (``CityRoles``); and the
cities and bundles under a root with their roles, as `uavdata list` shows them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from uavplace.dataset.bundle import list_versions, read_latest, read_manifest, resolve
from uavplace.dataset.catalog import CityEntry, list_cities, nearest_names, read_roles
from uavplace.infra.files import check_name
from uavplace.schemas import InputError


@dataclass(frozen=True)
class BuildPlan:
    """What a build of ``city`` declares beside its settings: its ``role`` (None: none), whether its receiver grid
    may cover part of its scene (``crop``), and the users of a train city held out for validation (``val_users``)."""

    city: str
    role: str | None
    crop: bool
    val_users: int


def plan_builds(
    cities: tuple[str, ...] | list[str],
    root: str | Path,
    *,
    roles: dict[str, str | None] | None = None,
    crop_cities: tuple[str, ...] = (),
    roles_file: str | Path | None = None,
    val_users: int | None = None,
) -> list[BuildPlan]:
    """The cities a build makes (``cities``, default every ingested one) with their roles: ``roles`` (``--split``)
    and ``crop_cities`` given, over those of the ``roles_file`` (``CityRoles``; None: none), whose ``val_users`` holds
    for its train cities unless ``val_users`` is given. ``InputError`` before anything is built: a city not
    ingested (with the nearest names), a role or crop given for a city not built, or a city whose latest bundle has a
    role this build would drop."""
    roles = dict(roles or {})
    for city in cities:
        check_name(city, "city name")
    ingested = [c.name for c in list_cities(root)]
    names = list(cities) or ingested
    if not names:
        raise InputError(root, "no ingested city: run `uavdata ingest data/raw/<city>/` first")
    for city in names:  # checked before anything is read: a mistyped name gets the nearest ones
        if city not in ingested:
            raise InputError(
                Path(root) / city, f"no ingested city of that name{nearest_names(city, ingested, 'ingested')}", field="city"
            )
    for field, given in (("split", roles), ("crop_city", crop_cities)):
        unknown = sorted(set(given) - set(names))
        if unknown:
            raise InputError(root, f"cities {unknown} are not being built", field=field)
    held_out = dict.fromkeys(names, 0 if val_users is None else val_users)  # validation users of each train city
    if roles_file is not None:  # the roles beside the data, for the cities built; the options win
        declared = read_roles(roles_file)
        roles = {n: declared.role_of(n) for n in names if declared.role_of(n) is not None} | roles
        crop_cities = (*crop_cities, *(n for n in declared.crop if n in names))
        if val_users is None:  # the file's val_users, for the train cities the file lists
            held_out |= {n: declared.val_users for n in declared.train if n in held_out}
    held = {n: r for n in names if n not in roles and (r := _latest_role(n, root)) is not None}
    if held:  # a build without their role would make new bundles without one and move `latest` to them
        raise InputError(
            root,
            f"{', '.join(f'{n} (a {r} city)' for n, r in held.items())}: the latest bundle has a role that "
            "this build would drop; name it again (--split CITY=ROLE, and --val-users for a train city), "
            "drop it with --split CITY=none, or build other cities with --city",
            field="split",
        )
    return [BuildPlan(n, roles.get(n), n in crop_cities, held_out[n] if roles.get(n) == "train" else 0) for n in names]


def _latest_role(city: str, root: str | Path) -> str | None:
    """The role of ``city``'s latest bundle (None: no role, or no bundle yet)."""
    try:
        return read_manifest(resolve(city, root=root)).config.role
    except InputError:
        return None


#: The columns of `uavdata list`'s two tables: the ingested cities (``ingested_row``) and their bundles (``bundle_rows``).
INGESTED_COLUMNS = ("city", "users", "receiver rows", "reached", "buildings", "frequency [MHz]", "ingested (UTC)")
BUNDLE_COLUMNS = ("city", "version", "grid [m]", "alt [m]", "cells", "users", "split", "SINR from", "size", "built (UTC)")


def _minute(utc: str) -> str:
    """An ISO time to the minute (the date, a space, hours:minutes): short enough for a narrow terminal's table."""
    return utc[:16].replace("T", " ")


def ingested_row(c: CityEntry) -> list[str]:
    """An ingested city as a row of ``INGESTED_COLUMNS``."""
    k, f = c.manifest.counts, c.manifest.frequency_hz
    counts = [str(k[n]) for n in ("transmitters", "receiver_rows", "receiver_rows_reached", "buildings")]
    return [c.name, *counts, f"{f / 1e6:g}" if f else "-", _minute(c.manifest.created_utc)]


def bundle_rows(c: CityEntry, root: str | Path) -> list[list[str]]:
    """Every bundle of ingested city ``c`` as a row of ``BUNDLE_COLUMNS`` (its latest marked ``*``; its role with the
    users of each split)."""
    latest, rows = read_latest(c.name, root), []
    for m in list_versions(c.name, root):
        split = ", ".join(f"{v} {k}" for k, v in m.split.items() if v)
        size = sum(p.stat().st_size for p in (c.path / m.version).iterdir() if p.is_file())
        rows.append(
            [c.name, m.version + (" *" if m.version == latest else ""), f"{m.grid.spacing_m:g}", f"{m.config.altitude_m:g}"]
            + [f"{m.grid.num_x} x {m.grid.num_y}", str(m.num_users), f"{m.config.role} ({split})" if m.config.role else "-"]
            + [m.sinr.source, f"{size / 1e6:.1f} MB", _minute(m.created_utc)]
        )
    return rows

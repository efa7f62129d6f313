"""Which cities development may look at: validation cities, and test cities only for a release.

The test cities (those built with ``--split CITY=test``) give release numbers, printed by
``uavrl report``; every development decision (a lever table, a failure analysis, a sweep) is
taken on validation cities. The development scripts in ``benchmarks/`` call
``development_cities``: without cities they take every built validation city, and they refuse a
test city unless ``--release`` is given.
"""

from __future__ import annotations

from pathlib import Path

from uavplace.dataset.bundle import read_latest, read_manifest, resolve
from uavplace.dataset.catalog import list_cities
from uavplace.schemas import InputError


def city_role(city: str, root: str | Path = "data/processed") -> str | None:
    """The role the city's latest bundle was built with (``train``, ``val``, ``test``), or None."""
    return read_manifest(resolve(city.split("@")[0], root=root)).config.role


def release_cities(root: str | Path = "data/processed", *, routes: bool = False) -> list[str]:
    """Every built city whose latest bundle has the test role, in name order: those with the tracking task's routes
    (``routes``) or those without. ``InputError`` when there is none."""
    found = []
    for c in list_cities(root):
        if read_latest(c.name, root) is None:
            continue
        manifest = read_manifest(resolve(c.name, root=root))
        if manifest.config.role == "test" and bool(manifest.num_route_points) == routes:
            found.append(c.name)
    if not found:
        kind = "with routes " if routes else ""
        raise InputError(
            root,
            f"no test city {kind}is built: build some with --split CITY=test (or in data/raw/cities.toml), "
            "or name one with --dataset",
            field="dataset",
        )
    return found


def development_cities(cities: list[str] | None, root: str | Path = "data/processed", *, release: bool = False) -> list[str]:
    """``cities``, checked: an ``InputError`` naming a test city unless ``release``; none given: every built city whose
    role is ``val`` (an ``InputError`` when there is none)."""
    if not cities:
        found = [c.name for c in list_cities(root) if read_latest(c.name, root) is not None and city_role(c.name, root) == "val"]
        if not found:
            raise InputError(root, "no validation city is built: build some with --split CITY=val", field="city")
        return found
    for city in cities:
        if city_role(city, root) == "test" and not release:
            raise InputError(
                city, "is a test city: its numbers are for a release (uavrl report); add --release to look", field="city"
            )
    return list(cities)

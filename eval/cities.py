"""Which cities development may look at: validation cities, and test cities only for a release.

The test cities (those built with ``--split CITY=test``) give release numbers, printed by
``uavrl report``; every development decision (a lever table, a failure analysis, a sweep) is
taken on validation cities. The development scripts in ``benchmarks/`` call
``development_cities``: without cities they take every built validation city, and they refuse a
test city unless ``--release`` is given.
"""

from __future__ import annotations

from pathlib import Path

from uavplace.dataset.bundle import load_bundle, read_latest
from uavplace.dataset.catalog import list_cities
from uavplace.schemas import InputError


def city_role(city: str, root: str | Path = "data/processed") -> str | None:
    """The role the city's latest bundle was built with (``train``, ``val``, ``test``), or None."""
    return load_bundle(city.split("@")[0], root=root).manifest.config.role


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

"""What cities are on disk under a processed-data root, read from their manifests."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pydantic import ValidationError

from uavplace.infra.files import DEFAULT_ROOT, check_name, in_corpus, read_model_toml, read_small_file
from uavplace.schemas import CityManifest, InputError
from uavplace.schemas.base import validation_message
from uavplace.schemas.bundle import CityRoles

INGESTED_MANIFEST = Path("ingested") / "manifest.json"


@dataclass(frozen=True)
class CityEntry:
    name: str
    path: Path
    manifest: CityManifest


def read_city_manifest(path: str | Path) -> CityManifest:
    path = Path(path)
    data = read_small_file(path, "an ingest manifest", missing="no such manifest (run `uavdata ingest` first)")
    try:
        return CityManifest.model_validate_json(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise InputError(path, "not UTF-8 text: not an ingest manifest") from None
    except ValidationError as exc:
        field, message = validation_message(exc)
        raise InputError(path, message, field=field) from None


def list_cities(root: str | Path = DEFAULT_ROOT) -> list[CityEntry]:
    """Every ingested city below ``root``, by name."""
    root = Path(root)
    if not root.is_dir():
        return []
    return [
        CityEntry(name=p.parent.parent.name, path=p.parent.parent, manifest=read_city_manifest(p))
        for p in sorted(root.glob(f"*/{INGESTED_MANIFEST.as_posix()}"))
    ]


def expand_datasets(names: list[str] | tuple[str, ...], root: str | Path = DEFAULT_ROOT) -> list[str]:
    """City names, with a corpus name replaced by its cities: ``corpus`` -> ``corpus-000``, ``corpus-001``...

    A name (or ``city@version``) is kept when a city of that name is ingested under ``root``; otherwise it must be the
    ``NAME`` of cities ``NAME-NNN`` (as ``uavdata simulate --count`` names them), else ``InputError``.
    Duplicates are dropped, the order kept.
    """
    cities = [c.name for c in list_cities(root)]
    out: list[str] = []
    for name in names:
        city, _, version = name.partition("@")
        check_name(city, "city name")
        if version:
            check_name(version, "bundle version")
        if city in cities:
            members = [name]
        else:
            members = [c for c in cities if in_corpus(c, name)]
            if not members:
                raise InputError(
                    Path(root) / name,
                    f"no ingested city or corpus of that name{nearest_names(city, cities, 'ingested')}",
                    field="dataset",
                )
        out += [m for m in members if m not in out]
    return out


def nearest_names(name: str, known: list[str], what: str = "built") -> str:
    """``: did you mean A or B?`` for the names of ``known`` nearest to a mistyped ``name`` (``; built: ...`` when none
    is near, ``; nothing is built ...`` when ``known`` is empty; ``what``: what ``known`` are)."""
    import difflib

    near = difflib.get_close_matches(name, known, n=3, cutoff=0.6)
    if near:
        return f": did you mean {' or '.join(near)}?"
    if not known:
        return f"; nothing is {what}: run `uavdata ingest` and `uavdata build` first"
    shown = ", ".join(known[:8]) + (f" and {len(known) - 8} more (`uavdata list`)" if len(known) > 8 else "")
    return f"; {what}: {shown}"


#: Where the roles of the cities of a data folder are declared (``CityRoles``): beside the cities' folders.
ROLES_FILE = "cities.toml"


def read_roles(path: str | Path) -> CityRoles:
    """A roles file (``CityRoles``, TOML); ``InputError`` naming the file and the field."""
    return read_model_toml(path, CityRoles, "a cities' roles file (TOML)", missing="no such roles file")


def export_spacing(city: str, root: str | Path) -> float:
    """The receiver-grid spacing of ``city``'s export (its .txrx grid sets, as ingest recorded them): the grid a
    build takes when ``--grid`` is not given. ``InputError`` when the city has no receiver grid or grids of several
    spacings."""
    manifest = read_city_manifest(Path(root) / city / INGESTED_MANIFEST)
    spacings = sorted({s.spacing_m for s in manifest.txrx_sets if s.kind == "grid" and s.is_receiver and s.spacing_m})
    if len(spacings) != 1:
        found = "no receiver grid" if not spacings else f"receiver grids of {', '.join(f'{v:g}' for v in spacings)} m"
        raise InputError(Path(root) / city, f"{found} in its .txrx: give the grid spacing (--grid 4m)", field="grid")
    return float(spacings[0])

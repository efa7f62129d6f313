"""The reader table: every input format uavplace reads, registered once with how it is recognised and read.

`uavdata ingest` classifies a city folder's files through ``FORMATS`` (``format_of``) and reads every building
format it finds through the entry's ``read``; `uavdata simulate` reads its geometry source through the same entries
(``geometry_format``). A folder format (RadioMapSeer) is recognised by its folder (``FOLDER_FORMATS``). A new format
is one entry here and its reader module; neither pipeline names a format's reader.

The order of ``FORMATS`` is the order of recognition: the first entry whose suffix (and, for a suffix two formats
share, content) matches is the file's format.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from uavplace.infra.files import regular_file_bytes
from uavplace.ingest.buildings import BuildingRecord
from uavplace.ingest.mesh import MESH_SUFFIXES
from uavplace.ingest.wireless_insite.p2m_header import parse_filename
from uavplace.schemas import InputError, Rejection
from uavplace.schemas.provenance import SIDE_FILE_SUFFIX

#: A crop box (xmin, ymin, xmax, ymax) [m].
Crop = tuple[float, float, float, float]


@dataclass(frozen=True)
class Buildings:
    """What a building reader gives: the buildings, what it left out and why, and what it says of them."""

    records: list[BuildingRecord]
    rejected: list[Rejection] = field(default_factory=list)
    #: Buildings left outside a crop the reader applied itself (``Format.crops``).
    cropped: int = 0
    #: How the format's heights were taken, where it says ("" where the file states them).
    heights: str = ""


@dataclass(frozen=True)
class Format:
    """One input format: its kind (the ingest report's ``kind``), how a file is recognised, and how it is read."""

    kind: str
    #: What a user calls it, for messages.
    title: str
    #: File name endings (lower case) that may be this format; ``names``: whole file names that are.
    suffixes: tuple[str, ...] = ()
    names: tuple[str, ...] = ()
    #: For a suffix two formats share: whether the file's bytes are this format (after the suffix matched).
    sniff: Callable[[Path], bool] | None = None
    #: Why a file of this kind is listed and not read (None: it is read), or a function of the file's name giving
    #: the reason for some files only (a .p2m whose name is not an InSite receiver output).
    skip: str | Callable[[str], str | None] | None = None
    #: The building reader: (path, name in messages, crop or None) -> ``Buildings``. None: not a building format.
    read: Callable[[Path, str, Crop | None], Buildings] | None = None
    #: Whether the reader crops itself (else the caller crops its records).
    crops: bool = False
    #: Whether ``uavdata ingest`` reads it from a city folder (a Mitsuba scene's meshes are read there as meshes).
    in_folder: bool = True
    #: What one record is, for the ingest report ("3 structure(s)").
    unit: str = "building(s)"

    def matches(self, path: Path) -> bool:
        low = path.name.lower()
        if low in self.names:
            return True
        if not low.endswith(self.suffixes) or not self.suffixes:
            return False
        return self.sniff is None or self.sniff(path)

    def skip_reason(self, name: str) -> str | None:
        return self.skip(name) if callable(self.skip) else self.skip


def _contains(*tokens: bytes) -> Callable[[Path], bool]:
    """A sniff: whether the file holds every token (any of a tuple's). A file that cannot be read within the text
    limit matches: its reader then says why it is refused, naming the file, instead of its being passed over."""

    def sniff(path: Path) -> bool:
        try:
            raw = regular_file_bytes(path, str(path), "text_bytes")
        except InputError:
            return True
        return all(any(t in raw for t in (tok if isinstance(tok, tuple) else (tok,))) for tok in tokens)

    return sniff


def _p2m_skip(name: str) -> str | None:
    ident = parse_filename(name)
    if ident is None:
        return "a .p2m whose name is not <project>.<output>.tTTT_SS.rRRR.p2m"
    return None if ident.is_receiver_output else ident.skip_reason


def _read_city(path: Path, name: str, crop: Crop | None) -> Buildings:
    from uavplace.ingest.wireless_insite.city import read_city

    return Buildings(read_city(path, name))


def _read_geojson(path: Path, name: str, crop: Crop | None) -> Buildings:
    from uavplace.ingest.geojson import read_geojson

    return Buildings(*read_geojson(path, name))


def _read_cityjson(path: Path, name: str, crop: Crop | None) -> Buildings:
    from uavplace.ingest.cityjson import read_cityjson

    records, rejected, heights = read_cityjson(path, name)
    return Buildings(records, rejected, heights=heights)


def _read_mesh(path: Path, name: str, crop: Crop | None) -> Buildings:
    from uavplace.ingest.mesh import read_mesh

    return Buildings(*read_mesh(path, name))


def _read_mitsuba(path: Path, name: str, crop: Crop | None) -> Buildings:
    from uavplace.ingest.mitsuba import read_mitsuba

    scene = read_mitsuba(path, name, crop=crop)
    return Buildings(scene.buildings, cropped=scene.num_cropped)


_CITYJSON = _contains(b'"CityObjects"', (b'"CityJSON"', b'"CityModel"'))
_GEOJSON = _contains((b'"FeatureCollection"', b'"Feature"'))

#: Every file format, in the order of recognition.
FORMATS: tuple[Format, ...] = (
    Format("p2m", "Wireless InSite receiver output", (".p2m", ".p2m.gz"), skip=_p2m_skip),
    Format("cells", "uavplace cell provenance", (SIDE_FILE_SUFFIX, SIDE_FILE_SUFFIX.removesuffix(".gz"))),
    Format("routes", "user routes", (".routes.csv",)),
    Format("txrx", "Wireless InSite transmitter/receiver sets", (".txrx",)),
    Format("setup", "Wireless InSite project setup", (".setup",)),
    Format("city", "Wireless InSite .city", (".city",), read=_read_city, unit="structure(s)"),
    Format("terrain", "Wireless InSite terrain", (".ter",)),
    Format("geojson", "GeoJSON footprints", (".geojson",), read=_read_geojson, unit="footprint(s)"),
    Format("cityjson", "CityJSON", (".json",), sniff=_CITYJSON, read=_read_cityjson),
    Format("geojson", "GeoJSON footprints", (".json",), sniff=_GEOJSON, read=_read_geojson, unit="footprint(s)"),
    Format("mesh", "building mesh", MESH_SUFFIXES, read=_read_mesh, unit="building bod(ies)"),
    Format("mitsuba", "Mitsuba scene", (".xml",), read=_read_mitsuba, crops=True, in_folder=False),
    Format(
        "geometry",
        "Wireless InSite object, foliage or floor plan",
        (".object", ".veg", ".flp"),
        skip="a Wireless InSite object, foliage or floor plan: not read (buildings come from the geometry formats)",
    ),
    Format(
        "provenance",
        "simulation provenance",
        names=("simulation.json",),
        skip="simulation provenance (copied into the manifest's sources)",
    ),
)

#: Names of the files ingest reads (a folder so named is reported, not silently passed over).
EXPORT_SUFFIXES: tuple[str, ...] = tuple(dict.fromkeys(s for f in FORMATS if f.in_folder for s in f.suffixes))
#: The geometry formats, for messages ("expected ...").
_SUFFIXES_OF: dict[str, list[str]] = {}
for _f in FORMATS:
    if _f.read is not None:
        _SUFFIXES_OF.setdefault(_f.title, []).extend(_f.suffixes)
GEOMETRY_TITLES = ", ".join(f"{title} ({'/'.join(s)})" for title, s in _SUFFIXES_OF.items())


def format_of(path: Path, *, in_folder: bool = True) -> Format | None:
    """The format of a file (the first entry that matches), or None; ``in_folder``: only formats ingest reads from
    a city folder."""
    return next((f for f in FORMATS if (f.in_folder or not in_folder) and f.matches(path)), None)


def geometry_format(path: Path) -> Format:
    """The building format of a geometry source (`uavdata simulate`), else ``InputError`` naming the file."""
    found = next((f for f in FORMATS if f.read is not None and f.matches(path)), None)
    if found is None:
        raise InputError(path, f"not a geometry format uavplace reads (expected {GEOMETRY_TITLES})", field="source")
    return found


@dataclass(frozen=True)
class FolderFormat:
    """A format that is a whole folder (recognised by its folder, ingested by its own function)."""

    kind: str
    title: str
    detect: Callable[[Path], bool]
    #: (folder, output folder, city, (manifest name, report name), command) -> (manifest, report).
    ingest: Callable[..., tuple]


def _is_radiomapseer(folder: Path) -> bool:
    from uavplace.ingest.radiomapseer import is_radiomapseer

    return is_radiomapseer(folder)


def _ingest_radiomapseer(*args: object) -> tuple:
    from uavplace.ingest.radiomapseer import ingest_radiomapseer

    return ingest_radiomapseer(*args)


#: Folder formats, tried before a folder is read as files of ``FORMATS``.
FOLDER_FORMATS: tuple[FolderFormat, ...] = (
    FolderFormat("radiomapseer", "RadioMapSeer-style folder", _is_radiomapseer, _ingest_radiomapseer),
)


def folder_format(folder: Path) -> FolderFormat | None:
    """The folder format ``folder`` is, or None (a folder of files)."""
    return next((f for f in FOLDER_FORMATS if f.detect(folder)), None)


__all__ = [
    "EXPORT_SUFFIXES",
    "FOLDER_FORMATS",
    "FORMATS",
    "Buildings",
    "FolderFormat",
    "Format",
    "folder_format",
    "format_of",
    "geometry_format",
]


@dataclass(frozen=True)
class Classified:
    path: Path
    rel: str
    kind: str
    skip_reason: str | None = None
    #: Its entry of the reader table (None: not a format ingest reads).
    fmt: Format | None = None


def classify(folder: Path) -> list[Classified]:
    """Every non-hidden file below ``folder``, sorted, with its format family.

    A symbolic link that leads out of ``folder`` is listed as skipped (kind
    ``link``) and never opened: a city folder cannot make ingest read files
    elsewhere on the machine. Whatever is not a regular file (a FIFO, a device, a
    socket, a broken or looping link, a folder named like an export) is listed as
    skipped too (kind ``special``), never opened: it would block or say nothing.
    """
    out = []
    inside = folder.resolve()
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if any(part.startswith(".") for part in Path(rel).parts):
            continue
        low = path.name.lower()
        kind, reason, fmt = "other", None, None
        try:
            target = path.resolve()
        except (OSError, RuntimeError):  # a link loop
            target = None
        if target is not None and not target.is_relative_to(inside):
            kind, reason = "link", f"symbolic link to {target}, outside the city folder: not read"
        elif path.is_dir() and target is not None:
            if not low.endswith(EXPORT_SUFFIXES):
                continue  # a folder of the city: its files are listed themselves
            kind, reason = "special", "a folder named like an export: not read"
        elif target is None or not path.is_file():
            kind, reason = "special", "not a regular file (a FIFO, device, socket, or a broken or looping link): not read"
        elif (fmt := format_of(path)) is not None:
            kind, reason = fmt.kind, fmt.skip_reason(path.name)
        out.append(Classified(path, rel, kind, reason, fmt))
    return out

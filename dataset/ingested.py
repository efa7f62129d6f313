"""An ingested city as ``uavdata build`` reads it: its tables checked against their manifest hashes
(``read_ingested``), and its routes apart from its users (``split_routes``)."""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from uavplace.dataset.catalog import DEFAULT_ROOT, INGESTED_MANIFEST, read_city_manifest
from uavplace.infra.files import ARCHIVE_ERRORS, folder_lock
from uavplace.schemas import SCHEMA_VERSION, CityManifest, InputError
from uavplace.schemas.tables import BUILDING_PARTS, BUILDINGS, RECEIVERS, ROUTES, TRANSMITTERS


@dataclass(frozen=True)
class Ingested:
    """An ingested city as the build reads it."""

    folder: Path
    manifest: CityManifest
    receivers: pd.DataFrame
    transmitters: pd.DataFrame
    buildings: pd.DataFrame
    parts: pd.DataFrame
    terrain: dict[str, np.ndarray] | None
    hashes: dict[str, str]
    routes: pd.DataFrame | None = None  # the tracking task's route points (ingest.routes), when the city has routes


def read_ingested(city: str, root: str | Path = DEFAULT_ROOT) -> Ingested:
    """Read an ingested city, refusing tables whose sha256 differs from the ingest manifest.

    The folder is read under its lock (the one ``uavdata ingest`` holds while it replaces the folder), and every file
    is read once: its bytes are hashed and parsed, so the hashes recorded in a bundle are those of what it was built
    from, even when an ingest of the same city runs at the same time.
    """
    folder = Path(root) / city / INGESTED_MANIFEST.parent
    if not folder.parent.is_dir():  # checked before the lock, which would make the city's folder
        read_city_manifest(folder / INGESTED_MANIFEST.name)  # the error: run `uavdata ingest` first
    with folder_lock(folder):
        manifest = read_city_manifest(folder / INGESTED_MANIFEST.name)
        if manifest.schema_version != SCHEMA_VERSION:
            raise InputError(
                folder / INGESTED_MANIFEST.name,
                f"ingested with schema version {manifest.schema_version!r}, "
                f"this uavplace reads {SCHEMA_VERSION!r}: run `uavdata ingest` again",
                field="schema_version",
            )
        files = {spec.name: spec.filename for spec in (RECEIVERS, TRANSMITTERS, BUILDINGS, BUILDING_PARTS, ROUTES)}
        files["terrain"] = "terrain.npz"
        hashes: dict[str, str] = {}
        data: dict[str, bytes] = {}
        for name, expected in manifest.tables.items():
            path = folder / files.get(name, name)
            if not path.is_file():
                raise InputError(path, "missing ingested table: run `uavdata ingest` again")
            data[name] = path.read_bytes()
            actual = hashlib.sha256(data[name]).hexdigest()
            if actual != expected:
                raise InputError(
                    path, "sha256 differs from the ingest manifest: the table was changed after ingest", field="sha256"
                )
            hashes[files.get(name, name)] = actual

    def table(spec) -> pd.DataFrame:
        if spec.name not in data:
            raise InputError(folder / INGESTED_MANIFEST.name, f"lists no table {spec.name}: run `uavdata ingest` again")
        try:
            return pq.read_table(pa.BufferReader(data[spec.name])).to_pandas()
        except (OSError, ValueError) as exc:
            raise InputError(folder / spec.filename, f"unreadable ingested table ({str(exc)[:160]})") from None

    terrain = None
    if "terrain" in data:
        try:
            with np.load(io.BytesIO(data["terrain"]), allow_pickle=False) as npz:
                terrain = {k: npz[k] for k in npz.files}
        except ARCHIVE_ERRORS as exc:
            raise InputError(folder / "terrain.npz", f"unreadable terrain ({type(exc).__name__}: {str(exc)[:160]})") from None
    return Ingested(
        folder=folder,
        manifest=manifest,
        receivers=table(RECEIVERS),
        transmitters=table(TRANSMITTERS),
        buildings=table(BUILDINGS),
        parts=table(BUILDING_PARTS),
        terrain=terrain,
        hashes=hashes,
        routes=table(ROUTES) if ROUTES.name in data else None,
    )


def split_routes(ing: Ingested) -> tuple[Ingested, Ingested | None]:
    """(the users' part of ``ing``, the route points' part or None): the receivers and transmitters of the route
    points (``ing.routes``) apart from the users', so that each is rasterised on its own and no route point is a user."""
    if ing.routes is None:
        return ing, None
    keys = pd.MultiIndex.from_frame(ing.routes[["tx_set_id", "tx_point"]].astype("int64"))

    def of_routes(df: pd.DataFrame) -> np.ndarray:
        return pd.MultiIndex.from_arrays([df["tx_set_id"].astype("int64"), df["tx_point"].astype("int64")]).isin(keys)

    rx, tx = of_routes(ing.receivers), of_routes(ing.transmitters)
    users = replace(ing, receivers=ing.receivers[~rx], transmitters=ing.transmitters[~tx], routes=None)
    return users, replace(ing, receivers=ing.receivers[rx], transmitters=ing.transmitters[tx])

"""Project setup (.setup): carrier frequency, antennas and their power thresholds, comm systems.

Only top-level blocks of ``begin_<project>`` are read: ``begin_<Waveform>``
(``waveform N``, ``CarrierFrequency`` [Hz], ``bandwidth`` [Hz]),
``begin_<antenna>`` (``antenna N``, ``type``, ``polarization``,
``power_threshold`` [dBm]), ``begin_<CommSystem>`` (``NoisePowerDensity``
[dBm/Hz], ``UniformInterference`` [dBm], set numbers), ``begin_<feature>``
(geometry file names) and ``begin_<txrx_sets>`` (the .txrx file name).
"""

from __future__ import annotations

from pathlib import Path

from uavplace.ingest.wireless_insite.keyword import Block, parse_keyword_file
from uavplace.schemas import AntennaInfo, CommSystemInfo, InputError, SetupInfo, WaveformInfo
from uavplace.schemas.tables import RECEIVERS, TRANSMITTERS, Column
from uavplace.schemas.txrx import FeatureFile

_FEATURE_KINDS = {"city": "city", "terrain": "terrain", "object": "object", "floorplan": "floorplan", "foliage": "foliage"}


def _ints(block: Block, key: str) -> tuple[int, ...]:
    found = block.find_entry(key)
    if found is None:
        return ()
    line, text = found
    try:
        return tuple(int(w) for w in text.split())
    except ValueError:
        raise InputError(block.path, f"'{text}' is not a list of set numbers", line=line, field=key) from None


def _required_number(block: Block, key: str, cast: type = float, column: Column | None = None) -> float | int:
    value = block.number(key, cast, column)
    if value is None:
        raise InputError(block.path, f"{block.kind} '{block.name}' has no {key}", line=block.line, field=key)
    return value


def read_setup(path: str | Path, display: str | None = None) -> SetupInfo:
    root = parse_keyword_file(path, display)
    projects = root.blocks("project")
    if not projects:
        raise InputError(display or str(path), "no begin_<project> block", field="project")
    project = projects[0]
    globals_ = project.blocks("globals")
    waveforms = tuple(
        WaveformInfo(
            number=int(_required_number(b, "waveform", int)),
            name=b.name,
            carrier_frequency_hz=float(_required_number(b, "CarrierFrequency", column=TRANSMITTERS.column("frequency_hz"))),
            bandwidth_hz=b.number("bandwidth", column=TRANSMITTERS.column("frequency_hz")),
        )
        for b in project.blocks("Waveform")
    )
    antennas = tuple(
        AntennaInfo(
            number=int(_required_number(b, "antenna", int)),
            name=b.name,
            type=b.value("type"),
            polarization=b.value("polarization"),
            power_threshold_dbm=b.number("power_threshold", column=RECEIVERS.column("power_dbm")),
        )
        for b in project.blocks("antenna")
    )
    comm = tuple(
        CommSystemInfo(
            number=int(_required_number(b, "CommSystemNumber", int)),
            name=b.name,
            noise_power_density_dbm_hz=b.number("NoisePowerDensity"),
            uniform_interference_dbm=b.number("UniformInterference"),
            base_stations=_ints(b, "BaseStations"),
            interferers=_ints(b, "Interferers"),
            receivers=_ints(b, "Receivers"),
        )
        for b in project.blocks("CommSystem")
    )
    features = []
    for b in project.blocks("feature"):
        kind = next((k for k in _FEATURE_KINDS if b.has_word(k)), "other")
        features.append(
            FeatureFile(
                kind=_FEATURE_KINDS.get(kind, "other"), filename=b.value("filename") or "", active=not b.has_word("inactive")
            )  # type: ignore[arg-type]
        )
    txrx_files = tuple(b.value("filename") or "" for b in project.blocks("txrx_sets"))
    return SetupInfo(
        project_name=project.name,
        longitude=globals_[0].number("longitude") if globals_ else None,
        latitude=globals_[0].number("latitude") if globals_ else None,
        waveforms=waveforms,
        antennas=antennas,
        comm_systems=comm,
        features=tuple(features),
        txrx_files=txrx_files,
        source=project.where(),
    )

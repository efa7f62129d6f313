"""Resource limits: every loop and allocation whose size comes from the input is bounded before the work starts.

Each limit has a name, a default that fits the 2-core, 24 GiB machines this project runs on, and a reason. Input
past a limit is refused with one error line that names the limit and says how to raise it::

    uavdata --limit grid_cells=20000000 build --grid 0.5m --alt 10
    UAVPLACE_LIMITS="mesh_bytes=1e9,grid_cells=2e7" uavdata ingest data/raw/big/

``--limit`` (on ``uavdata`` and ``uavrl``, before the command) writes ``UAVPLACE_LIMITS`` for the process, so that
children and local Ray workers see the same limits; on a Ray cluster set ``UAVPLACE_LIMITS`` on the workers.
"""

from __future__ import annotations

import math
import os

from pydantic import Field, ValidationError

from uavplace.schemas.base import Contract, InputError

#: The environment variable holding overrides, ``NAME=VALUE`` pairs separated by commas.
ENV = "UAVPLACE_LIMITS"
GiB = 2**30


class Limits(Contract):
    """The resource limits of every command (override with ``--limit NAME=VALUE`` or ``UAVPLACE_LIMITS``)."""

    mesh_bytes: int = Field(
        default=256 * 2**20, ge=1, description="Size of one mesh file (PLY, OBJ, glTF) read by ingest or simulate [bytes]"
    )
    text_bytes: int = Field(
        default=256 * 2**20,
        ge=1,
        description="One text export read whole by ingest or simulate: .city, .txrx, .setup, GeoJSON, routes, Mitsuba "
        "XML [bytes]",
    )
    route_points: int = Field(default=100_000, ge=1, description="Rows of one routes table (ingest)")
    record_bytes: int = Field(
        default=16 * 2**20,
        ge=1,
        description="One record or settings file read whole (a bundle's manifest.json, a run's run.json, a sweep spec, "
        "a predictor's constants) [bytes]",
    )
    export_bytes: int = Field(
        default=2**30, ge=1, description="Text of one receiver export (.p2m), decompressed, read by ingest [bytes]"
    )
    array_bytes: int = Field(
        default=8 * GiB, ge=1, description="One array of a bundle, from its .npy header, before reading [bytes]"
    )
    grid_cells: int = Field(
        default=4_000_000,
        ge=1,
        description="Cells of one grid, extent / grid squared: a bundle's (uavdata build) or a simulated receiver grid's "
        "(uavdata simulate)",
    )
    buildings: int = Field(
        default=50_000,
        ge=1,
        description="Buildings or shapes of one city's geometry (a .city's structures, a GeoJSON's features, a Mitsuba "
        "scene's shapes), counted before any is processed",
    )
    map_bytes: int = Field(
        default=6 * GiB, ge=1, description="The per-user maps of one build, users x cells x 8 bytes, held in memory [bytes]"
    )
    cities: int = Field(default=1000, ge=1, description="Cities of one uavdata simulate call (--count)")
    users: int = Field(default=1000, ge=1, description="Users of one simulated city (--users)")
    samples: float = Field(default=1e10, ge=1e3, description="Rays per user of uavdata simulate (--samples)")
    extent_m: float = Field(default=5000.0, gt=0, description="Side of a simulated city or of its --extent/--crop box [m]")
    user_cells: float = Field(default=5e7, ge=1, description="Users x grid cells of one simulated city: its maps in memory")
    receiver_rows: int = Field(
        default=5_000_000,
        ge=1,
        description="Receiver rows one ingest of a RadioMapSeer-style folder makes (its users x grid cells), in memory: "
        "about 280 bytes each at the peak",
    )
    routes: int = Field(default=200, ge=0, description="Routes of one simulated city (--routes)")
    route_length_m: float = Field(default=2000.0, ge=4, description="Length of one simulated route (--route-length) [m]")
    simulated_route_points: int = Field(
        default=5000, ge=0, description="Route points of one simulated city, each traced as a user"
    )
    network_params: int = Field(
        default=50_000_000, ge=1, description="Parameters of one agent network (train, and every load of a run)"
    )
    replay_bytes: int = Field(
        default=8 * GiB, ge=1, description="Replay memory of one training (buffer_size x one transition) [bytes]"
    )
    episodes: int = Field(default=1_000_000, ge=1, description="Episodes of one evaluation (report, baselines) per city")
    t_max: int = Field(default=100_000, ge=1, description="Step budget of one evaluation episode (--t-max)")
    episode_steps: int = Field(
        default=5_000_000,
        ge=1,
        description="Episodes x step budget of one evaluation per city (--episodes x --t-max or --horizon): the steps "
        "it plays and, for tracking, the coverage it holds per method",
    )
    sweep_runs: int = Field(default=1000, ge=1, description="Runs of one sweep file (its trials x their seeds)")
    bootstrap: int = Field(default=1_000_000, ge=1, description="Bootstrap resamples of a report's intervals (--bootstrap)")
    predictor_step_bytes: int = Field(
        default=2 * GiB,
        ge=1,
        description="Activations of one training step of the learned predictor: crops x each level's cells x its "
        "channels x 32 bytes (forward and backward) [bytes]",
    )
    prediction_bytes: int = Field(
        default=4 * GiB,
        ge=1,
        description="The map searcher's predicted maps of one city, candidates x legal cells x 12 bytes (16 where it krigs)",
    )
    train_steps: int = Field(default=10_000_000_000, ge=1, description="Environment steps of one training (--steps, total_steps)")


_current: Limits | None = None


def parse_limits(text: str, source: str = ENV) -> dict[str, float]:
    """``NAME=VALUE[,NAME=VALUE...]`` as a dict; ``InputError`` naming ``source`` on a malformed pair or an unknown name."""
    out: dict[str, float] = {}
    for pair in (p.strip() for p in text.split(",")):
        if not pair:
            continue
        name, sep, value = pair.partition("=")
        name = name.strip()
        if not sep or name not in Limits.model_fields:
            raise InputError(
                source, f"{pair!r}: expected NAME=VALUE with NAME one of {', '.join(Limits.model_fields)}", field="limit"
            )
        try:
            number = float(value)
        except ValueError:
            raise InputError(source, f"{pair!r}: {value!r} is not a number", field=name) from None
        out[name] = number
    return out


def _build(overrides: dict[str, float], source: str) -> Limits:
    fields = Limits.model_fields
    values = {
        k: (int(v) if fields[k].annotation is int and math.isfinite(v) and v == int(v) else v) for k, v in overrides.items()
    }
    try:
        return Limits(**values)
    except ValidationError as err:
        first = err.errors()[0]
        raise InputError(source, f"{first['msg']} (got {first.get('input')!r})", field=str(first["loc"][0])) from None


def limits() -> Limits:
    """The limits in force: the defaults, overridden by ``UAVPLACE_LIMITS`` (read once per process)."""
    global _current
    if _current is None:
        _current = _build(parse_limits(os.environ.get(ENV, "")), ENV)
    return _current


def set_limits(pairs: list[str] | tuple[str, ...], source: str = "--limit") -> Limits:
    """Apply ``NAME=VALUE`` overrides on top of ``UAVPLACE_LIMITS`` for this process and the processes it starts."""
    global _current
    overrides = parse_limits(os.environ.get(ENV, ""), ENV)
    for pair in pairs:
        overrides.update(parse_limits(pair, source))
    _current = _build(overrides, source)
    os.environ[ENV] = ",".join(f"{k}={v:.17g}" for k, v in overrides.items())
    return _current


def shown(value: float) -> str:
    """A limit's value as the help and errors write it: ``268,435,456``, ``1e+10``, ``5,000``."""
    return f"{int(value):,}" if abs(value) < 1e15 and value == int(value) else f"{value:g}"


def over_limit(name: str, value: float, what: str) -> str:
    """The message for ``value`` of ``what`` past limit ``name``: names the limit and how to raise it."""
    limit = getattr(limits(), name)
    return f"{what}: {shown(value)} is over the limit {name} = {shown(limit)}; raise it with `--limit {name}=VALUE` (or {ENV})"


def check_limit(name: str, value: float, source: object, what: str, *, line: int | None = None, field: str | None = None) -> None:
    """``InputError`` (naming ``source``, ``line``, ``field``, the limit and how to raise it) if ``value`` passes limit ``name``."""
    if not value <= getattr(limits(), name):
        raise InputError(source, over_limit(name, value, what), line=line, field=field)

"""Many cities in one `uavdata simulate` call, each a Ray task: local Ray by default, a cluster by address.

A corpus is a list of ``SimulationSpec`` (a name and a seed each); its result
depends only on the specs. A city whose folder already holds a
``simulation.json`` of the same spec and ray-trace settings is skipped, so an
interrupted corpus is resumed by running the same command again. Each city is
written atomically by ``simulate_city`` in the task that traces it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from uavplace.infra.cluster import start_ray
from uavplace.schemas import InputError
from uavplace.simulate.config import SimulationSpec
from uavplace.simulate.pipeline import PROVENANCE, simulate_city
from uavplace.simulate.raytrace import RayTraceConfig, raytrace_record
from uavplace.simulate.trace_cache import spec_record


def corpus_specs(sources: list[str], name: str, count: int, base: SimulationSpec, first: int = 0) -> list[SimulationSpec]:
    """The cities of one call: ``count`` seeds of one source (from index ``first``), or one city per source; names
    ``NAME-000``...

    City ``i`` takes seed ``base.seed + i``, so adding cities never changes the earlier ones.
    """
    if count > 1 and len(sources) > 1:
        raise InputError(None, "give several SOURCES or --count N, not both", field="count")
    if first and count == 1:
        raise InputError(None, f"--first {first} needs --count N above it (the corpus's cities FIRST..N-1)", field="first")
    if first >= count > 1:
        raise InputError(None, f"--first {first} leaves no city of --count {count}", field="first")
    if count == 1 and len(sources) == 1:
        return [replace(base, source=sources[0], name=name)]
    pairs = [(sources[0], i) for i in range(first, count)] if count > 1 else list(zip(sources, range(len(sources)), strict=True))
    return [replace(base, source=src, name=f"{name}-{i:03d}", seed=base.seed + i) for src, i in pairs]


def city_config(config: RayTraceConfig, spec: SimulationSpec) -> RayTraceConfig:
    """The ray-trace settings of one city: its own seed for the ray sampler."""
    return replace(config, seed=spec.seed)


def is_done(spec: SimulationSpec, config: RayTraceConfig, out_root: str | Path) -> bool:
    """True when ``out_root/<name>/simulation.json`` records exactly this spec and these ray-trace settings."""
    path = Path(out_root) / spec.name / PROVENANCE
    if not path.is_file():
        return False
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, OSError):
        return False
    same_spec = record.get("spec") == json.loads(json.dumps(spec_record(spec)))
    return same_spec and record.get("raytrace") == json.loads(json.dumps(raytrace_record(config)))


def _simulate_task(
    spec: SimulationSpec,
    config: RayTraceConfig,
    out_root: str,
    command: str,
    trace_cache: str | None = None,
    cpus_per_user: float = 2.0,
) -> dict:
    """One city, in a Ray worker: the summary of its simulation.json, or the one-line error that stopped it. Its
    exact paths for the missed cells (``--complete-missed``) are Ray tasks of the same cluster."""
    try:
        folder, record = simulate_city(
            spec, config, out_root, command=command, trace_cache=trace_cache, cpus_per_user=cpus_per_user
        )
    except (InputError, RuntimeError, OSError) as err:
        return {"name": spec.name, "error": " ".join(str(err).split())}
    return {"name": spec.name, "folder": str(folder), "geometry": record["geometry"], "seconds": record["wall_seconds"]}


def simulate_corpus(
    specs: list[SimulationSpec],
    config: RayTraceConfig,
    out_root: str | Path,
    *,
    command: str = "",
    address: str | None = None,
    cpus_per_city: float = 2.0,
    on_city: Callable[[dict, int, int], None] | None = None,
    trace_cache: str | Path | None = None,
) -> tuple[list[dict], list[str]]:
    """Simulate every city not yet done, as Ray tasks; (summaries of the cities traced, names skipped).

    ``address``: a Ray cluster (``ray://host:10001`` or ``auto``); None starts a local Ray with this
    machine's CPUs. ``cpus_per_city``: CPUs a task reserves (the ray tracer uses them all).
    ``on_city(summary, done, total)`` is called as each city finishes. ``trace_cache``: as ``simulate_city``'s (a
    folder the Ray workers can reach).
    """
    try:
        import ray
    except ImportError:
        raise RuntimeError("Ray is not installed: pip install -e '.[raytrace]'") from None
    todo = [s for s in specs if not is_done(s, city_config(config, s), out_root)]
    skipped = [s.name for s in specs if s not in todo]
    if not todo:
        return [], skipped
    started = start_ray(address, cpus_per_city, "--cpus-per-city")
    try:
        task = ray.remote(num_cpus=cpus_per_city, max_retries=0)(_simulate_task)
        cache = None if trace_cache is None else str(Path(trace_cache).resolve())
        pending = [
            task.remote(s, city_config(config, s), str(Path(out_root).resolve()), command, cache, cpus_per_city) for s in todo
        ]
        done: list[dict] = []
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            try:
                summary = ray.get(ready[0])
            except ray.exceptions.RayError as err:
                raise RuntimeError(f"a city's Ray task failed: {str(err).splitlines()[0]}") from None
            if "error" in summary:
                raise RuntimeError(
                    f"{summary['name']}: {summary['error']} (the cities done so far are kept; run again to resume)"
                )
            done.append(summary)
            if on_city is not None:
                on_city(summary, len(done), len(todo))
        return done, skipped
    finally:
        if started:
            ray.shutdown()

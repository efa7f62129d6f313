"""A report's methods played side by side as Ray tasks: local by default, a cluster by address. Every task's report
plays through it: placement's (``run_episodes``), the tracking task's (``run_tracking``) and the fleet's
(``run_fleet``), each rollout told its piece's place in the whole list (``first``).

Every random choice of an episode is drawn from that episode and step (``rl.randomness``; a tracking episode's from
its place in the list, which ``first`` keeps), and an episode plays the same whatever else shares its batch: so a
method's episodes can be cut into contiguous pieces, each played by its own task, and put back together. The results
are the same frames, to the bit, whether the methods play one after the other in this process or in pieces on any
number of workers (``tests/test_parallel.py``). Pieces, not whole methods, because one method can hold most of a
report's time (the hybrid, which updates the searcher's belief every step: ``benchmarks/breakdown.py``); every method
is cut into as many pieces as the cluster has CPUs (pieces of at least ``MIN_PIECE`` episodes).

The searchers' predicted maps are made first, in this process, and kept in the prediction cache; a task reads them
from there (a policy travels without its in-memory maps). Progress comes back from the tasks through a Ray queue, at
most once a second a task, and is summed per method, so a report's progress lines count each method's episodes done
as they pass, as they do without Ray.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

#: Seconds between two progress messages of one task.
PROGRESS_EVERY_S = 1.0
#: The fewest episodes a piece of a method holds (a task has a fixed cost: its policy and maps to load).
MIN_PIECE = 50


@dataclass(frozen=True)
class Method:
    """One method of a report as its pieces play it: ``play(world, policy, specs, first=, on_step=, **options)`` on
    contiguous pieces of ``specs`` (``run_episodes`` on a ``MapSet``, ``run_tracking`` on a ``RouteSet``, ``run_fleet``
    on ``FleetMaps``), each piece with ``record=`` the episodes of ``record`` it holds (numbered from its first) when
    ``record`` is given (the episodes whose paths are kept, numbered in the whole list)."""

    name: str
    policy: Any
    world: Any
    specs: np.ndarray
    record: np.ndarray | None = None
    options: dict = field(default_factory=dict)


def _play(play: Callable, method: Method, world: Any, first: int, stop: int, key: tuple, queue) -> Any:  # noqa: ANN001
    """Episodes ``first .. stop`` of ``method`` on ``world`` (its world, sent once for all the methods that share it)
    in a Ray task of one CPU: one torch thread, progress to ``queue`` under ``key``; numbered as in the whole list."""
    import torch

    torch.set_num_threads(1)
    last = [0.0]

    def tell(done: int, total: int) -> None:
        now = time.monotonic()
        if now - last[0] >= PROGRESS_EVERY_S or done >= total:
            last[0] = now
            queue.put((key, done))

    options = dict(method.options)
    if method.record is not None:
        wanted = np.asarray(method.record, np.int64)
        options["record"] = wanted[(wanted >= first) & (wanted < stop)] - first
    return play(world, method.policy, method.specs[first:stop], first=first, on_step=tell, **options)


def joined_frames(parts: list[pd.DataFrame]) -> pd.DataFrame:
    """Contiguous pieces of one method's frame (``run_episodes``, ``run_fleet``), in order, as one: the rows and the
    recorded paths (``attrs["paths"]``)."""
    paths = {e: p for f in parts for e, p in (f.attrs.get("paths") or {}).items()}
    df = pd.concat(parts, ignore_index=True)
    df.attrs["paths"] = paths
    return df


def pieces(n: int, workers: int) -> list[tuple[int, int]]:
    """``[start, stop)`` of the contiguous pieces ``n`` episodes are cut into for ``workers`` CPUs."""
    count = max(1, min(workers, math.ceil(n / MIN_PIECE)))
    edges = np.linspace(0, n, count + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def play_on_ray(
    methods: list[Method],
    play: Callable,
    join: Callable[[list], Any] = joined_frames,
    on_progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, Any]:
    """``{name: join(its pieces' results)}`` of every method of ``methods``, each played by ``play`` in pieces
    (``pieces``), each a Ray task of one CPU on the Ray this process has joined (``infra.cluster.start_ray``), in
    ``methods``' order. ``on_progress(name, done, total)``: each method's episodes done, summed over its pieces."""
    import ray
    from ray.util.queue import Empty, Queue

    workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
    queue = Queue()
    task = ray.remote(num_cpus=1, max_retries=0)(_play)
    play_ref = ray.put(play)
    stored: dict[int, ray.ObjectRef] = {}
    pending: dict[ray.ObjectRef, tuple[str, int]] = {}
    done: dict[str, dict[int, int]] = {m.name: {} for m in methods}
    for m in methods:
        world_ref = stored.setdefault(id(m.world), ray.put(m.world))  # one copy of each world for all its methods
        method_ref = ray.put(replace(m, world=None))  # its world put once above
        for first, stop in pieces(len(m.specs), workers):
            ref = task.remote(play_ref, method_ref, world_ref, first, stop, (m.name, first), queue)
            pending[ref] = (m.name, first)
            done[m.name][first] = 0
    parts: dict[tuple[str, int], Any] = {}
    total = {m.name: len(m.specs) for m in methods}

    def tell() -> None:
        while True:
            try:
                (name, first), n = queue.get_nowait()
            except Empty:
                return
            done[name][first] = n
            if on_progress is not None:
                on_progress(name, sum(done[name].values()), total[name])

    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
            tell()
            for ref in ready:
                parts[pending.pop(ref)] = ray.get(ref)
        tell()
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        ray.kill(queue.actor)
    return {m.name: join([parts[(m.name, first)] for first in sorted(done[m.name])]) for m in methods}

"""A report's methods played side by side as Ray tasks: local by default, a cluster by address.

Every random choice of an episode is drawn from that episode and step (``rl.randomness``), and an episode plays the
same whatever else shares its batch: so a method's episodes can be cut into contiguous pieces, each played by its
own task, and put back together. The results are the same frames, to the bit, whether the methods play one after
the other in this process or in pieces on any number of workers (``tests/test_parallel.py``). Pieces, not whole
methods, because one method can hold most of a report's time (the hybrid, which updates the searcher's belief every
step: ``benchmarks/breakdown.py``); every method is cut into as many pieces as the cluster has CPUs (pieces of at
least ``MIN_PIECE`` episodes).

The searchers' predicted maps are made first, in this process, and kept in the prediction cache; a task reads them
from there (a policy travels without its in-memory maps). Progress comes back from the tasks through a Ray queue, at
most once a second a task, and is summed per method, so a report's progress lines count each method's episodes done
as they pass, as they do without Ray.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
import pandas as pd

from uavplace.rl.tasks.placement.policies import Policy
from uavplace.rl.tasks.placement.rollout import run_episodes
from uavplace.rl.world.maps import MapSet

#: Seconds between two progress messages of one task.
PROGRESS_EVERY_S = 1.0
#: The fewest episodes a piece of a method holds (a task has a fixed cost: its policy and maps to load).
MIN_PIECE = 50


def _play(
    maps: MapSet, policy: Policy, specs: np.ndarray, first: int, record: np.ndarray | None, key: tuple, queue
) -> pd.DataFrame:  # noqa: ANN001
    """Episodes ``first ..`` of a method (``specs``, contiguous) in a Ray task of one CPU: one torch thread, progress
    to ``queue`` under ``key``; numbered as in the whole list (``episode``, the recorded paths)."""
    import torch

    torch.set_num_threads(1)
    last = [0.0]

    def tell(done: int, total: int) -> None:
        now = time.monotonic()
        if now - last[0] >= PROGRESS_EVERY_S or done >= total:
            last[0] = now
            queue.put((key, done))

    df = run_episodes(maps, policy, specs, on_step=tell, record=record)
    df["episode"] += first
    df.attrs["paths"] = {e + first: p for e, p in (df.attrs.get("paths") or {}).items()}
    return df


def pieces(n: int, workers: int) -> list[tuple[int, int]]:
    """``[start, stop)`` of the contiguous pieces ``n`` episodes are cut into for ``workers`` CPUs."""
    count = max(1, min(workers, math.ceil(n / MIN_PIECE)))
    edges = np.linspace(0, n, count + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def play_on_ray(
    methods: list[tuple[str, Policy, MapSet]],
    specs: dict[str, np.ndarray],
    record: dict[str, np.ndarray | None],
    on_progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, pd.DataFrame]:
    """``{name: run_episodes frame}`` of every method of ``methods`` (``(name, policy, maps)``) on its ``specs``, in
    pieces (``pieces``), each a Ray task of one CPU on the Ray this process has joined (``infra.cluster.start_ray``),
    in ``methods``' order; ``record``: the episodes whose paths a method keeps (None: none)."""
    import ray
    from ray.util.queue import Empty, Queue

    workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
    queue = Queue()
    task = ray.remote(num_cpus=1, max_retries=0)(_play)
    stored: dict[int, ray.ObjectRef] = {}
    pending: dict[ray.ObjectRef, tuple[str, int]] = {}
    done: dict[str, dict[int, int]] = {name: {} for name, _, _ in methods}
    for name, policy, maps in methods:
        maps_ref = stored.setdefault(id(maps), ray.put(maps))  # one copy of each canvas set for all its methods
        policy_ref = ray.put(policy)
        wanted = record[name]
        for first, stop in pieces(len(specs[name]), workers):
            mine = None if wanted is None else wanted[(wanted >= first) & (wanted < stop)] - first
            ref = task.remote(maps_ref, policy_ref, specs[name][first:stop], first, mine, (name, first), queue)
            pending[ref] = (name, first)
            done[name][first] = 0
    parts: dict[tuple[str, int], pd.DataFrame] = {}

    def tell() -> None:
        while True:
            try:
                (name, first), n = queue.get_nowait()
            except Empty:
                return
            done[name][first] = n
            if on_progress is not None:
                on_progress(name, sum(done[name].values()), len(specs[name]))

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
    out = {}
    for name, _, _ in methods:
        frames = [parts[(name, first)] for first in sorted(done[name])]
        paths = {e: p for f in frames for e, p in f.attrs["paths"].items()}
        df = pd.concat(frames, ignore_index=True)
        df.attrs["paths"] = paths
        out[name] = df
    return out
